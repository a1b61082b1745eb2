"""A raw live recording of a ``--no-mag`` session replays without magnetometers, with the
session's lever arms (live/recording.py, live/live_replay.py, cli/live.py)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from margtrack.io.live_hdf5 import read_live_recording, write_live_recording
from margtrack.joint.lever_arms import LeverArms
from margtrack.live.avatars import identity_calibration
from margtrack.live.engine import Engine
from margtrack.live.protocol import Chunk
from margtrack.live.recording import RawRecorder
from margtrack.live.replay import LiveReplaySource
from margtrack.live.simulator import PeopleSimulation, SimulatorSource

SIM = PeopleSimulation(n_people=1, preset="lower", motion="walk", seed=3)
KNEE = [[0.0, -0.2, 0.0], [0.0, 0.18, 0.0]]  # m, given for the left knee only


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """12 s of a simulated walk through a --no-mag engine, recorded from its start."""
    src = SimulatorSource(SIM, speed=math.inf, duration_s=12.0)
    engine = Engine(src.info, "default", no_mag=True, heading="pelvis",
                    forward_axis=SIM.pelvis_forward_axis(),
                    lever_arms={"left_knee": LeverArms.given(KNEE)}, walking_root=True)
    engine.set_calibrations([dataclasses.replace(identity_calibration(SIM.skeleton),
                                                 offsets=SIM.mounting[0])])
    recorder = RawRecorder(engine)
    recorder.start()
    poses = []
    engine.subscribe(poses.append)
    src.open()
    while not src.finished:
        chunk = src.poll(0.0)[0]
        for i in range(0, chunk.n_frames, 9):  # batches of 9 frames
            sl = slice(i, i + 9)
            engine.push([Chunk(chunk.t_s[sl], chunk.sensors, chunk.gyr[:, sl],
                               chunk.acc[:, sl], chunk.mag[:, sl], chunk.arrival_s[sl])])
    path = tmp_path_factory.mktemp("nomag") / "session.hdf5"
    write_live_recording(recorder.stop(), path)
    return engine, poses, path


def test_the_recording_says_no_mag_and_the_lever_arms(session) -> None:
    engine, _, path = session
    meta = read_live_recording(path).meta
    assert meta["no_mag"] is True
    # in force at the start: the given knee only (the others were estimated after 3 s)
    assert list(meta["lever_arms"]) == ["left_knee"]
    assert meta["lever_arms"]["left_knee"]["parent_m"] == KNEE[0]
    assert meta["lever_arms"]["left_knee"]["source"] == "given"
    at_stop = meta["lever_arms_at_stop"]
    assert len(at_stop) == 6 and {v["source"] for k, v in at_stop.items()
                                  if k != "left_knee"} == {"estimated"}
    for name, arms in engine.lever_arms_in_force.items():  # floats round-trip exactly
        assert at_stop[name]["parent_m"] == arms.r_m[0].tolist()
        assert at_stop[name]["child_m"] == arms.r_m[1].tolist()


def test_the_replay_runs_no_mag_with_the_same_lever_arms_and_poses(session) -> None:
    engine, poses, path = session
    source = LiveReplaySource(read_live_recording(path))
    assert source.no_mag is True and list(source.lever_arms) == ["left_knee"]
    again = Engine(source.info, source.method, source.params, no_mag=source.no_mag,
                   lever_arms=source.lever_arms, heading="pelvis",
                   forward_axis=SIM.pelvis_forward_axis(), walking_root=True)
    replayed = []
    again.subscribe(replayed.append)
    again.start(source)
    assert again.wait(60.0)
    again.stop()
    first, second = engine.lever_arms_in_force, again.lever_arms_in_force
    assert list(first) == list(second) and len(first) == 6
    for name in first:  # the estimated ones estimated again on the same frames
        np.testing.assert_array_equal(second[name].r_m, first[name].r_m)
    assert len(replayed) == len(poses)
    np.testing.assert_array_equal(replayed[-1].q_segment, poses[-1].q_segment)
    assert np.hypot(*(poses[-1].root_m[0, :2] - engine.avatars.root_positions_m[0, :2])) > 1
    np.testing.assert_array_equal(replayed[-1].root_m, poses[-1].root_m)  # walked alike


def test_cli_replay_uses_the_session_choice_unless_a_flag_says_otherwise(session, tmp_path
                                                                         ) -> None:
    from margtrack.cli import app

    engine, _, path = session
    runner = CliRunner()
    out = tmp_path / "as_ran.json"
    ran = runner.invoke(app, ["live", "--replay", str(path), "--headless", "--speed", "inf",
                              "--summary", str(out)])
    assert ran.exit_code == 0, ran.output
    text = " ".join(ran.output.split())
    assert "the session ran with --no-mag; replaying with --no-mag (the session's)" in text
    assert "lever arms: the session's for left_knee" in text
    summary = json.loads(out.read_text())["engine"]
    assert summary["no_mag"] is True
    rows = {j["joint"]: j for j in summary["joints"]}
    for row in engine.joints:
        assert rows[row["joint"]]["lever_arms_m"] == row["lever_arms_m"]
    assert rows["left_knee"]["lever_arms_m"] == KNEE
    override = tmp_path / "with_mag.json"
    flagged = runner.invoke(app, ["live", "--replay", str(path), "--headless", "--speed",
                                  "inf", "--mag", "--summary", str(override)])
    assert flagged.exit_code == 0, flagged.output
    text = " ".join(flagged.output.split())
    assert "the session ran with --no-mag; replaying with --mag (from the command line)" in text
    assert "no_mag" not in json.loads(override.read_text())["engine"]


def test_explicit_lever_arms_win_and_an_older_recording_replays_with_mag(session, tmp_path
                                                                          ) -> None:
    from margtrack.cli import app

    _, _, path = session
    arms = tmp_path / "arms.json"
    other = [[0.01, -0.25, 0.0], [0.0, 0.2, 0.02]]
    arms.write_text(json.dumps({"left_knee": {"parent_m": other[0], "child_m": other[1]}}))
    out = tmp_path / "given.json"
    ran = CliRunner().invoke(app, ["live", "--replay", str(path), "--headless", "--speed",
                                   "inf", "--lever-arms", str(arms), "--summary", str(out)])
    assert ran.exit_code == 0, ran.output
    assert "lever arms: --lever-arms (1 joint(s))" in " ".join(ran.output.split())
    rows = {j["joint"]: j for j in json.loads(out.read_text())["engine"]["joints"]}
    assert rows["left_knee"]["lever_arms_m"] == other
    # a recording written before the session's choice was stored: no_mag unknown
    older = dataclasses.replace(read_live_recording(path), meta={}, path=None)
    source = LiveReplaySource(older)
    assert source.no_mag is None and source.lever_arms == {}
    old_path = write_live_recording(older, tmp_path / "older.hdf5")
    ran = CliRunner().invoke(app, ["live", "--replay", str(old_path), "--headless",
                                   "--speed", "inf"])
    assert ran.exit_code == 0, ran.output
    assert ("the session ran with an unrecorded magnetometer choice (--mag assumed); "
            "replaying with --mag (the default)") in " ".join(ran.output.split())
