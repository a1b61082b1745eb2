"""Live guided calibration: the status machine (calibration/live_procedure.py), its use on a
running engine and page (live/calibration_panel.py) and in the terminal over real UDP."""

from __future__ import annotations

import json
import math
import socket
import threading
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from margtrack import quaternion as qt
from margtrack.calibration import Calibration, load_calibration
from margtrack.calibration.live_procedure import LiveProcedure
from margtrack.calibration.simulate_procedure import error_profile, procedure_steps
from margtrack.live.calibration_panel import CalibratedSource, GuidedRun, feed_chunks
from margtrack.live.engine import Engine
from margtrack.live.lines import format_line
from margtrack.live.replay import ReplaySource
from margtrack.live.udp import send_lines
from margtrack.sim import Hold, Rotate, simulate
from margtrack.sim.trajectories import rotation_sequence

_DOWN = np.array([0.0, 0.0, 1.0])  # NED

# when each mistake happens in the recording below, s
WRONG_START = (0.5, 3.0)  # +y down instead of +z down
WIGGLE = (5.5, 6.5)  # a 20 deg turn back and forth during the first hold
WRONG_TURN_HOLD = (16.5, 18.5)  # step 4 done about the wrong axis: +x down, held


def _mistakes_recording():
    """000's procedure with three mistakes (module constants), "raw" sensor errors, 100 Hz."""
    steps, _ = procedure_steps(20.0, 90.0, 3.0, 5.0)
    q0 = qt.from_axis_angle(_DOWN, np.radians(20.0))
    bx = qt.rotate(q0, [1.0, 0.0, 0.0])
    q_wrong = qt.multiply(qt.from_axis_angle(bx, np.radians(90.0)), q0)  # +y down
    bz = tuple(qt.rotate(q_wrong, [0.0, 0.0, 1.0]))  # horizontal while +y is down
    pre = [Hold(3.0), Rotate(tuple(bx), -90.0, 90.0)]  # then +z down
    first = [Hold(1.5), Rotate(tuple(_DOWN), 20.0, 40.0), Rotate(tuple(_DOWN), -20.0, 40.0),
             Hold(5.0)]
    wrong = [Rotate(bz, 90.0, 90.0), Hold(3.0), Rotate(bz, -90.0, 90.0), Hold(3.0)]
    sequence = pre + first + steps[1:3] + wrong + steps[3:]
    gyr, acc, mag = error_profile("raw")
    rec = simulate(rotation_sequence(sequence, 100.0, q0=q_wrong), frame="NED",
                   gyr_errors=gyr, acc_errors=acc, mag_errors=mag, seed=1)
    return rec, (gyr, acc, mag)


@pytest.fixture(scope="module")
def mistakes():
    return _mistakes_recording()


@pytest.fixture(scope="module")
def played(mistakes):
    """The recording through a LiveProcedure, with every status kept."""
    rec, _ = mistakes
    procedure = LiveProcedure()
    statuses = []
    for i in range(rec.n_samples):
        procedure.add_sample(rec.t[i], rec.gyr[i], rec.acc[i], rec.mag[i])
        statuses.append(procedure.status)
        if procedure.finished:
            break
    return procedure, statuses


def _between(statuses, span):
    return [s for s in statuses if span[0] <= s.t_s <= span[1]]


def test_finishes_despite_the_mistakes_with_the_true_calibration(mistakes, played) -> None:
    _, (gyr_err, acc_err, mag_err) = mistakes
    procedure, statuses = played
    assert procedure.finished and statuses[-1].finished and statuses[-1].hold_progress == 1.0
    cal = procedure.result().calibration
    # gyro null (1.5, -1, 2) deg/s from the 3 s hold in step 1: noise-limited to ~0.01 deg/s
    np.testing.assert_allclose(np.degrees(cal.gyr.b), np.degrees(gyr_err.bias), atol=0.02)
    np.testing.assert_allclose(cal.acc.b, acc_err.bias, atol=0.02)
    np.testing.assert_allclose(cal.mag.b, mag_err.bias, atol=1.5)


def test_wrong_start_pose_is_named(played) -> None:
    procedure, statuses = played
    during = _between(statuses, WRONG_START)
    assert during and all(s.down == "+y" and s.expected_down == "+z" for s in during)
    assert all(s.problem == "+z should point down (now +y is down)" for s in during)
    assert all(s.step == 1 for s in during)
    warnings = [e.message for e in procedure.events if e.kind == "warning"]
    assert "+y is down but step 1 needs +z down" in warnings


def test_moving_during_a_hold_says_hold_still_and_resets_progress(played) -> None:
    _, statuses = played
    before = [s for s in statuses if 5.0 <= s.t_s < WIGGLE[0]]
    assert before and max(s.hold_progress for s in before) > 0.2  # the hold had begun
    wiggle = _between(statuses, (WIGGLE[0] + 0.1, WIGGLE[1]))
    assert wiggle and all(s.problem == "hold still" and s.hold_progress == 0.0 for s in wiggle)
    # then a clean hold: progress rises monotonically to full and step 1 is done
    after = [s for s in statuses if WIGGLE[1] + 0.6 <= s.t_s and s.step == 1]
    progress = [s.hold_progress for s in after]
    assert progress and np.all(np.diff(progress) >= 0) and progress[-1] > 0.99
    assert all(s.hold_needed_s == 3.0 for s in after)
    step2 = [s for s in statuses if s.step == 2]
    assert step2[0].t_s == pytest.approx(after[-1].t_s + 0.01)
    assert step2[0].hold_progress == 0.0 and step2[0].hold_needed_s == 1.0  # a new bar


def test_a_wrong_turn_is_named_and_recovered(played) -> None:
    procedure, statuses = played
    held = _between(statuses, WRONG_TURN_HOLD)
    assert held and all(s.step == 4 and s.down == "+x" for s in held)
    assert any(s.problem.startswith("-y should point down after this turn (now +x is down)")
               for s in held)
    warnings = [e.message for e in procedure.events if e.kind == "warning"]
    assert any("go back to +y down (step 4's start)" in w for w in warnings)
    assert any(e.message.startswith("step 5: -y down") for e in procedure.events)


def test_status_line_shows_step_bar_and_problem(played) -> None:
    _, statuses = played
    line = _between(statuses, (1.0, 1.0))[0].line(10)
    assert line.startswith("step  1/18 [----------]   0%  down +y (want +z)")
    assert line.endswith("+z should point down (now +y is down)")


def test_bad_samples_are_counted_not_raised() -> None:
    procedure = LiveProcedure()
    rest = ([0.0, 0.0, 0.0], [0.0, 0.0, -9.81], [20.0, 0.0, 40.0])
    procedure.add_sample(0.0, *rest)
    procedure.add_sample(0.01, [math.nan, 0, 0], rest[1], rest[2])
    procedure.add_sample(0.01, rest[0], [0, 0, math.inf], rest[2])
    procedure.add_sample(-5.0, *rest)  # time went back
    procedure.add_sample(0.02, *rest)
    assert procedure.rejected == 3 and procedure.status.samples == 2
    assert "not after the previous" in procedure.last_rejection
    # two samples: not yet a full stillness window, so not still: "hold still"
    assert procedure.status.down == "+z" and procedure.status.problem == "hold still"


def test_calibrated_source_corrects_copies(played) -> None:
    rec, _ = _short_rest()
    source = ReplaySource(rec["t"], rec["gyr"], rec["acc"], rec["mag"], ["a", "b"],
                          speed=math.inf)
    raw_gyr = source.gyr.copy()
    cal = played[0].result().calibration
    wrapped = CalibratedSource(source, {1: cal})
    (chunk,) = wrapped.poll(0.0)
    np.testing.assert_array_equal(chunk.gyr[0], raw_gyr[0])  # sensor a: raw
    np.testing.assert_allclose(chunk.gyr[1], cal.gyr.correct(raw_gyr[1]), atol=1e-15)
    np.testing.assert_allclose(chunk.mag[1], cal.mag.correct(rec["mag"][1]), atol=1e-12)
    np.testing.assert_array_equal(source.gyr, raw_gyr)  # the replay's arrays untouched
    with pytest.raises(ValueError, match=r"sensor must be in 0\.\.1"):
        wrapped.set_calibration(2, cal)


def _short_rest():
    n = 50
    t = np.arange(n) / 100.0
    gyr = np.tile([0.02, -0.01, 0.03], (2, n, 1))
    acc = np.tile([0.1, 0.0, -9.7], (2, n, 1))
    mag = np.tile([20.0, 1.0, 40.0], (2, n, 1))
    return {"t": t, "gyr": gyr, "acc": acc, "mag": mag}, n


def test_guided_run_on_an_engine_saves_and_applies(mistakes, tmp_path) -> None:
    """Sensor 1 of a two-sensor stream does the procedure; the result is saved and applied."""
    rec, (gyr_err, _, _) = mistakes
    gyr = np.stack([np.zeros((rec.n_samples, 3)), rec.gyr])
    acc = np.stack([np.tile([0.0, 0.0, -9.81], (rec.n_samples, 1)), rec.acc])
    mag = np.stack([np.tile([20.0, 0.0, 40.0], (rec.n_samples, 1)), rec.mag])
    source = CalibratedSource(ReplaySource(rec.t, gyr, acc, mag, ["still", "calib"],
                                           speed=math.inf, chunk_frames=50))
    engine = Engine(source.info, "default", avatars=None)
    (tmp_path / "calibration_calib.json").write_text("{}")  # an older file is kept
    run = GuidedRun(engine, 1, source, tmp_path)
    with engine.start(source):
        assert engine.wait(120.0)
    assert run.status.finished and not run.active
    assert run.saved == tmp_path / "calibration_calib_2.json"
    assert (tmp_path / "calibration_calib.json").read_text() == "{}"
    saved = load_calibration(run.saved)
    np.testing.assert_allclose(np.degrees(saved.gyr.b), np.degrees(gyr_err.bias), atol=0.02)
    applied = source.calibration(1)
    assert applied is not None and source.calibration(0) is None
    np.testing.assert_array_equal(applied.gyr.b, saved.gyr.b)
    assert json.loads(run.saved.read_text())["source"].endswith("sensor calib")


def test_guided_run_needs_a_magnetometer() -> None:
    source = ReplaySource(np.arange(3) / 100, np.zeros((3, 3)), np.tile([0, 0, 9.8], (3, 1)))
    engine = Engine(source.info, "default", avatars=None)
    with pytest.raises(ValueError, match="needs a magnetometer"):
        GuidedRun(engine, 0, None, ".")


def test_cli_guided_live_over_udp(mistakes, tmp_path) -> None:
    """``margtrack calibrate guided --udp PORT``: a sender plays the procedure with mistakes
    (and junk lines); the command follows it, prints the steps and writes the file."""
    from margtrack.cli import app

    rec, (gyr_err, _, _) = mistakes
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    lines = [format_line(rec.t[i], "imu", rec.gyr[i], rec.acc[i], rec.mag[i])
             for i in range(rec.n_samples)]
    lines.insert(100, "not,a,line\n")
    lines.insert(200, format_line(0.5, "imu", [math.nan, 0, 0], [0, 0, -9.8], [1, 1, 1]))

    def sender() -> None:
        time.sleep(1.0)
        for k in range(0, len(lines), 25):
            send_lines(lines[k:k + 25], ("127.0.0.1", port), per_datagram=25)
            time.sleep(0.002)

    out = tmp_path / "imu.json"
    thread = threading.Thread(target=sender)
    thread.start()
    result = CliRunner().invoke(app, ["calibrate", "guided", "--udp", str(port), "--sensors",
                                      "imu", "--output", str(out), "--timeout", "60"])
    thread.join()
    assert result.exit_code == 0, result.output
    assert "+z should point down (now +y is down)" in result.output
    assert "go back to +y down" in result.output
    assert "rejected: 2 malformed lines" in result.output
    assert f"wrote {out}" in result.output.replace("\n", "")
    cal = load_calibration(out)
    np.testing.assert_allclose(np.degrees(cal.gyr.b), np.degrees(gyr_err.bias), atol=0.02)
    again = CliRunner().invoke(app, ["calibrate", "guided", "--udp", str(port), "--output",
                                     str(out), "--timeout", "1"])
    assert again.exit_code == 2 and "--force" in again.output


def test_feed_chunks_refuses_a_source_without_magnetometer() -> None:
    source = ReplaySource(np.arange(3) / 100, np.zeros((3, 3)), np.tile([0, 0, 9.8], (3, 1)),
                          speed=math.inf)
    with pytest.raises(ValueError, match="needs a magnetometer"):
        feed_chunks(LiveProcedure(), source.poll(0.0), 0)


def test_page_panel_shows_the_step_progress_and_problem(mistakes, tmp_path) -> None:
    """The page's panel on a real viser server (loopback): start, watch, cancel."""
    import types

    viser = pytest.importorskip("viser", reason="viser (live extra) is not installed")
    from margtrack.live.calibration_panel import attach

    rec, _ = mistakes
    n = 305  # the first 3.05 s: +y down instead of +z (the warning comes at 3 s)
    gyr = np.stack([np.zeros((n, 3)), rec.gyr[:n]])
    acc = np.stack([np.tile([0.0, 0.0, -9.81], (n, 1)), rec.acc[:n]])
    mag = np.stack([np.tile([20.0, 0.0, 40.0], (n, 1)), rec.mag[:n]])
    replay = ReplaySource(rec.t[:n], gyr, acc, mag, ["still", "calib"], speed=math.inf,
                          chunk_frames=20)
    engine = Engine(replay.info, "default", avatars=None)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        viewer = types.SimpleNamespace(engine=engine, server=server, out_dir=tmp_path)
        source = attach(viewer, replay)
        earlier = Calibration(source="an older calibration")
        source.set_calibration(1, earlier)
        panel = viewer.calibration_panel
        assert "press start" in panel.text()
        panel._sensor.value = "calib"
        panel.toggle()
        assert panel.run.sensor == 1 and panel._button.label == "Cancel guided calibration"
        assert source.calibration(1) is None  # lifted: the procedure needs raw samples
        source.open()
        while not source.finished:
            engine.push(source.poll(0.0))
        text = panel.text()
        assert text.startswith("**step 1 of 18**: step 1: place the sensor")
        assert "**+z should point down (now +y is down)**" in text
        assert "_+y is down but step 1 needs +z down_" in text
        time.sleep(0.5)  # the panel refreshes at 5 Hz
        assert panel._progress.value == 0.0 and panel._text.content == text
        panel.toggle()  # cancel
        assert not panel.run.active and "cancelled" in panel.text()
        assert source.calibration(1) is earlier  # restored
        panel.close()
    finally:
        server.stop()
