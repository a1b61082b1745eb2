"""Issue 40, what a new user trips on in the first hour, through the command line."""

from __future__ import annotations

import dataclasses
import json
import re
import shlex

import numpy as np
import pytest
from typer.testing import CliRunner

import margtrack as mt
from margtrack import io, methods
from margtrack.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def sim_file(tmp_path_factory):
    """10 s of simulated random motion at 100 Hz in SI units, with truth."""
    rec = mt.sim.simulate_motion("random", duration_s=10, rate_hz=100, seed=3)
    path = tmp_path_factory.mktemp("first_hour") / "sim.h5"
    io.write(rec, path)
    return path


def _invoke(*args):
    return runner.invoke(app, [str(a) for a in args], env={"COLUMNS": "200"})


def _one_line(text: str) -> str:
    return " ".join(text.split())


# -- 5. a mistyped parameter -------------------------------------------------------------
def test_a_mistyped_parameter_gets_the_close_name_not_the_list_and_no_class_name():
    wanted = r"^unknown parameter 'tau_acc'; did you mean tau_acc_s\?$"
    with pytest.raises(ValueError, match=wanted):
        methods.parse_params(methods.get("robust").params_type, ["tau_acc=2"])
    with pytest.raises(ValueError, match=r"did you mean max_gap_s\?"):
        methods.create("gyro", {"max_gap": 1.0})
    # nothing close: the valid names, still without the class's name
    with pytest.raises(ValueError, match=r"unknown parameter 'zzz'; the parameters are ") as info:
        methods.create("robust", ["zzz=1"])
    assert "Params" not in str(info.value) and "tau_acc_s" in str(info.value)
    result = _invoke("methods", "robust")  # keeps the CLI path honest too
    assert result.exit_code == 0


def test_run_with_a_mistyped_parameter_says_did_you_mean(sim_file, tmp_path):
    result = _invoke("run", sim_file, "-o", tmp_path / "o.h5", "-p", "tau_acc=2")
    assert result.exit_code == 2
    text = _one_line(result.output)
    assert "unknown parameter 'tau_acc'; did you mean tau_acc_s?" in text
    assert "RobustParams" not in text and "valid:" not in text


def test_methods_robust_describes_the_method_instead_of_pointing_at_a_docstring():
    result = _invoke("methods", "robust")
    assert result.exit_code == 0, result.output
    text = _one_line(result.output)
    assert "docstring" not in text
    assert text.startswith(
        "robust: margtrack's robust filter: bias-estimating, disturbance-rejecting MARG "
        "orientation."
    )
    listing = _one_line(_invoke("methods").output)
    assert "docstring" not in listing and "bias-estimating" in listing


# -- 3. states are not faults ------------------------------------------------------------
CLEAN_TRIAL = "02_undisturbed_slow_rotation_B.hdf5"  # robust flags no fault on it, only rest


def test_a_clean_broad_trial_reports_0_faults_and_its_rest_as_a_state(broad_folder, tmp_path):
    result = _invoke("run", broad_folder / CLEAN_TRIAL, "-o", tmp_path / "est.h5")
    assert result.exit_code == 0, result.output
    text = _one_line(result.output)
    # it read "flags: 20147 of 53240 samples (38 %): REST 20147 (first at sample 429)"
    assert "faults: 0 of 53240 samples; states: REST 20147 (38 %, first at sample 429)" in text


def test_batch_summary_counts_faults_and_rest_apart(broad_folder, tmp_path):
    from margtrack.batch.summary import read_summary_csv

    inputs = tmp_path / "in"
    inputs.mkdir()
    (inputs / CLEAN_TRIAL).symlink_to(broad_folder / CLEAN_TRIAL)
    result = _invoke("batch", inputs, "-o", tmp_path / "out", "--workers", "1")
    assert result.exit_code == 0, result.output
    (row,) = read_summary_csv(tmp_path / "out" / "summary.csv")
    assert row["status"] == "done"
    assert (row["fault_samples"], row["rest_samples"]) == (0, 20147)


# -- 1. timestamps in ms -----------------------------------------------------------------
@pytest.fixture(scope="module")
def phone_csv(tmp_path_factory):
    """The tutorial's phone.csv: time in ms, gyroscope in deg/s, acc in g, field in µT."""
    rec = mt.sim.simulate_motion("random", duration_s=30, rate_hz=100, seed=1)
    path = tmp_path_factory.mktemp("phone") / "phone.csv"
    table = np.column_stack([rec.t * 1000.0, np.degrees(rec.gyr), rec.acc / 9.80665, rec.mag])
    np.savetxt(path, table, delimiter=",", fmt="%.10g", comments="",
               header="time_ms,gx,gy,gz,ax,ay,az,mx,my,mz")
    return path


PHONE_MAP = ["--column", "t=time_ms", "--column", "gyr=gx,gy,gz", "--column", "acc=ax,ay,az",
             "--column", "mag=mx,my,mz", "--gyr-unit", "deg/s", "--acc-unit", "g"]


def test_run_refuses_ms_timestamps_with_the_time_unit_option(phone_csv, tmp_path):
    out = tmp_path / "nots.h5"
    for extra in ([], ["-p", "strict=true"]):
        result = _invoke("run", phone_csv, *PHONE_MAP, *extra, "-o", out)
        assert result.exit_code == 2, result.output
        text = _one_line(result.output)
        assert ("phone.csv: t advances by a median of 10 s per sample (0.1 Hz; t[1] - t[0] = "
                "10) while the gyroscope turns") in text
        assert text.endswith("the timestamps are probably in ms (100 Hz then): declare the "
                             "file's unit with --time-unit ms")
        assert "max_gap_s" not in text and not out.exists()
    result = _invoke("run", phone_csv, *PHONE_MAP, "--time-unit", "ms", "-o", out)
    assert result.exit_code == 0, result.output
    assert "faults: 0 of 3001 samples" in _one_line(result.output)


def test_info_warns_of_ms_timestamps_beside_the_rate(phone_csv):
    result = _invoke("info", phone_csv, *PHONE_MAP)
    assert result.exit_code == 0
    text = _one_line(result.output.replace("│", " "))  # a long value wraps in its cell
    assert "warning: " in text and "declare the file's unit with --time-unit ms" in text
    assert "0.100 Hz (median interval; timestamps probably in ms: --time-unit ms)" in text


def test_a_margtrack_hdf5_in_ms_is_refused_chunk_by_chunk(tmp_path):
    rec = mt.sim.simulate_motion("random", duration_s=10, rate_hz=100, seed=2)
    path = tmp_path / "ms.h5"
    io.write(dataclasses.replace(rec, t=rec.t * 1000.0), path)
    result = _invoke("run", path, "-o", tmp_path / "o.h5", "--chunk-samples", "400")
    assert result.exit_code == 2
    assert "--time-unit ms" in result.output and "read_kwargs" not in result.output
    ok = _invoke("run", path, "-o", tmp_path / "o.h5", "--time-unit", "ms")
    assert ok.exit_code == 0, ok.output


# -- 2. the column guess -----------------------------------------------------------------
ZEIT_HEADER = ("Zeit [ms];Gyro X [deg/s];Gyro Y [deg/s];Gyro Z [deg/s];Acc X [g];Acc Y [g];"
               "Acc Z [g]")


@pytest.fixture(scope="module")
def zeit_csv(tmp_path_factory):
    rec = mt.sim.simulate_motion("random", duration_s=10, rate_hz=100, seed=4)
    path = tmp_path_factory.mktemp("zeit") / "zeit.csv"
    table = np.column_stack([rec.t * 1000.0, np.degrees(rec.gyr), rec.acc / 9.80665])
    np.savetxt(path, table, delimiter=";", fmt="%.10g", comments="", header=ZEIT_HEADER)
    return path


def test_the_guessed_mapping_runs_as_pasted(zeit_csv, tmp_path):
    result = _invoke("run", zeit_csv, "-o", tmp_path / "z.h5")
    assert result.exit_code == 2
    text = _one_line(result.output)
    guess = re.search(r"map them with (.*) \(guessed from the names: check them\)", text)
    assert guess is not None, text
    flags = shlex.split(guess.group(1))
    assert flags == ["--column", "t=Zeit [ms]",
                     "--column", "gyr=Gyro X [deg/s],Gyro Y [deg/s],Gyro Z [deg/s]",
                     "--column", "acc=Acc X [g],Acc Y [g],Acc Z [g]",
                     "--time-unit", "ms", "--gyr-unit", "deg/s", "--acc-unit", "g"]
    assert "TIME" not in text and "read(" not in text  # no placeholder, no Python
    pasted = _invoke("run", zeit_csv, *flags, "-o", tmp_path / "z.h5")
    assert pasted.exit_code == 0, pasted.output
    info = _invoke("info", zeit_csv, *flags)
    assert info.exit_code == 0 and "'Gyro X [deg/s]'" in _one_line(info.output)


@pytest.mark.parametrize(("name", "unit"), [
    ("Zeit [ms]", "ms"), ("time_ms", "ms"), ("temps (ms)", "ms"), ("tiempo [us]", "us"),
    ("timestamp_ns", "ns"), ("t", None), ("Time (s)", None),
])
def test_time_words_of_the_usual_languages_with_their_units(name, unit):
    from margtrack.io.csv_layout import guess_columns, guess_units

    header = [name, "gx_dps", "gy_dps", "gz_dps", "ax_g", "ay_g", "az_g"]
    columns = guess_columns(header)
    assert columns["t"] == [name]
    expected = {"gyr": "deg/s", "acc": "g"} | ({"time": unit} if unit else {})
    assert guess_units(columns) == expected


# -- 4. command-line messages name commands and options ----------------------------------
_PYTHON = re.compile(r"\b[a-z_][a-z_.]*\((path|r'|\)|\.\.\.|[a-z_]+=)|margtrack\.io\.|"
                     r"read_kwargs|check_units=|in Python")


def _refused(*args) -> str:
    result = _invoke(*args)
    assert result.exit_code == 2, result.output
    text = _one_line(result.output)
    assert not _PYTHON.search(text), text
    return text


def test_cli_errors_name_commands_not_python_functions(xio_folder, broad_folder, sim_file,
                                                      phone_csv, zeit_csv, tmp_path):
    out = tmp_path / "out.h5"
    text = _refused("run", xio_folder, "-o", out)
    assert f"margtrack body {xio_folder} -o OUT/" in text
    assert f"margtrack run {xio_folder}/<sensor> -o OUT.h5" in text
    estimate = tmp_path / "est.h5"
    assert _invoke("run", sim_file, "-o", estimate).exit_code == 0
    assert "pass --force to replace it" in _refused("run", sim_file, "-o", estimate)
    for command in ("evaluate", "run"):
        args = (command, estimate) + (("-o", out) if command == "run" else ())
        text = _refused(*args)
        assert "is an orientation estimate file, not a recording" in text
        assert f"margtrack plot {estimate} --truth RECORDING -o OUT.png" in text
    text = _refused("run", broad_folder, "-o", out)
    assert f"margtrack batch {broad_folder} -o OUT/ runs them all" in text
    assert f"margtrack evaluate {broad_folder} scores them" in text
    empty = tmp_path / "empty"
    empty.mkdir()
    text = _refused("evaluate", empty)
    assert "holds no trials: margtrack evaluate FOLDER reads the .hdf5 recordings" in text
    text = _refused("run", empty, "-o", out)
    assert "holds no recording" in text
    _refused("run", phone_csv, "-o", out)  # units: options, not read_kwargs
    _refused("run", zeit_csv, "-o", out)  # the mapping: flags, not read(path, columns=...)
    _refused("info", xio_folder / "pelvis" / "Inertial.csv")


def test_batch_of_an_empty_folder_leaves_no_output_folder(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    text = _refused("batch", empty, "-o", tmp_path / "r")
    assert "no recording there" in text
    assert not (tmp_path / "r").exists()


# -- 6. the API's score equals evaluate's figure -----------------------------------------
def test_score_equals_the_figure_evaluate_prints(broad_folder, tmp_path):
    trial = broad_folder / "01_undisturbed_slow_rotation_A.hdf5"
    rec = io.read(trial)
    est = mt.create("default").run(rec)
    got = mt.score(est, rec)
    result = _invoke("evaluate", trial, "--json", tmp_path / "e.json")
    assert result.exit_code == 0, result.output
    figures = json.loads((tmp_path / "e.json").read_text())["trials"][trial.stem]
    for key in ("total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg"):
        assert getattr(got, key) == pytest.approx(figures[key], rel=1e-12)
    assert f"{got.total_rmse_deg:.2f}" == "1.54" and "1.54" in result.output
    assert got.n_samples == int(np.count_nonzero(rec.movement))
    # the README's former example scored every sample: 1.26 deg, not the benchmark's figure
    every = mt.summarize(mt.error_series(est.quat, rec.quat_true, est.frame, rec.frame))
    assert f"{every.total_rmse_deg:.2f}" == "1.26"


# -- 7. help text ------------------------------------------------------------------------
@pytest.mark.parametrize("command", [[], ["run"], ["batch"], ["evaluate"], ["body"], ["live"],
                                     ["calibrate", "accel"], ["bench", "broad"], ["tune"]])
def test_help_shows_no_python_types_braces_or_default_default(command):
    result = _invoke(*command, "--help")
    assert result.exit_code == 0, result.output
    text = result.output
    for token in ("<bool>", "<str>", "<path>", "<int", "<list", "{", "[default: default]"):
        assert token not in text, (command, token)


def test_help_keeps_sentences_whole():
    text = _invoke("run", "--help").output
    assert "merged onto the gyroscope's timestamps" in text  # was broken after "the"
    assert "Usage: margtrack run [OPTIONS] PATHS..." in text


def test_body_and_live_share_the_heading_default_and_the_axis_spelling():
    body_help = _one_line(_invoke("body", "--help").output)
    live_help = _one_line(_invoke("live", "--help").output)
    for text in (body_help, live_help):
        assert "+x, -x, +y, -y, +z, -z or x,y,z" in text and "-z, an x-IMU3 on the sacrum" in text
        assert "0,0,-1" not in text
    assert "[default: pelvis]" in body_help and "Default pelvis, as in margtrack body" in live_help
