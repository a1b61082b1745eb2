"""``margtrack info`` on estimate files, and the estimate reader behind it."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from margtrack import io, methods, sim
from margtrack.cli import app
from margtrack.io.estimate_reader import is_estimate_file, read_estimate

runner = CliRunner()


def _invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def _ok(*args):
    result = _invoke(*args)
    assert result.exit_code == 0, result.output
    return " ".join(result.output.split())


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A 4 s recording with a 0.5 s gap, and its bias-kf estimate as HDF5 and CSV (NED)."""
    folder = tmp_path_factory.mktemp("info")
    rec = sim.simulate_motion("random", duration_s=4.0, rate_hz=100.0, seed=1, frame="NED")
    keep = np.r_[0:150, 200:rec.n_samples]
    rec = dataclasses.replace(rec, **{k: getattr(rec, k)[keep] for k in (
        "t", "gyr", "acc", "mag", "quat_true", "movement") if getattr(rec, k) is not None})
    io.write(rec, folder / "rec.h5")
    est = methods.create("bias-kf").run(rec)
    io.write_estimate(est, folder / "est.h5")
    io.write_estimate(est, folder / "est.csv")
    # a CSV as margtrack wrote it before it stated the frame: no comment lines
    text = (folder / "est.csv").read_text().splitlines(keepends=True)
    (folder / "old.csv").write_text("".join(x for x in text if not x.startswith("#")))
    return {"folder": folder, "rec": rec, "est": est}


def test_info_reads_an_hdf5_estimate(files):
    est = files["est"]
    text = _ok("info", files["folder"] / "est.h5")
    assert "orientation estimate" in text
    assert "method │ bias-kf" in text
    assert f"body to {est.frame} (earth)" in text and "[w, x, y, z]" in text
    assert f"samples │ {est.n_samples}" in text
    assert "GAP 1 (first at sample 150)" in text
    bias_deg = np.degrees(est.outputs["gyr_bias_rad_s"])
    for k, axis in enumerate("xyz"):
        lo, hi = bias_deg[:, k].min(), bias_deg[:, k].max()
        assert f"{axis} {lo:+.4f}..{hi:+.4f} (last {bias_deg[-1, k]:+.4f})" in text
    assert "max_gap_s=0.25" in text


def test_info_reads_a_csv_estimate_and_says_the_frame_is_unstated(files, tmp_path):
    text = _ok("info", files["folder"] / "old.csv")
    assert "not stated in the file" in text and "GAP 1 (first at sample 150)" in text
    text = _ok("info", files["folder"] / "est.csv")  # what run writes now states it
    assert f"body to {files['est'].frame} (earth)" in text and "method │ bias-kf" in text
    assert "max_gap_s=0.25" in text  # the parameters, from the "# params=" line
    stated = tmp_path / "stated.csv"
    stated.write_text("# margtrack-estimate v1 method=bias-kf frame=NED\n"
                      + (files["folder"] / "old.csv").read_text())
    text = _ok("info", stated)
    assert "body to NED (earth)" in text and "method │ bias-kf" in text


def test_reader_round_trips_what_run_wrote(files):
    est = files["est"]
    for name in ("est.h5", "est.csv"):
        got = read_estimate(files["folder"] / name)
        np.testing.assert_array_equal(got.t, est.t)
        np.testing.assert_array_equal(got.quat, est.quat)  # repr floats: exact in CSV too
        np.testing.assert_array_equal(got.flags, est.flags)
        np.testing.assert_array_equal(got.outputs["gyr_bias_rad_s"],
                                      est.outputs["gyr_bias_rad_s"])
    assert read_estimate(files["folder"] / "est.h5").estimate().frame == est.frame
    assert read_estimate(files["folder"] / "est.csv").estimate().frame == est.frame
    with pytest.raises(ValueError, match="does not say its earth frame"):
        read_estimate(files["folder"] / "old.csv").estimate()
    assert read_estimate(files["folder"] / "old.csv").estimate("ned").frame == "NED"


def test_recordings_are_not_estimates(files, tmp_path):
    assert is_estimate_file(files["folder"] / "est.h5")
    assert is_estimate_file(files["folder"] / "est.csv")
    assert not is_estimate_file(files["folder"] / "rec.h5")
    io.write(files["rec"], tmp_path / "rec.csv")
    assert not is_estimate_file(tmp_path / "rec.csv")
    assert "truth" in _ok("info", files["folder"] / "rec.h5")  # the recording table
    with pytest.raises(ValueError, match="is not an estimate \\(a margtrack recording\\)"):
        read_estimate(files["folder"] / "rec.h5")
    with pytest.raises(ValueError, match="margtrack recording: run `margtrack run`"):
        read_estimate(tmp_path / "rec.csv")
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_estimate(tmp_path / "missing.h5")


def test_bad_estimate_files(files, tmp_path):
    lines = (files["folder"] / "old.csv").read_text().splitlines()
    short = tmp_path / "short.csv"
    short.write_text("\n".join([lines[0], lines[1], ",".join(lines[2].split(",")[:-1] + [""])])
                     + "\n")
    with pytest.raises(ValueError, match="line 3: a value is not a number"):
        read_estimate(short)
    empty = tmp_path / "empty.csv"
    empty.write_text(lines[0] + "\n")
    with pytest.raises(ValueError, match="no data rows"):
        read_estimate(empty)
    flags = tmp_path / "flags.csv"
    col = lines[0].split(",").index("flags")
    row = lines[5].split(",")
    row[col] = "2.5"
    flags.write_text("\n".join([*lines[:5], ",".join(row), *lines[6:]]) + "\n")
    with pytest.raises(ValueError, match=r"flags at sample 4 is 2\.5"):
        read_estimate(flags)
    result = _invoke("info", flags)
    assert result.exit_code == 2 and "flags at sample 4" in result.output
    old = tmp_path / "v2.h5"
    with h5py.File(files["folder"] / "est.h5") as src, h5py.File(old, "w") as dst:
        for key, value in src.attrs.items():
            dst.attrs[key] = value
        dst.attrs["version"] = 2
        dst["t"], dst["quat"] = src["t"][()], src["quat"][()]
    with pytest.raises(ValueError, match="estimate version 2"):
        read_estimate(old)
    mismatch = tmp_path / "mismatch.h5"
    with h5py.File(files["folder"] / "est.h5") as src, h5py.File(mismatch, "w") as dst:
        for key, value in src.attrs.items():
            dst.attrs[key] = value
        dst["t"], dst["quat"] = src["t"][()], src["quat"][:-1]
    with pytest.raises(ValueError, match="quat has shape"):
        read_estimate(mismatch)


@pytest.mark.parametrize("name", ["bias-kf", "robust", "triad"])
def test_methods_prints_whole_defaults_and_help_on_one_row(name):
    from margtrack.estimator.params import specs

    result = _invoke("methods", name)
    assert result.exit_code == 0, result.output
    assert "…" not in result.output  # rich's ellipsis: nothing cut
    rows = result.output.splitlines()
    for spec in specs(methods.get(name).params_type):
        row = next(line for line in rows if line.startswith(f"│ {spec.name} "))
        cells = [c.strip() for c in row.split("│")[1:-1]]
        assert cells == [spec.name, repr(spec.default), spec.unit, spec.bounds_text(), spec.help]
