"""``margtrack live`` through a Typer app mounting ``live_command`` as the lead's cli.py does."""

from __future__ import annotations

import threading

import pytest
import typer
from typer.testing import CliRunner

from margtrack.live.cli import live_command

app = typer.Typer()
app.command(name="live")(live_command)


@app.command(name="other")
def _other() -> None:  # a second command, so that "live" is a subcommand as in margtrack
    """Unused."""


runner = CliRunner()


def test_headless_replay_of_the_xio_body_tracks_and_calibrates(xio_folder):
    args = ["live", "--replay", str(xio_folder), "--speed", "inf", "--headless"]
    result = runner.invoke(app, [*args, "--method", "bachmann", "-p", "gain=0.5"])
    assert result.exit_code == 0, result.output
    assert "7 sensors, method bachmann" in result.output
    assert "928 frames" in result.output  # the sensors' common span at 50 Hz
    assert "calibration: calibrated on 917.43-918.41 s" in result.output
    assert not [t for t in threading.enumerate() if t.name.startswith("margtrack-live")]


def test_headless_demo_runs_for_the_given_duration():
    result = runner.invoke(app, ["live", "--demo", "--preset", "left_arm", "--motion", "wave",
                                 "--speed", "20", "--duration", "0.5", "--headless"])
    assert result.exit_code == 0, result.output
    assert "simulator: 1 person (wave, left_arm): 3 sensors" in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "choose exactly one source"),
        (["--demo", "--udp", "9000"], "got --demo, --udp"),
        (["--udp", "0"], "need --sensors"),
        (["--demo", "--motion", "dance"], "motion must be one of"),
        (["--demo", "--heading", "west"], "--heading must be north or pelvis"),
        (["--replay", "/no/such/folder"], "no such file or folder"),
        (["--demo", "--method", "bachmann", "-p", "gain=-1", "--headless"], "gain"),
    ],
)
def test_bad_options_exit_2_with_a_message(args, message):
    result = runner.invoke(app, ["live", *args])
    assert result.exit_code == 2
    assert message in result.output


def test_demo_serves_the_page_for_the_given_duration(tmp_path):
    pytest.importorskip("viser", reason="the live view needs viser (pip install viser)")
    result = runner.invoke(app, ["live", "--demo", "--preset", "lower", "--port", "0",
                                 "--duration", "1.0", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "serving http://127.0.0.1:0" in result.output
    assert "frames" in result.output and "poses" in result.output
    assert not [t for t in threading.enumerate() if t.name.startswith("margtrack-live")]
