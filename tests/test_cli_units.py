"""The command line's unit options: files in deg/s, g, ms or nT refused or converted."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from margtrack import io, sim
from margtrack.accuracy import error_series, summarize
from margtrack.cli import app
from margtrack.recording import Recording

runner = CliRunner()
BROAD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "broad"


def _invoke(*args: object):
    return runner.invoke(app, [str(a) for a in args])


def _ok(*args: object) -> str:
    result = _invoke(*args)
    assert result.exit_code == 0, result.output
    return result.output


def _refused(*args: object) -> str:
    result = _invoke(*args)
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    return " ".join(result.output.split())  # the console wraps long lines


@pytest.fixture(scope="module")
def truth() -> Recording:
    # noise-free, so the estimate's error is the method's alone (hundredths of a degree)
    return sim.simulate_motion("random", duration_s=10.0, rate_hz=100.0, seed=3, noise=False)


@pytest.fixture(scope="module")
def files(truth: Recording, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("units")
    variants = {
        "si": truth,
        "deg_s": dataclasses.replace(truth, gyr=np.degrees(truth.gyr)),
        "g": dataclasses.replace(truth, acc=truth.acc / 9.80665),
        "nT": dataclasses.replace(truth, mag=truth.mag * 1e3),
        "ms": dataclasses.replace(truth, t=truth.t * 1e3),
    }
    out = {}
    for name, rec in variants.items():
        for ext in (".h5", ".csv"):
            path = root / f"{name}{ext}"
            io.write(rec, path)
            out[name + ext] = path
    return out


def _quat(path: Path) -> np.ndarray:
    with h5py.File(path) as f:
        return f["quat"][()]


def _error_deg(path: Path, truth: Recording) -> float:
    with h5py.File(path) as f:
        quat, frame = f["quat"][()], str(f.attrs["frame"])
    return summarize(error_series(quat, truth.quat_true, frame, truth.frame), truth.movement
                     ).total_rmse_deg


def test_run_refuses_gyr_in_deg_s_naming_the_option(files, tmp_path: Path) -> None:
    out = tmp_path / "est.h5"
    message = _refused("run", files["deg_s.h5"], "-o", out)
    assert "deg_s.h5: gyr " in message
    assert "probably in deg/s" in message
    assert "--gyr-unit deg/s" in message
    assert not out.exists()


def test_run_with_gyr_unit_equals_the_si_file(files, truth, tmp_path: Path) -> None:
    _ok("run", files["si.h5"], "-o", tmp_path / "si.h5")
    _ok("run", files["deg_s.h5"], "-o", tmp_path / "deg.h5", "--gyr-unit", "deg/s")
    np.testing.assert_allclose(_quat(tmp_path / "deg.h5"), _quat(tmp_path / "si.h5"),
                               rtol=0, atol=1e-9)
    assert _error_deg(tmp_path / "deg.h5", truth) < 1.0


def test_run_refuses_acc_in_g_and_converts_it(files, truth, tmp_path: Path) -> None:
    message = _refused("run", files["g.h5"], "-o", tmp_path / "g.h5")
    assert "median norm of 1.0" in message and "--acc-unit g" in message
    _ok("run", files["si.h5"], "-o", tmp_path / "si.h5")
    _ok("run", files["g.h5"], "-o", tmp_path / "g.h5", "--acc-unit", "g")
    np.testing.assert_allclose(_quat(tmp_path / "g.h5"), _quat(tmp_path / "si.h5"),
                               rtol=0, atol=1e-9)
    assert _error_deg(tmp_path / "g.h5", truth) < 1.0


def test_time_unit_ms_on_csv(files, tmp_path: Path) -> None:
    _ok("run", files["si.csv"], "-o", tmp_path / "si.h5")
    _ok("run", files["ms.csv"], "-o", tmp_path / "ms.h5", "--time-unit", "ms")
    with h5py.File(tmp_path / "si.h5") as a, h5py.File(tmp_path / "ms.h5") as b:
        np.testing.assert_allclose(b["t"][()], a["t"][()], rtol=1e-15, atol=0)
        np.testing.assert_allclose(b["quat"][()], a["quat"][()], rtol=0, atol=1e-9)
    # undeclared, the 1000-times-longer intervals are refused with the option (issue 40; it
    # ran with every interval a gap)
    result = _invoke("run", files["ms.csv"], "-o", tmp_path / "raw.h5")
    assert result.exit_code == 2 and "declare the file's unit with --time-unit ms" in " ".join(
        result.output.split())
    assert not (tmp_path / "raw.h5").exists()


def test_mag_unit_nt_reads_back_in_microtesla(files, truth, tmp_path: Path) -> None:
    field = np.median(np.linalg.norm(truth.mag, axis=1))
    assert "mag norm" in _ok("info", files["si.h5"])
    assert f"median {field:.2f}" in _ok("info", files["si.h5"])
    assert f"median {field:.2f}" in _ok("info", files["nT.h5"], "--mag-unit", "nT")
    assert f"median {1e3 * field:.2f}" in _ok("info", files["nT.h5"])
    _ok("run", files["si.h5"], "-o", tmp_path / "si.h5")
    _ok("run", files["nT.h5"], "-o", tmp_path / "nT.h5", "--mag-unit", "nT")
    np.testing.assert_allclose(_quat(tmp_path / "nT.h5"), _quat(tmp_path / "si.h5"),
                               rtol=0, atol=1e-9)


def test_info_warns_but_describes(files) -> None:
    result = _invoke("info", files["deg_s.csv"])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "warning:" in text and "--gyr-unit deg/s" in text
    assert "1001" in text  # the table is still printed
    clean = _invoke("info", files["deg_s.csv"], "--gyr-unit", "deg/s")
    assert "warning" not in clean.output and "units_converted" in clean.output


def test_evaluate_refuses_and_converts(files, tmp_path: Path) -> None:
    message = _refused("evaluate", files["deg_s.csv"], "--method", "gyro")
    assert "--gyr-unit deg/s" in message
    reports = {}
    for name, extra in (("si.csv", ()), ("deg_s.csv", ("--gyr-unit", "deg/s"))):
        out = tmp_path / f"{name}.json"
        _ok("evaluate", files[name], "--method", "gyro", "--json", out, *extra)
        reports[name] = json.loads(out.read_text())["mean"]
    assert reports["si.csv"]["total_rmse_deg"] < 1e-6  # noise-free gyro integration
    assert reports["deg_s.csv"]["total_rmse_deg"] == pytest.approx(
        reports["si.csv"]["total_rmse_deg"], abs=1e-9
    )


def test_evaluate_refuses_a_folder_trial_naming_it(files, tmp_path: Path) -> None:
    folder = tmp_path / "trials"
    folder.mkdir()
    (folder / "a.hdf5").write_bytes(files["si.h5"].read_bytes())
    (folder / "b.hdf5").write_bytes(files["g.h5"].read_bytes())
    message = _refused("evaluate", folder, "--method", "triad")
    assert "b.hdf5: acc has a median norm" in message and "--acc-unit g" in message


def test_tune_has_the_options(files, tmp_path: Path) -> None:
    grid = ("--method", "bachmann", "--grid", "gain=0.05,0.06")
    message = _refused("tune", files["g.h5"], *grid)
    assert "median norm of 1.0" in message and "--acc-unit g" in message
    result = _invoke("tune", files["g.h5"], *grid, "--acc-unit", "g")
    assert result.exit_code == 0, result.output


def test_unknown_unit_lists_the_valid_ones(files, tmp_path: Path) -> None:
    message = _refused("run", files["si.h5"], "-o", tmp_path / "o.h5", "--gyr-unit", "rpm")
    assert "gyr_unit must be one of ['deg/s', 'rad/s'], got 'rpm'" in message
    message = _refused("info", files["si.h5"], "--mag-unit", "gauss")
    assert "'G'" in message and "'nT'" in message


def test_a_converted_file_is_not_converted_twice(files, truth, tmp_path: Path) -> None:
    converted = tmp_path / "converted.h5"
    io.write(io.read(files["deg_s.h5"], gyr_unit="deg/s"), converted)  # SI, meta says so
    message = _refused("run", converted, "-o", tmp_path / "o.h5", "--gyr-unit", "deg/s")
    assert "already converted from deg/s" in message
    _ok("run", converted, "-o", tmp_path / "o.h5")


def test_every_file_command_declares_the_unit_options() -> None:
    for command in ("run", "evaluate", "info", "tune"):
        text = " ".join(_invoke(command, "--help").output.split())
        for option in ("--gyr-unit", "--acc-unit", "--mag-unit", "--time-unit"):
            assert option in text, (command, option)


def test_broad_slice_in_deg_s_is_refused(tmp_path: Path) -> None:
    if not (BROAD / "trials.json").is_file():
        pytest.skip(f"BROAD data not found at {BROAD} (it lives in ../shared beside the repo)")
    trial = io.read_broad(BROAD / "01_undisturbed_slow_rotation_A.hdf5")
    # 10 s from the first movement sample: the sensor turns at over 1 rad/s in this stretch
    start = int(np.flatnonzero(trial.movement)[0])
    part = trial.slice(start, start + 2860)
    assert 0.7 < np.abs(part.gyr).max() < 40.0  # in deg/s it exceeds 40, in rad/s it does not
    path = tmp_path / "broad_deg_s.h5"
    io.write(dataclasses.replace(part, gyr=np.degrees(part.gyr)), path)
    message = _refused("run", path, "-o", tmp_path / "o.h5")
    assert "probably in deg/s" in message and "--gyr-unit deg/s" in message
    _ok("run", path, "-o", tmp_path / "o.h5", "--gyr-unit", "deg/s")
