"""The input policy through the command line: what `margtrack run` finds, says and writes."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

import margtrack as mt
from margtrack import io
from margtrack.calibration import Calibration, save_calibration
from margtrack.calibration.reference import ReferenceVectors
from margtrack.cli import app
from margtrack.estimator import Flag

runner = CliRunner()


def _invoke(args):
    return runner.invoke(app, [str(a) for a in args], env={"COLUMNS": "200"})


@pytest.fixture(scope="module")
def broken_file(tmp_path_factory):
    """30 s random motion with a 5 s gap at 15 s and a 1e300 gyro sample at 5 s."""
    rec = mt.sim.simulate_motion("random", duration_s=30, rate_hz=100, seed=2)
    keep = np.ones(rec.t.size, bool)
    keep[1500:2000] = False
    gyr = rec.gyr.copy()
    gyr[500, 1] = 1e300
    rec = dataclasses.replace(
        rec, t=rec.t[keep], gyr=gyr[keep], acc=rec.acc[keep], mag=rec.mag[keep],
        quat_true=rec.quat_true[keep],
        movement=None if rec.movement is None else rec.movement[keep],
    )
    path = tmp_path_factory.mktemp("policy") / "broken.h5"
    io.write(rec, path)
    return path


def test_run_reports_gaps_and_clipped_rates_and_writes_the_flags(broken_file, tmp_path):
    out = tmp_path / "est.h5"
    result = _invoke(["run", broken_file, "-o", out])
    assert result.exit_code == 0, result.output
    assert "faults: 2 of 2501 samples" in result.output
    assert "GAP 1 (first at sample 1500)" in result.output
    assert "GYR_CLIPPED 1 (first at sample 500)" in result.output
    with h5py.File(out) as f:
        flags = f["flags"][:]
        assert flags[1500] == Flag.GAP | Flag.INITIALISING and flags[500] == Flag.GYR_CLIPPED
        assert np.isfinite(f["quat"][:]).all()


def test_csv_output_carries_integer_flags(broken_file, tmp_path):
    out = tmp_path / "est.csv"
    result = _invoke(["run", broken_file, "-o", out, "-m", "gyro"])
    assert result.exit_code == 0, result.output
    lines = [x for x in out.read_text().splitlines() if not x.startswith("#")]
    header = lines[0].split(",")
    col = header.index("flags")
    assert lines[1 + 1500].split(",")[col] == str(int(Flag.GAP | Flag.INITIALISING))
    assert "flags=bits" in out.read_text().splitlines()[2]  # the units line says so


def test_strict_mode_refuses_and_names_the_first_bad_sample(broken_file, tmp_path):
    result = _invoke(["run", broken_file, "-o", tmp_path / "x.h5", "-p", "strict=true"])
    assert result.exit_code != 0
    assert "sample 500 is flagged GYR_CLIPPED" in result.output
    assert "Traceback" not in result.output


def test_the_calibration_reference_field_reaches_the_method(broken_file, tmp_path):
    cal = Calibration(
        reference=ReferenceVectors((0.0, 0.0, 9.81), (0.0, 25.0, -43.3), 9.81, 50.0, 60.0, 0.0)
    )
    path = save_calibration(cal, tmp_path / "cal.json")
    result = _invoke(["run", broken_file, "-o", tmp_path / "x.h5", "--calibration", path])
    assert result.exit_code == 0, result.output
    assert "sets mag_norm_ref=50" in result.output and "mag_dip_ref_deg=60" in result.output
    # -p wins over the file
    result = _invoke(["run", broken_file, "-o", tmp_path / "y.h5", "--calibration", path,
                      "-p", "mag_dip_ref_deg=55"])
    assert result.exit_code == 0, result.output
    with h5py.File(tmp_path / "y.h5") as f:
        assert '"mag_dip_ref_deg": 55' in f.attrs["params"]


def test_methods_name_lists_parameters_with_unit_range_and_help():
    result = _invoke(["methods", "robust"])
    assert result.exit_code == 0, result.output
    text = result.output
    assert "tau_acc_s" in text and "max_gap_s" in text
    assert "input policy and frame (every method)" in text
    row = next(line for line in text.splitlines() if "max_gap_s" in line)
    assert "0.25" in row and "│ s " in row and "> 0" in row and "restarts" in row
