"""``margtrack live`` through a Typer app mounting ``live_command`` as the lead's cli.py does."""

from __future__ import annotations

import re
import threading

import pytest
import typer
from typer.testing import CliRunner

from margtrack.cli.live import live_command

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
    # session time: 0 at the first frame (device clock 917.43 s)
    assert "calibration: calibrated on 0.00-0.98 s" in result.output
    assert not [t for t in threading.enumerate() if t.name.startswith("margtrack-live")]


def test_headless_no_mag_replay_chains_the_joints_and_calibrates_on_the_still_start(
        xio_folder, tmp_path):
    summary = tmp_path / "summary.json"
    result = runner.invoke(app, ["live", "--replay", str(xio_folder), "--speed", "inf",
                                 "--headless", "--no-mag", "--summary", str(summary)])
    assert result.exit_code == 0, result.output
    out = " ".join(result.output.split())
    assert "no magnetometer: 6 joints constrained" in out
    for joint in ("left_hip", "left_knee", "left_ankle", "right_hip", "right_knee",
                  "right_ankle"):
        assert re.search(rf"- {joint}: parent \[[-0-9., ]+\] ± \[[0-9., ]+\], child .*"
                         r"\(estimated\); settled", out), out
    # on the still start, once every joint has settled (its frames chained with the
    # relative headings found in the walk after it), as without --no-mag
    assert "calibration: calibrated on 0.00-0.98 s" in out
    import json

    engine = json.loads(summary.read_text())["engine"]
    assert engine["no_mag"] is True and [j["joint"] for j in engine["joints"]][:2] == [
        "left_hip", "left_knee"]


def test_lever_arms_need_no_mag():
    result = runner.invoke(app, ["live", "--demo", "--headless", "--lever-arms", "a.json"])
    assert result.exit_code == 2 and "add --no-mag" in result.output


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
    assert re.search(r"serving http://127\.0\.0\.1:\d+/ ", result.output), result.output
    assert "?token=" not in result.output and "warning" not in result.output
    assert "frames" in result.output and "poses" in result.output
    assert not [t for t in threading.enumerate() if t.name.startswith("margtrack-live")]


def test_page_on_every_interface_prints_the_warning_and_the_token_url(tmp_path):
    """--host 0.0.0.0 binds every interface for 0.3 s only, then the session stops."""
    pytest.importorskip("viser", reason="the live view needs viser (pip install viser)")
    result = runner.invoke(app, ["live", "--demo", "--preset", "left_arm", "--port", "0",
                                 "--host", "0.0.0.0", "--duration", "0.3",
                                 "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "warning:" in result.output and "every network interface" in result.output
    assert re.search(r"serving http://\S+:\d+/\?token=[A-Za-z0-9_\-]{20,} ", result.output)


def test_udp_host_binds_the_listener_there():
    # 127.0.0.2 is loopback too (no warning) but not the default: the source reports it
    result = runner.invoke(app, ["live", "--udp", "0", "--sensors", "2", "--udp-host",
                                 "127.0.0.2", "--headless", "--duration", "0.2"])
    assert result.exit_code == 0, result.output
    assert "UDP 127.0.0.2:0: 2 sensors" in result.output
    assert "warning" not in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--udp", "0", "--sensors", "2", "--udp-host", "sensors.example"],
         "--udp-host must be an IP address of this machine"),
        (["--demo", "--token", "short", "--port", "0", "--duration", "0.1"],
         "12 to 256 characters"),
    ],
)
def test_bad_security_options_exit_2_with_a_message(args, message):
    result = runner.invoke(app, ["live", *args])
    assert result.exit_code == 2
    assert message in result.output
