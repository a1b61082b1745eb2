"""margtrack HDF5: exact round trip, file layout, refusal of foreign files, estimate files."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from margtrack.io import read_hdf5, write_estimate_hdf5, write_hdf5
from margtrack.recording import Recording


def _recording(n: int = 200, full: bool = True) -> Recording:
    """A seeded recording with irregular timestamps and every optional field."""
    rng = np.random.default_rng(42)
    q = rng.normal(size=(n, 4))
    extra = {}
    if full:
        extra = {
            "mag": rng.normal(scale=40.0, size=(n, 3)),
            "quat_true": q / np.linalg.norm(q, axis=1)[:, None],
            "movement": rng.random(n) < 0.6,
        }
    return Recording(
        t=1000.0 + np.cumsum(rng.uniform(0.004, 0.006, n)),
        gyr=rng.normal(scale=2.0, size=(n, 3)),
        acc=np.array([0.0, 0.0, -9.81]) + rng.normal(size=(n, 3)),
        frame="NED",
        name="trial ü = 3",
        meta={"source": "sim", "seed": 42, "gains": [0.1, 1e-300], "nested": {"a": None},
              "rate": np.float64(0.1)},
        **extra,
    )


def test_round_trip_is_exact(tmp_path: Path) -> None:
    rec = _recording()
    write_hdf5(rec, tmp_path / "r.h5")
    back = read_hdf5(tmp_path / "r.h5")
    for key in ("t", "gyr", "acc", "mag", "movement"):
        np.testing.assert_array_equal(getattr(back, key), getattr(rec, key), err_msg=key)
    assert back.movement.dtype == bool
    # the file holds quat_true bit for bit; the Recording built from it renormalises once
    # more (recording.py, see test_recording), which can move a value by an ulp or two
    with h5py.File(tmp_path / "r.h5") as f:
        np.testing.assert_array_equal(f["quat_true"][()], rec.quat_true)
    np.testing.assert_allclose(back.quat_true, rec.quat_true, rtol=0, atol=1e-15)
    assert (back.frame, back.name) == ("NED", "trial ü = 3")
    assert back.meta == {"source": "sim", "seed": 42, "gains": [0.1, 1e-300],
                         "nested": {"a": None}, "rate": 0.1}


def test_layout_and_attributes(tmp_path: Path) -> None:
    rec = _recording(20)
    write_hdf5(rec, tmp_path / "r.hdf5")
    with h5py.File(tmp_path / "r.hdf5") as f:
        assert sorted(f.keys()) == ["acc", "gyr", "mag", "movement", "quat_true", "t"]
        assert f.attrs["format"] == "margtrack-recording"
        assert f.attrs["version"] == 1
        assert f.attrs["frame"] == "NED"
        assert json.loads(f.attrs["meta"])["gains"] == [0.1, 1e-300]
        assert f["t"].dtype == np.float64 and f["gyr"].shape == (20, 3)
        np.testing.assert_array_equal(f["t"][()], rec.t)


def test_optional_fields_stay_absent(tmp_path: Path) -> None:
    rec = _recording(5, full=False)
    write_hdf5(rec, tmp_path / "r.h5")
    back = read_hdf5(tmp_path / "r.h5")
    assert back.mag is None and back.quat_true is None and back.movement is None
    np.testing.assert_array_equal(back.acc, rec.acc)
    with h5py.File(tmp_path / "r.h5") as f:
        assert sorted(f.keys()) == ["acc", "gyr", "t"]


def test_overwrite_replaces_content(tmp_path: Path) -> None:
    write_hdf5(_recording(30), tmp_path / "r.h5")
    write_hdf5(_recording(4, full=False), tmp_path / "r.h5")
    assert read_hdf5(tmp_path / "r.h5").n_samples == 4


def test_missing_file_and_folder(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"no such file: .*nothing\.h5"):
        read_hdf5(tmp_path / "nothing.h5")
    with pytest.raises(FileNotFoundError, match=r"folder .*absent does not exist"):
        write_hdf5(_recording(3), tmp_path / "absent" / "r.h5")


def test_foreign_files_are_refused(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(ValueError, match=r"not a margtrack recording \(attribute format is None\)"):
        read_hdf5(tmp_path / "other.h5")
    with h5py.File(tmp_path / "broad.h5", "w") as f:
        f["imu_gyr"] = np.zeros((3, 3))
    with pytest.raises(ValueError, match="looks like BROAD: use read_broad"):
        read_hdf5(tmp_path / "broad.h5")


def test_version_and_missing_dataset(tmp_path: Path) -> None:
    write_hdf5(_recording(5), tmp_path / "r.h5")
    with h5py.File(tmp_path / "r.h5", "a") as f:
        f.attrs["version"] = 2
    with pytest.raises(ValueError, match="version 2; this margtrack reads 1"):
        read_hdf5(tmp_path / "r.h5")
    write_hdf5(_recording(5), tmp_path / "r.h5")
    with h5py.File(tmp_path / "r.h5", "a") as f:
        del f["gyr"]
    with pytest.raises(ValueError, match="no dataset 'gyr'"):
        read_hdf5(tmp_path / "r.h5")


def test_invalid_content_names_file_and_sample(tmp_path: Path) -> None:
    write_hdf5(_recording(8), tmp_path / "r.h5")
    with h5py.File(tmp_path / "r.h5", "a") as f:
        f["acc"][3, 1] = np.nan
    with pytest.raises(ValueError, match=r"r\.h5: acc has a non-finite value .* at sample 3"):
        read_hdf5(tmp_path / "r.h5")


def test_unserialisable_meta_is_refused_before_writing(tmp_path: Path) -> None:
    rec = Recording(t=[0.0], gyr=[[0, 0, 0]], acc=[[0, 0, 9.8]], meta={"bad": object()})
    with pytest.raises(ValueError, match="meta cannot be written: object is not JSON"):
        write_hdf5(rec, tmp_path / "r.h5")
    assert not (tmp_path / "r.h5").exists()


def test_estimate_file(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    n = 50
    t = np.arange(n) / 100.0
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    bias = rng.normal(scale=1e-3, size=(n, 3))
    flags = rng.random(n) < 0.3
    cov = rng.normal(size=(n, 3, 3))
    write_estimate_hdf5(
        tmp_path / "e.h5", t, q,
        {"bias_rad_s": bias, "disturbed": flags, "cov": cov},
        {"method": "madgwick", "gain": 0.041, "rate_hz": 100, "mag": True,
         "params": {"beta": 0.041, "zeta": 0.0}, "frame": "NED", "rmse_deg": [1.5, 2.25]},
    )
    with h5py.File(tmp_path / "e.h5") as f:
        np.testing.assert_array_equal(f["t"][()], t)
        np.testing.assert_array_equal(f["quat"][()], q)
        np.testing.assert_array_equal(f["bias_rad_s"][()], bias)
        np.testing.assert_array_equal(f["disturbed"][()], flags)
        np.testing.assert_array_equal(f["cov"][()], cov)
        assert f["disturbed"].dtype == bool
        attrs = dict(f.attrs)
    assert attrs["format"] == "margtrack-estimate" and attrs["version"] == 1
    assert attrs["method"] == "madgwick" and attrs["gain"] == 0.041 and attrs["rate_hz"] == 100
    assert bool(attrs["mag"]) is True and attrs["frame"] == "NED"
    assert json.loads(attrs["json_attrs"]) == ["params", "rmse_deg"]
    assert json.loads(attrs["params"]) == {"beta": 0.041, "zeta": 0.0}
    assert json.loads(attrs["rmse_deg"]) == [1.5, 2.25]


def test_estimate_file_errors(tmp_path: Path) -> None:
    t = np.arange(4.0)
    q = np.tile([1.0, 0, 0, 0], (4, 1))
    with pytest.raises(ValueError, match=r"quat must have shape \(4, 4\) to match t, got \(3, 4\)"):
        write_estimate_hdf5(tmp_path / "e.h5", t, q[:3], {}, {})
    with pytest.raises(ValueError, match=r"output 'bias' has shape \(3, 3\); its first axis must"):
        write_estimate_hdf5(tmp_path / "e.h5", t, q, {"bias": np.zeros((3, 3))}, {})
    with pytest.raises(ValueError, match="output name 't' is reserved"):
        write_estimate_hdf5(tmp_path / "e.h5", t, q, {"t": t}, {})
    with pytest.raises(ValueError, match="attribute name 'format' is reserved"):
        write_estimate_hdf5(tmp_path / "e.h5", t, q, {}, {"format": "x"})
    with pytest.raises(ValueError, match="attribute 'x' cannot be written as JSON"):
        write_estimate_hdf5(tmp_path / "e.h5", t, q, {}, {"x": {1, 2}})
