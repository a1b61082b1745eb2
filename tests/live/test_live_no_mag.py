"""``--no-mag`` in the live engine: every segment chained to its parent across its joint.

The knee angles of a simulated walk streamed through the engine stay within a few degrees
of the commanded ones without any magnetometer, where each sensor's own filter (6-D, or
9-D in a disturbed field) does not; the joint stream equals the offline online filter
sample for sample; the input policy's bad cases (a NaN sample, a missing sensor, a gap)
stay with their joint.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from margtrack import body
from margtrack.joint import relative_orientation
from margtrack.joint.lever_arms import LeverArms
from margtrack.live.avatars import identity_calibration
from margtrack.live.engine import Engine
from margtrack.live.joint_chain import read_chain_lever_arms
from margtrack.live.joint_stream import JointStream
from margtrack.live.protocol import Chunk, iter_chunks
from margtrack.live.simulator import PeopleSimulation, SimulatorSource

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "joint"))
from chain_sim import angle_deg, simulate_chain

PEOPLE = PeopleSimulation(preset="lower", seed=3, still_s=2.0)
KNEES = ("left_knee", "right_knee")


def _walk(no_mag: bool, duration_s: float = 30.0, mag: str = "clean", edit=None,
          calibrate: str = "true"):
    """Run the simulated walk through the engine; (engine, t, knee errors (N, 2, 3) deg).

    mag: "clean", "absent" (the source has none) or "disturbed" (a magnet's constant field
    at both shank sensors). calibrate: "true" (the simulated mounting in force) or
    "start" (the engine's calibration on the first still second). ``edit(chunk)`` may
    return a changed chunk, a list of chunks, or None to drop it.
    """
    source = SimulatorSource(PEOPLE, speed=math.inf, duration_s=duration_s)
    info = source.info if mag != "absent" else dataclasses.replace(source.info, has_mag=False)
    engine = Engine(info, "default", no_mag=no_mag, calibrate_at_start=calibrate == "start",
                    heading="pelvis", forward_axis=PEOPLE.pelvis_forward_axis())
    if calibrate == "true":
        engine.set_calibrations([dataclasses.replace(identity_calibration(PEOPLE.skeleton),
                                                     offsets=PEOPLE.mounting[0])])
    poses = []
    engine.subscribe(poses.append)
    for chunk in iter_chunks(source):
        if mag == "absent":
            chunk = dataclasses.replace(chunk, mag=None)
        elif mag == "disturbed":
            m = chunk.mag.copy()
            m[2] += [30.0, 0.0, 0.0]  # µT in the sensor frame: a magnet strapped beside it
            m[5] += [0.0, 25.0, 0.0]
            chunk = dataclasses.replace(chunk, mag=m)
        chunks = [chunk] if edit is None else edit(chunk)
        for c in [] if chunks is None else (chunks if isinstance(chunks, list) else [chunks]):
            engine.push([c], now_s=float(c.t_s[-1]))
    engine.push([], now_s=1e9, flush=True)
    t = np.array([p.t_s for p in poses])
    q = np.stack([p.q_segment[0] for p in poses])
    assert np.isfinite(q).all()
    angles = body.joint_angles(PEOPLE.skeleton, q)
    truth, _, _ = PEOPLE.joint_angles_deg(t)
    err = np.stack([angles.degrees(k) - truth[k][0] for k in KNEES], axis=1)
    return engine, t, err


def test_joint_stream_equals_the_online_joint_filter_batch_by_batch():
    chain = simulate_chain(20.0, 100.0, seed=1)
    arms = LeverArms.given(chain.lever_arms_m)
    offline = relative_orientation(chain.parent, chain.child, lever_arms=arms)
    stream = JointStream(100.0, arms)
    t = chain.parent.t
    gyr = np.stack([chain.parent.gyr, chain.child.gyr])
    acc = np.stack([chain.parent.acc, chain.child.acc])
    rng = np.random.default_rng(0)
    rel, predicted, i = [], [], 0
    while i < t.size:  # batches of 1 to 8 samples, as the engine's
        j = min(i + int(rng.integers(1, 9)), t.size)
        r, p = stream.step(t[i:j], gyr[:, i:j], acc[:, i:j], np.zeros(j - i, bool),
                           np.zeros(j - i, bool))
        rel.append(r)
        predicted.append(p)
        i = j
    rel, predicted = np.concatenate(rel), np.concatenate(predicted)
    diff = angle_deg(rel, offline.quat)
    # a filtered sample is the same filter on the same samples: equal to rounding
    assert predicted.mean() < 0.6 and diff[~predicted].max() < 1e-4
    # the newest two of a batch are the gyroscopes' prediction from two samples before
    assert np.median(diff[predicted][20:]) < 0.2 and diff[predicted][100:].max() < 2.0
    assert stream.settled and stream.unmeasured == 0


def test_lever_arms_estimated_once_after_three_seconds_of_motion_then_frozen():
    chain = simulate_chain(30.0, 100.0, seed=1)
    stream = JointStream(100.0)
    t = chain.parent.t
    gyr = np.stack([chain.parent.gyr, chain.child.gyr])
    acc = np.stack([chain.parent.acc, chain.child.acc])
    rel, fitted_at = [], None
    for i in range(0, t.size, 5):
        n = min(5, t.size - i)
        r, _ = stream.step(t[i:i + n], gyr[:, i:i + n], acc[:, i:i + n], np.zeros(n, bool),
                           np.zeros(n, bool))
        rel.append(r)
        if fitted_at is None and stream.lever_arms is not None:
            fitted_at, first = t[i], stream.lever_arms
    assert stream.lever_arms is first  # frozen: estimated once
    assert first.source == "estimated" and stream.settled
    assert 3.0 <= stream.motion_s and fitted_at < 6.0  # 3 s of motion, the chain always moves
    err = angle_deg(np.concatenate(rel), chain.q_rel)
    assert np.sqrt(np.mean(err[-1000:] ** 2)) < 2.5  # the last 10 s, deg


@pytest.fixture(scope="module")
def walks():
    return {
        "no_mag": _walk(True, mag="absent"),
        "no_mag_disturbed": _walk(True, mag="disturbed"),
        "6d": _walk(False, mag="absent", calibrate="start"),
        "9d_disturbed": _walk(False, mag="disturbed"),
    }


def test_no_mag_knee_angles_stay_within_a_few_degrees_where_per_sensor_filters_do_not(walks):
    engine, t, err = walks["no_mag"]
    after = t >= 8.0  # 2 s still, the ramp, 3 s of motion for the lever arms
    assert np.abs(err[after]).max() < 3.0
    assert all(j["state"] == "settled" and j["lever_arms_source"] == "estimated"
               for j in engine.joints)
    assert [j["joint"] for j in engine.joints] == ["left_hip", "left_knee", "left_ankle",
                                                   "right_hip", "right_knee", "right_ankle"]
    # the magnetometer disturbed: --no-mag does not read it, so the same angles
    _, _, err2 = walks["no_mag_disturbed"]
    np.testing.assert_allclose(err2, err, atol=1e-9)
    # each sensor's own 6-D filter, calibrated on the still start: the sensors' headings are
    # unrelated (an earth-frame heading offset per sensor, which no body-frame offset absorbs)
    _, t6, err6 = walks["6d"]
    assert np.abs(err6[t6 >= 8.0]).max() > 3 * np.abs(err[after]).max()
    # each sensor's own 9-D filter in the disturbed field: the shanks' headings are wrong
    _, t9, err9 = walks["9d_disturbed"]
    assert np.abs(err9[t9 >= 8.0]).max() > 10.0


def test_calibration_waits_for_the_joints_then_uses_the_still_start():
    info = SimulatorSource(PEOPLE).info
    engine = Engine(info, "default", no_mag=True, calibrate_at_start=True, heading="pelvis",
                    forward_axis=PEOPLE.pelvis_forward_axis())
    assert engine.calibration_status.startswith("waiting for every joint to settle")
    summary = engine.summary()["engine"]
    assert summary["no_mag"] is True and len(summary["joints"]) == 6
    assert summary["joints"][0]["state"].startswith("estimating lever arms (0.0 of 3 s")
    with pytest.raises(ValueError, match="heading 'north' needs the magnetometers"):
        Engine(info, "default", no_mag=True)
    # the joints settle a few seconds into the walk; the frames kept meanwhile, chained with
    # the relative headings found since (the joint filter run backwards), calibrate on the
    # still second before the first step
    engine, t, err = _walk(True, duration_s=20.0, mag="absent", calibrate="start")
    assert engine.calibration_window_s[0] < 0.05
    assert np.abs(err[t >= 8.0]).max() < 5.0


def _drop(sensor: int, start_s: float, stop_s: float):
    def edit(chunk: Chunk):
        if not ((chunk.t_s >= start_s) & (chunk.t_s < stop_s)).any():
            return chunk
        out = []
        for k in range(chunk.n_frames):
            keep = np.ones(chunk.n_sensors, bool)
            if start_s <= chunk.t_s[k] < stop_s:
                keep[sensor] = False
            sl = slice(k, k + 1)
            out.append(Chunk(chunk.t_s[sl], chunk.sensors[keep], chunk.gyr[keep, sl],
                             chunk.acc[keep, sl], None, chunk.arrival_s[sl]))
        return out
    return edit


def test_bad_cases_stay_with_their_joint():
    def nan_at(chunk: Chunk):  # one NaN specific force and one NaN rate of the left shank
        hit = (chunk.t_s >= 12.0) & (chunk.t_s < 12.05)
        if hit.any():
            acc, gyr = chunk.acc.copy(), chunk.gyr.copy()
            acc[2, hit] = np.nan
            gyr[2, hit] = np.nan
            return dataclasses.replace(chunk, acc=acc, gyr=gyr)
        return chunk

    engine, t, err = _walk(True, duration_s=20.0, mag="absent", edit=nan_at)
    rows = {j["joint"]: j for j in engine.joints}
    # the samples within two of a bad one are not measured, on the shank's two joints only
    assert rows["left_knee"]["unmeasured_samples"] == rows["left_ankle"]["unmeasured_samples"]
    assert 5 <= rows["left_knee"]["unmeasured_samples"] <= 12
    assert rows["right_knee"]["unmeasured_samples"] == 0
    assert np.abs(err[t >= 8.0]).max() < 3.0

    # the left shank missing for 1 s: held, then stale (no rate, its orientation held);
    # its joints restart when it returns and find the relative heading again
    engine, t, err = _walk(True, duration_s=20.0, mag="absent", edit=_drop(2, 10.0, 11.0))
    rows = {j["joint"]: j for j in engine.joints}
    assert rows["left_knee"]["unmeasured_samples"] >= 100
    assert rows["right_knee"]["unmeasured_samples"] == 0
    right = np.abs(err[:, 1])
    assert right[t >= 8.0].max() < 3.0  # the other leg is untouched
    left = np.abs(err[:, 0])
    assert left[(t >= 8.0) & (t < 10.0)].max() < 3.0 and left[t >= 14.0].max() < 3.0

    # a gap of every sensor (0.5 s without frames): not integrated over, re-found after
    def gap(chunk: Chunk):
        keep = (chunk.t_s < 10.0) | (chunk.t_s >= 10.5)
        if keep.all():
            return chunk
        if not keep.any():
            return None
        return Chunk(chunk.t_s[keep], chunk.sensors, chunk.gyr[:, keep], chunk.acc[:, keep],
                     None, chunk.arrival_s[keep])

    engine, t, err = _walk(True, duration_s=20.0, mag="absent", edit=gap)
    assert not ((t > 10.0) & (t < 10.5)).any()
    assert np.abs(err[(t >= 8.0) & (t < 10.0)]).max() < 3.0
    assert np.abs(err[t >= 14.0]).max() < 3.0


def test_given_lever_arms_from_a_file_and_its_errors(tmp_path):
    path = tmp_path / "arms.json"
    path.write_text(json.dumps({"left_knee": {"parent_m": [0, -0.2, 0],
                                              "child_m": [0, 0.18, 0]}}))
    arms = read_chain_lever_arms(path)
    np.testing.assert_array_equal(arms["left_knee"].r_m, [[0, -0.2, 0], [0, 0.18, 0]])
    info = SimulatorSource(PEOPLE).info
    engine = Engine(info, "default", no_mag=True, lever_arms=arms, heading="pelvis")
    rows = {j["joint"]: j for j in engine.joints}
    assert rows["left_knee"]["lever_arms_source"] == "given"
    assert rows["right_knee"]["lever_arms_m"] is None  # estimated later
    with pytest.raises(ValueError, match="no joint of; its joints: left_hip"):
        Engine(info, "default", no_mag=True, lever_arms={"left_elbow": arms["left_knee"]},
               heading="pelvis")
    with pytest.raises(ValueError, match="give them with --no-mag"):
        Engine(info, "default", lever_arms=arms)
    path.write_text(json.dumps({"left_knee": {"parent": [0, 0, 0]}}))
    with pytest.raises(ValueError, match="expected JSON like"):
        read_chain_lever_arms(path)


def test_the_page_lists_the_constrained_joints_with_lever_arms_in_cm():
    from margtrack.live.viewer_panels import joints_lines

    rows = [{"person": "", "joint": "left_knee", "lever_arms_m": [[0.01, -0.2, 0.0],
                                                                  [0.0, 0.18, 0.005]],
             "lever_arms_std_m": [[0.001, 0.002, 0.003], [0.004, 0.005, 0.006]],
             "lever_arms_source": "estimated", "state": "settled"},
            {"person": "p1", "joint": "left_hip", "lever_arms_m": None,
             "lever_arms_std_m": None, "lever_arms_source": None,
             "state": "estimating lever arms (1.2 of 3 s of motion)"}]
    lines = joints_lines(rows)
    assert lines[0].startswith("no magnetometer: 2 joints constrained")
    assert lines[1] == ("- left_knee: parent [1.0, -20.0, 0.0] ± [0.1, 0.2, 0.3], child "
                        "[0.0, 18.0, 0.5] ± [0.4, 0.5, 0.6] (estimated); settled")
    assert lines[2] == ("- p1/left_hip: lever arms: not yet; estimating lever arms (1.2 of "
                        "3 s of motion)")
    assert "no body model" in joints_lines([])[0]


def test_the_chain_product_is_the_hamilton_product():
    from margtrack import quaternion as quat
    from margtrack.live.joint_chain import _product

    rng = np.random.default_rng(4)
    p, q = (quat.normalize(rng.normal(size=(50, 4))) for _ in range(2))
    np.testing.assert_allclose(_product(p, q), quat.multiply(p, q), atol=1e-15)


def test_without_a_body_model_no_mag_runs_each_sensor_6d():
    from margtrack import methods
    from margtrack.live.protocol import SourceInfo

    t, gyr, acc, mag = PEOPLE.signals(0, 300)
    info = SourceInfo(("a", "b"), 100.0, True, "two loose sensors")
    engine = Engine(info, "default", no_mag=True)  # no body: north is no question here
    assert engine.avatars is None and engine.joints == []
    got = []
    engine.subscribe(lambda p: got.append((p.t_s, p.q_sensor)))
    chunk = Chunk(t, np.arange(2), gyr[:2], acc[:2], mag[:2], np.zeros(t.size))
    engine.push([chunk], now_s=0.0, flush=True)
    ref = methods.create("default", rate_hz=100.0).run(gyr=gyr[:2], acc=acc[:2], mag=None,
                                                        t=t).quat
    t_pose, q = got[-1]
    k = int(np.searchsorted(t, t_pose))
    np.testing.assert_allclose(q, ref[:, k], atol=1e-9)  # the magnetometer never read
    assert engine.summary()["engine"]["joints"] == []
