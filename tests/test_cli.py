"""The margtrack command end to end: simulate, info, run, evaluate, errors."""

from __future__ import annotations

import json

import h5py
import numpy as np
from typer.testing import CliRunner

from margtrack import io, methods
from margtrack.cli import app

runner = CliRunner()


def _ok(args):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.output


def test_methods_lists_the_registry():
    out = _ok(["methods"])
    for name in methods.available():
        assert name in out
    assert "(default)" in out


def test_noise_free_simulation_is_tracked_exactly_by_gyro_integration(tmp_path):
    rec_path = tmp_path / "sim.h5"
    _ok(["simulate", "-o", rec_path, "--duration", "20", "--no-noise", "--seed", "4"])
    out_json = tmp_path / "gyro.json"
    _ok(["evaluate", rec_path, "--method", "gyro", "--json", out_json])
    report = json.loads(out_json.read_text())
    assert report["method"] == "gyro"
    assert set(report["mean"]) == {"total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg"}
    (trial,) = report["trials"].values()
    assert trial["total_rmse_deg"] < 1e-6
    assert report["mean"]["total_rmse_deg"] == trial["total_rmse_deg"]


def test_noisy_simulation_drifts(tmp_path):
    rec_path = tmp_path / "noisy.csv"
    _ok(["simulate", "-o", rec_path, "--duration", "30", "--seed", "1"])
    out_json = tmp_path / "gyro.json"
    _ok(["evaluate", rec_path, "--method", "gyro", "--json", out_json])
    total = json.loads(out_json.read_text())["mean"]["total_rmse_deg"]
    # MEMS gyro bias of about 0.4 deg/s over 30 s: degrees, not micro-degrees
    assert 0.5 < total < 30.0


def test_run_writes_t_and_quat_equal_to_the_api(tmp_path):
    rec_path = tmp_path / "sim.h5"
    _ok(["simulate", "-o", rec_path, "--duration", "5", "--motion", "limb"])
    out = tmp_path / "est.h5"
    text = _ok(["run", rec_path, "--method", "triad", "-o", out, "--frame", "NED"])
    assert "against the truth" in text
    rec = io.read(rec_path)
    expected = methods.create("triad").run(rec).in_frame("NED")
    with h5py.File(out) as f:
        np.testing.assert_array_equal(f["t"][:], rec.t)
        np.testing.assert_allclose(f["quat"][:], expected.quat, atol=1e-15)
        assert f.attrs["frame"] == "NED"


def test_info_describes_a_recording(tmp_path):
    rec_path = tmp_path / "sim.csv"
    _ok(["simulate", "-o", rec_path, "--duration", "3", "--rate", "200", "--motion", "static"])
    out = _ok(["info", rec_path])
    assert "200.000 Hz" in out
    assert "601" in out
    assert "quat_true in ENU" in out


def test_errors_are_one_line_with_exit_code_2(tmp_path):
    result = runner.invoke(app, ["info", str(tmp_path / "missing.h5")])
    assert result.exit_code == 2
    assert "no such file" in result.output
    rec_path = tmp_path / "sim.h5"
    _ok(["simulate", "-o", rec_path, "--duration", "2"])
    result = runner.invoke(app, ["evaluate", str(rec_path), "--method", "nope"])
    assert result.exit_code == 2
    assert "unknown method 'nope'" in result.output
    result = runner.invoke(app, ["evaluate", str(rec_path), "-m", "gyro", "-p", "gain=2"])
    assert result.exit_code == 2
    assert "unknown parameter 'gain'" in result.output
    result = runner.invoke(app, ["simulate", "-o", str(tmp_path / "x.txt")])
    assert result.exit_code == 2
    assert "unsupported extension '.txt'" in result.output


def test_evaluate_broad_folder_prints_every_trial_and_the_mean(broad_folder, tmp_path):
    out_json = tmp_path / "broad.json"
    text = _ok(["evaluate", broad_folder, "--method", "gyro", "--json", out_json])
    report = json.loads(out_json.read_text())
    assert len(report["trials"]) == len(list(broad_folder.glob("*.hdf5")))
    totals = [t["total_rmse_deg"] for t in report["trials"].values()]
    assert report["mean"]["total_rmse_deg"] == np.mean(totals)
    assert "mean (" in text
    assert "undisturbed" in report["groups"]
    # unaided gyro integration drifts by degrees to tens of degrees on every trial
    assert all(1.0 < t < 90.0 for t in totals)


def test_run_reads_an_xio_sensor_folder_in_deg_s_and_g(tmp_path, xio_folder):
    folder = xio_folder / "pelvis"
    out = tmp_path / "pelvis.csv"
    _ok(["run", folder, "--method", "gyro", "-o", out])
    lines = out.read_text().splitlines()
    assert lines[0].startswith("# margtrack-estimate v1 method=gyro frame=")
    assert lines[3] == "t_s,quat_w,quat_x,quat_y,quat_z,flags"
    data = np.loadtxt(out, delimiter=",", skiprows=4)
    np.testing.assert_allclose(np.linalg.norm(data[:, 1:5], axis=1), 1.0, atol=1e-12)


def test_error_text_with_brackets_is_printed_verbatim(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    result = runner.invoke(app, ["info", str(bad)])
    assert result.exit_code == 2
    text = " ".join(result.output.split())
    assert "[--column mag=MX,MY,MZ]" in text  # not markup
    assert "read(" not in text  # the command line's fix, not Python's


def test_guided_calibration_file_improves_margtrack_run(tmp_path):
    proc = tmp_path / "procedure.h5"
    cal = tmp_path / "cal.json"
    _ok(["calibrate", "simulate", "-o", proc])
    _ok(["calibrate", "guided", "--source", proc, "-o", cal])
    raw = _ok(["run", proc, "-m", "gyro", "-o", tmp_path / "raw.h5"])
    fixed = _ok(["run", proc, "-m", "gyro", "-o", tmp_path / "cal.h5", "--calibration", cal])

    def total(text):
        return float(text.split("total ")[1].split(" deg")[0])

    # MEMS gyro bias of ~0.4 deg/s integrates to degrees over the minute; calibrated, the
    # remaining error is noise and bias walk
    assert total(fixed) < 0.5 < total(raw)


def test_info_and_run_report_a_saturated_magnetometer(tmp_path):
    from margtrack import io as mio
    from margtrack import sim

    magnet = sim.magnet_pass(t_center_s=5.0, duration_s=2.0, peak_ut=400.0, direction=(0, 1, 0))
    rec = sim.simulate(
        sim.static(10.0, 100.0),
        mag_disturbances=(magnet,),
        mag_errors=sim.SensorErrors(noise_density=0.05, saturation=100.0),
        seed=0,
    )
    path = tmp_path / "clipped.h5"
    mio.write(rec, path)
    first = int(np.flatnonzero(np.any(np.abs(rec.mag) >= 100.0, axis=1))[0])
    assert f"mag at ±100 from sample {first}" in _ok(["info", path])
    out = _ok(["run", path, "-o", tmp_path / "est.h5"])
    assert f"mag sits at its range limit ±100 from sample {first}" in out
