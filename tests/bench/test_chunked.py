"""run_file: a recording run and written chunk by chunk equals the whole run, file for file."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import h5py
import numpy as np
import pytest

import margtrack as mt
from margtrack import io, methods
from margtrack.accuracy import error_series, summarize
from margtrack.estimator.flags import FAULT_FLAGS, Flag, summary
from margtrack.io.chunks import open_chunks
from margtrack.io.csv import write_estimate_csv
from margtrack.io.estimate_writer import EstimateWriter, estimate_fields
from margtrack.io.hdf5 import write_estimate_hdf5
from margtrack.run.chunked import ROW_FIELDS, FileSummary, FlagTally, run_file

GAP_AT = 1500  # the first sample after the 2 s hole cut into the recording


@pytest.fixture(scope="module")
def rec() -> mt.Recording:
    """30 s of simulated random motion at 100 Hz with samples 1500-1699 removed (a gap)."""
    full = mt.sim.simulate_motion("random", duration_s=30, rate_hz=100, seed=2)
    keep = np.ones(full.n_samples, bool)
    keep[GAP_AT : GAP_AT + 200] = False
    return dataclasses.replace(
        full, t=full.t[keep], gyr=full.gyr[keep], acc=full.acc[keep], mag=full.mag[keep],
        quat_true=full.quat_true[keep], movement=full.movement[keep],
    )


@pytest.fixture(scope="module")
def files(rec, tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("chunked")
    out = {"h5": folder / "rec.h5", "csv": folder / "rec.csv"}
    io.write(rec, out["h5"])
    io.write(rec, out["csv"])
    return out


def _datasets(path: Path) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    with h5py.File(path, "r") as f:
        return {k: f[k][()] for k in f}, {k: f.attrs[k] for k in f.attrs}


def _assert_same_hdf5(a: Path, b: Path) -> None:
    data_a, attrs_a = _datasets(a)
    data_b, attrs_b = _datasets(b)
    assert sorted(data_a) == sorted(data_b)
    for key in data_a:
        assert data_a[key].dtype == data_b[key].dtype, key
        np.testing.assert_array_equal(data_a[key], data_b[key], err_msg=key)
    assert attrs_a == attrs_b


@pytest.mark.parametrize("method", ["robust", "gradient", "bias-kf"])
@pytest.mark.parametrize("chunk", [GAP_AT, GAP_AT + 1, GAP_AT - 1, 611])
def test_chunked_hdf5_run_equals_the_whole_run(rec, files, tmp_path, method, chunk) -> None:
    # chunk = GAP_AT puts a chunk boundary exactly at the gap, GAP_AT +- 1 just around it
    whole = methods.create(method).run(rec)
    assert whole.flags[GAP_AT] & Flag.GAP  # the hole really is a flagged gap
    expected = tmp_path / "whole.h5"
    io.write_estimate(whole, expected)
    out = tmp_path / "chunked.h5"
    seen: list[tuple[int, int]] = []
    result = run_file(files["h5"], out, method, chunk_samples=chunk,
                      progress=lambda done, total: seen.append((done, total)))
    _assert_same_hdf5(out, expected)
    # the figures equal those of the whole run
    errors = summarize(error_series(whole.quat, rec.quat_true, whole.frame, rec.frame),
                       rec.movement)
    assert result.total_rmse_deg == pytest.approx(errors.total_rmse_deg, rel=1e-12)
    assert result.heading_rmse_deg == pytest.approx(errors.heading_rmse_deg, rel=1e-12)
    assert result.inclination_rmse_deg == pytest.approx(errors.inclination_rmse_deg, rel=1e-12)
    assert result.samples == rec.n_samples
    assert result.rate_hz == rec.rate_hz
    assert result.duration_s == rec.duration_s
    assert result.gaps == int(np.count_nonzero(whole.flags & Flag.GAP)) == 1
    assert result.fault_samples == int(np.count_nonzero(whole.flags & FAULT_FLAGS))
    assert result.rest_samples == int(np.count_nonzero(whole.flags & Flag.REST))
    mag_off = np.count_nonzero(whole.flags & (Flag.MAG_IGNORED | Flag.MAG_DISTURBED))
    assert result.mag_ignored_pct == pytest.approx(100.0 * mag_off / rec.n_samples, rel=1e-12)
    assert result.flag_summary == summary(whole.flags)
    assert result.method == method and result.frame == whole.frame
    n_chunks = -(-rec.n_samples // chunk)
    assert len(seen) == n_chunks and seen[-1] == (rec.n_samples, rec.n_samples)
    assert all(a[0] < b[0] for a, b in itertools.pairwise(seen))


@pytest.mark.parametrize("chunk", [GAP_AT, 997])
def test_chunked_csv_output_is_the_same_bytes(rec, files, tmp_path, chunk) -> None:
    whole = methods.create("robust").run(rec)
    expected = tmp_path / "whole.csv"
    io.write_estimate(whole, expected)
    for source in ("h5", "csv"):  # chunked reading, and a whole read run in chunks
        out = tmp_path / f"from_{source}.csv"
        run_file(files[source], out, "robust", chunk_samples=chunk)
        assert out.read_bytes() == expected.read_bytes()
    # the same bytes as the writer before streaming existed (one call on the whole run)
    outputs, _ = estimate_fields(whole)
    direct = tmp_path / "direct.csv"
    write_estimate_csv(direct, whole.t, whole.quat, outputs, method=whole.method,
                       frame=whole.frame, params=whole.params)
    assert direct.read_bytes() == expected.read_bytes()


def test_streamed_hdf5_equals_the_one_call_writer(rec, tmp_path) -> None:
    whole = methods.create("bias-kf").run(rec)
    outputs, attrs = estimate_fields(whole)
    direct = tmp_path / "direct.h5"
    write_estimate_hdf5(direct, whole.t, whole.quat, outputs, attrs)
    streamed = tmp_path / "streamed.h5"
    with EstimateWriter(streamed) as writer:
        for start in range(0, whole.n_samples, 400):
            part = slice(start, start + 400)
            writer.append(dataclasses.replace(
                whole, t=whole.t[part], quat=whole.quat[part], flags=whole.flags[part],
                outputs={k: v[part] for k, v in whole.outputs.items()},
            ))
    _assert_same_hdf5(streamed, direct)
    with h5py.File(streamed) as f:
        assert f["quat"].chunks is not None and f["quat"].maxshape == (None, 4)
        assert f.attrs["frame"] == whole.frame and f.attrs["method"] == "bias-kf"


def test_frame_conversion_and_no_truth(rec, tmp_path) -> None:
    path = tmp_path / "no_truth.h5"
    io.write(dataclasses.replace(rec, quat_true=None, movement=None), path)
    result = run_file(path, tmp_path / "ned.h5", "robust", frame="NED", chunk_samples=1000)
    assert result.total_rmse_deg is None and result.heading_rmse_deg is None
    whole = methods.create("robust").run(rec).in_frame("NED")
    with h5py.File(tmp_path / "ned.h5") as f:
        np.testing.assert_array_equal(f["quat"][()], whole.quat)
        assert f.attrs["frame"] == "NED"
    row = result.as_row()
    assert list(row) == list(ROW_FIELDS) and row["total_rmse_deg"] is None
    assert isinstance(result, FileSummary) and row["samples"] == rec.n_samples


def test_flag_tally_equals_summary() -> None:
    rng = np.random.default_rng(4)
    flags = np.where(rng.random(1000) < 0.05, rng.integers(1, 512, 1000), 0).astype(np.uint16)
    tally = FlagTally()
    for start in range(0, 1000, 77):
        tally.add(flags[start : start + 77])
    assert tally.text() == summary(flags)
    empty = FlagTally()
    empty.add(np.zeros(10, np.uint16))
    assert empty.text() == summary(np.zeros(10, np.uint16))


def test_truncated_hdf5_input_names_the_file(rec, files, tmp_path) -> None:
    broken = tmp_path / "truncated.h5"
    data = files["h5"].read_bytes()
    broken.write_bytes(data[: len(data) // 2])
    out = tmp_path / "out.h5"
    with pytest.raises(ValueError, match=r"truncated\.h5 is not a readable HDF5 file.*truncated"):
        run_file(broken, out, "robust")
    assert not out.exists() and list(tmp_path.glob(".out.h5.tmp-*")) == []


def _hdf5_with(rec: mt.Recording, path: Path, **changes: np.ndarray) -> Path:
    """``rec`` written to ``path``, then datasets replaced raw (bypassing validation)."""
    io.write(rec, path)
    with h5py.File(path, "r+") as f:
        for name, value in changes.items():
            del f[name]
            f.create_dataset(name, data=value)
    return path


def test_bad_samples_in_a_later_chunk_name_the_sample_of_the_file(rec, tmp_path) -> None:
    gyr = rec.gyr.copy()
    gyr[2345, 2] = np.nan
    nan_file = _hdf5_with(rec, tmp_path / "nan.h5", gyr=gyr)
    out = tmp_path / "out.h5"
    out.write_bytes(b"previous output")
    with pytest.raises(ValueError, match=r"nan\.h5: gyr has a non-finite value .* sample 2345"):
        run_file(nan_file, out, "robust", chunk_samples=1000, force=True)
    assert out.read_bytes() == b"previous output"  # the failed run changed nothing
    t = rec.t.copy()
    t[1000] = t[999]  # a repeated timestamp exactly at a chunk boundary
    with pytest.raises(ValueError, match=r"duplicate timestamp at sample 1000: t\[999\]"):
        run_file(_hdf5_with(rec, tmp_path / "dup.h5", t=t), out, "robust",
                 chunk_samples=1000, force=True)
    t = rec.t.copy()
    t[1500] = t[1400]  # going back inside a chunk
    with pytest.raises(ValueError, match=r"non-monotonic timestamp at sample 1500"):
        run_file(_hdf5_with(rec, tmp_path / "back.h5", t=t), out, "robust",
                 chunk_samples=1000, force=True)
    short = _hdf5_with(rec, tmp_path / "short.h5", acc=rec.acc[:-5])
    with pytest.raises(ValueError, match=r"short\.h5: dataset 'acc' has shape"):
        run_file(short, out, "robust", force=True)
    assert out.read_bytes() == b"previous output"
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_reader_options_and_units_on_chunked_hdf5(rec, files, tmp_path) -> None:
    with pytest.raises(ValueError, match="reader options \\['columns'\\] do not apply"):
        open_chunks(files["h5"], 100, columns={"gyr": ["a", "b", "c"]})
    with pytest.raises(ValueError, match="gyr_unit must be one of"):
        open_chunks(files["h5"], 100, gyr_unit="rpm")
    deg = _hdf5_with(rec, tmp_path / "deg.h5", gyr=np.degrees(rec.gyr))
    with pytest.raises(ValueError, match=r"probably in deg/s.*--gyr-unit deg/s"):
        run_file(deg, tmp_path / "a.h5", "robust", chunk_samples=1000)
    run_file(deg, tmp_path / "a.h5", "robust", chunk_samples=1000,
             read_kwargs={"gyr_unit": "deg/s"})
    run_file(files["h5"], tmp_path / "b.h5", "robust")
    a, _ = _datasets(tmp_path / "a.h5")
    b, _ = _datasets(tmp_path / "b.h5")
    np.testing.assert_allclose(a["quat"], b["quat"], rtol=0, atol=1e-9)


def test_chunks_of_a_csv_are_slices_of_the_whole(rec, files) -> None:
    with open_chunks(files["csv"], 1000) as source:
        assert source.whole is not None and source.n_samples == rec.n_samples
        parts = list(source)
    assert [start for start, _ in parts] == [0, 1000, 2000]
    np.testing.assert_array_equal(np.concatenate([p.gyr for _, p in parts]), rec.gyr)
    with open_chunks(files["h5"], 1000) as source:
        assert source.whole is None and source.rate_hz() == rec.rate_hz
        np.testing.assert_array_equal(np.concatenate([p.t for _, p in source]), rec.t)


def test_broad_trial_figures_equal_the_whole_run(broad_folder, tmp_path) -> None:
    trial = broad_folder / "01_undisturbed_slow_rotation_A.hdf5"
    rec = io.read(trial)
    whole = methods.create("robust").run(rec)
    errors = summarize(error_series(whole.quat, rec.quat_true, whole.frame, rec.frame),
                       rec.movement)
    result = run_file(trial, tmp_path / "est.h5", "robust", chunk_samples=10_000)
    assert result.total_rmse_deg == pytest.approx(errors.total_rmse_deg, rel=1e-12)
    assert result.inclination_rmse_deg == pytest.approx(errors.inclination_rmse_deg, rel=1e-12)
    assert result.rate_hz == rec.rate_hz and result.samples == rec.n_samples
    with h5py.File(tmp_path / "est.h5") as f:
        np.testing.assert_array_equal(f["quat"][()], whole.quat)


def test_an_offline_method_runs_the_whole_file_whatever_the_chunk_size(rec, files, tmp_path):
    # the smoother smooths over the whole recording: chunks would change (and refuse) it
    whole = methods.create("smoother").run(rec)
    out = tmp_path / "offline.h5"
    seen: list[tuple[int, int]] = []
    result = run_file(files["h5"], out, "smoother", chunk_samples=611,
                      progress=lambda done, total: seen.append((done, total)))
    np.testing.assert_array_equal(io.read_estimate(out).quat, whole.quat)
    assert seen == [(rec.n_samples, rec.n_samples)]
    errors = summarize(error_series(whole.quat, rec.quat_true, whole.frame, rec.frame),
                       rec.movement)
    assert result.total_rmse_deg == pytest.approx(errors.total_rmse_deg, rel=1e-12)
