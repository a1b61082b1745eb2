"""Issue 40, what a new user trips on in the first hour, through the command line."""

from __future__ import annotations

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
