"""margtrack.io.read / write: choosing the reader by content and the writer by extension."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

import margtrack.io as mio
from margtrack.io import read, write
from margtrack.recording import Recording

XIO_HEADER = ("Timestamp (us),Gyroscope X (deg/s),Gyroscope Y (deg/s),Gyroscope Z (deg/s),"
              "Accelerometer X (g),Accelerometer Y (g),Accelerometer Z (g)")


def _recording(n: int = 40) -> Recording:
    rng = np.random.default_rng(9)
    q = rng.normal(size=(n, 4))
    return Recording(
        t=np.cumsum(rng.uniform(0.01, 0.02, n)),
        gyr=rng.normal(size=(n, 3)),
        acc=np.array([0.0, 0.0, 9.81]) + rng.normal(scale=0.3, size=(n, 3)),
        mag=rng.normal(size=(n, 3)),
        quat_true=q / np.linalg.norm(q, axis=1)[:, None],
        movement=rng.random(n) < 0.5,
        frame="NED", name="dispatch", meta={"k": "v"},
    )


def _xio_sensor(folder: Path) -> Path:
    folder.mkdir(parents=True)
    rows = [f"{20000 * i},{i},0,0,0,0,1" for i in range(4)]
    (folder / "Inertial.csv").write_text("\n".join([XIO_HEADER, *rows]) + "\n")
    return folder


@pytest.mark.parametrize("name", ["r.h5", "r.hdf5", "R.HDF5", "r.csv", "r.CSV"])
def test_write_then_read_by_extension(tmp_path: Path, name: str) -> None:
    rec = _recording()
    write(rec, tmp_path / name)
    back = read(tmp_path / name)
    for key in ("t", "gyr", "acc", "mag", "movement"):
        np.testing.assert_array_equal(getattr(back, key), getattr(rec, key), err_msg=key)
    np.testing.assert_allclose(back.quat_true, rec.quat_true, rtol=0, atol=1e-15)
    assert (back.frame, back.name, back.meta) == ("NED", "dispatch", {"k": "v"})
    is_csv = name.lower().endswith(".csv")
    assert (tmp_path / name).read_bytes().startswith(b"# margtrack-recording") == is_csv


@pytest.mark.parametrize("name", ["r.h5", "r.csv"])
def test_quat_true_round_trip_is_bit_exact(tmp_path: Path, name: str) -> None:
    rec = _recording(400)
    write(rec, tmp_path / name)
    np.testing.assert_array_equal(read(tmp_path / name).quat_true, rec.quat_true)


def test_hdf5_with_imu_gyr_is_read_as_broad(tmp_path: Path) -> None:
    n = 5
    with h5py.File(tmp_path / "trial.hdf5", "w") as f:
        f["imu_gyr"] = np.zeros((n, 3))
        f["imu_acc"] = np.tile([0.0, 0.0, 9.81], (n, 1))
        f["imu_mag"] = np.ones((n, 3))
        f["opt_quat"] = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        f["movement"] = np.ones(n, dtype=bool)
        f.attrs["sampling_rate"] = 200.0
    rec = read(tmp_path / "trial.hdf5")
    assert rec.name == "trial" and rec.meta["sampling_rate"] == 200.0
    np.testing.assert_array_equal(rec.t, np.arange(n) / 200.0)


def test_folder_with_inertial_csv_is_read_as_xio(tmp_path: Path) -> None:
    folder = _xio_sensor(tmp_path / "body" / "knee")
    rec = read(folder)
    np.testing.assert_allclose(rec.acc[:, 2], 9.80665, rtol=1e-15)
    np.testing.assert_array_equal(rec.t, [0.0, 0.02, 0.04, 0.06])
    with pytest.raises(ValueError, match=r"several x-IMU3 sensor folders; .* read_xio_body"):
        read(tmp_path / "body")
    with pytest.raises(ValueError, match=r"looks like an x-IMU3 export: use read\(.*knee"):
        read(folder / "Inertial.csv")
    (tmp_path / "plain").mkdir()
    with pytest.raises(ValueError, match=r"plain holds no recording: a folder is read as one "
                       r"recording when it holds an x-IMU3 export \(Inertial\.csv\)"):
        read(tmp_path / "plain")


def test_foreign_csv_needs_a_mapping(tmp_path: Path) -> None:
    p = tmp_path / "log.csv"
    p.write_text("gx,gy,gz,ax,ay,az\n0,0,0,0,0,9.8\n0,0,0,0,0,9.8\n")
    # the columns and the flags that map them (issue 18: no Python-only hint, no stray brace)
    with pytest.raises(ValueError, match=r"log\.csv is not a margtrack CSV; the file has columns "
                       r"\['gx', .*--column gyr=gx,gy,gz --column acc=ax,ay,az"):
        read(p)
    rec = read(p, columns={"gyr": ["gx", "gy", "gz"], "acc": ["ax", "ay", "az"]}, rate_hz=10.0)
    np.testing.assert_array_equal(rec.t, [0.0, 0.1])


def test_unsupported_and_missing_paths(tmp_path: Path) -> None:
    (tmp_path / "r.dat").write_text("x")  # .txt is a table now (issue 18)
    with pytest.raises(ValueError, match=r"unsupported extension '\.dat'; supported: \.h5, \.hdf5"):
        read(tmp_path / "r.dat")
    with pytest.raises(ValueError, match=r"extension '\.mat'; use one of \.h5, \.hdf5, \.csv"):
        write(_recording(), tmp_path / "r.mat")
    assert not (tmp_path / "r.mat").exists()
    with pytest.raises(FileNotFoundError, match=r"no such file or folder: .*gone\.h5"):
        read(tmp_path / "gone.h5")
    (tmp_path / "fake.h5").write_text("not hdf5")
    with pytest.raises(ValueError, match=r"fake\.h5 is not a readable HDF5 file"):
        read(tmp_path / "fake.h5")


def test_public_names() -> None:
    for name in mio.__all__:
        assert callable(getattr(mio, name)), name
    assert {"read", "write", "read_broad", "read_xio_sensor", "write_estimate_hdf5"} <= set(
        mio.__all__)
