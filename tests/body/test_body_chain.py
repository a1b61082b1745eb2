"""``process_body(no_mag=True)``: the joint constraint down the chain against the commanded angles.

A simulated walk (margtrack.live.simulator: accelerometers measure each sensor's own
acceleration, so the joint centres are consistent) with no magnetometer: chaining every
segment to its parent across the joint keeps the knee and hip angles on the truth, where
one 6-D filter per sensor lets the segments' headings drift apart.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from body_sim import pelvis_forward_axis, recordings, simulation, truth_deg

from margtrack import body
from margtrack import quaternion as quat
from margtrack.body.chain import chain_orientations, joint_name
from margtrack.body.skeleton import Skeleton

SEGMENTS = ("pelvis", "left_thigh", "left_shank", "right_thigh", "right_shank")


@pytest.fixture(scope="module")
def sim():
    return simulation()


@pytest.fixture(scope="module")
def no_mag(sim):
    """20 s (2 s standing, then walking), pelvis and both thighs and shanks, no magnetometer."""
    return {k: replace(r, mag=None) for k, r in recordings(sim, 2000).items() if k in SEGMENTS}


def _rms_after_pose(sim, result) -> dict[str, np.ndarray]:
    truth = truth_deg(sim, result.t_s)
    after = slice(result.window.stop, None)
    return {j: np.sqrt(np.mean((result.angles.degrees(j)[after] - truth[j][after]) ** 2,
                               axis=0)) for j in result.angles.names}


@pytest.mark.kernel
def test_constrained_angles_stay_on_the_truth_where_independent_6d_filters_drift(
        sim, no_mag) -> None:
    axis = pelvis_forward_axis(sim)
    chained = body.process_body(no_mag, forward_axis=axis, no_mag=True, offline=True)
    free = body.process_body(no_mag, forward_axis=axis)  # one 6-D filter per sensor
    assert chained.window == slice(0, 100)  # the still start, as with magnetometers
    err, err_free = _rms_after_pose(sim, chained), _rms_after_pose(sim, free)
    assert set(err) == {f"{s}_{j}" for s in ("left", "right") for j in ("hip", "knee")}
    for joint in err:
        # the filters' own error, as with magnetometers (test_body_workflow: < 1.5 deg)
        assert err[joint].max() < 2.0, (joint, err[joint])
    for side in ("left", "right"):
        knee, knee_free = err[f"{side}_knee"], err_free[f"{side}_knee"]
        # the shank's heading drifts against the thigh's: flexion turns into abduction
        assert np.linalg.norm(knee_free) > 8.0, knee_free
        assert np.linalg.norm(knee) < np.linalg.norm(knee_free) / 5, (knee, knee_free)
    names = [j.joint for j in chained.constrained]
    assert names == ["left_hip", "left_knee", "right_hip", "right_knee"]
    for j in chained.constrained:
        assert j.method == "joint_offline" and j.lever_arms.source == "estimated"
        assert j.lever_arms.residual_m_s2 < 0.2  # the sim's noise, no model error
        assert np.all(j.lever_arms.std_m < 0.02)
    lines = chained.summary()
    head = lines.index(next(x for x in lines if x.startswith("constrained joints (offline")))
    assert lines[head + 1].split()[:2] == ["left_hip", "pelvis"]
    assert "±" in lines[head + 1] and lines[head + 2].split()[0] == "left_thigh"
    assert all("not used" in x for x in lines[3:3 + len(SEGMENTS)])
    assert not free.constrained and not any(x.startswith("constrained") for x in free.summary())


def test_a_given_magnetometer_is_ignored(sim, no_mag) -> None:
    # a magnetometer next to a magnet (a constant offset of 3 field strengths): not used
    disturbed = {k: replace(r, mag=np.tile([150.0, -20.0, 40.0], (r.n_samples, 1)))
                 for k, r in no_mag.items()}
    axis = pelvis_forward_axis(sim)
    a = body.process_body(no_mag, forward_axis=axis, no_mag=True, offline=True)
    b = body.process_body(disturbed, forward_axis=axis, no_mag=True, offline=True)
    np.testing.assert_allclose(b.q_sensor, a.q_sensor, atol=1e-12)
    assert not any("magnetometer unusable" in n for n in a.notes)


@pytest.mark.kernel
def test_online_chain_finds_the_relative_orientations_once_the_joints_move(sim, no_mag) -> None:
    skeleton = Skeleton.from_segments(SEGMENTS)
    sensors = list(skeleton.names)
    t = no_mag["pelvis"].t
    chain = chain_orientations(skeleton, sensors, no_mag, t, "default", {}, "ENU")
    q_true, _ = sim.sensor_truth(t)
    q_true = q_true[[sim.skeleton.names.index(n) for n in sensors]]
    moving = t > 4.0  # walking for 1 s (2 s standing, 1 s ramp)
    for i in range(1, len(sensors)):
        p = skeleton.parents[i]
        rel = quat.multiply(quat.conjugate(chain.q[:, p]), chain.q[:, i])
        e = quat.multiply(rel, quat.conjugate(quat.multiply(quat.conjugate(q_true[p]),
                                                            q_true[i])))
        err = np.degrees(2 * np.arccos(np.clip(np.abs(e[moving, 0]), 0, 1)))
        assert np.sqrt(np.mean(err**2)) < 2.5, (sensors[i], np.sqrt(np.mean(err**2)))
    assert [j.method for j in chain.joints] == ["joint_online"] * 4
    assert chain.method == "robust" and chain.q.shape == (t.size, 5, 4)


def test_joint_names() -> None:
    skeleton = Skeleton.from_segments(["pelvis", "trunk", "right_thigh", "right_shank",
                                       "right_foot"])
    names = {skeleton.names[i]: joint_name(skeleton, i) for i in range(1, len(skeleton))}
    assert names == {"trunk": "pelvis-trunk", "right_thigh": "right_hip",
                     "right_shank": "right_knee", "right_foot": "right_ankle"}


@pytest.mark.kernel
def test_bad_input_names_the_joint_and_the_fix(sim, no_mag) -> None:
    with pytest.raises(ValueError, match=r"heading 'north' needs the magnetometers.*"
                                         r"--heading pelvis"):
        body.process_body(no_mag, heading="north", no_mag=True)
    with pytest.raises(ValueError, match=r"offline \(--offline\) .* with --no-mag"):
        body.process_body(no_mag, offline=True)
    # online, the relative headings are found once the joints move (the walk: from 2 s on),
    # and this walk stands still only before: no pose to calibrate on
    axis = pelvis_forward_axis(sim)
    with pytest.raises(ValueError, match=r"no still 1 s found for the reference pose after "
                                         r"3\.\d\d s: with --no-mag the online .* use --offline"):
        body.process_body(no_mag, forward_axis=axis, no_mag=True)
    with pytest.raises(ValueError, match=r"pose window from 0\.50 s: .* a pose before then "
                                         r"calibrates with them not yet found; use --offline"):
        body.process_body(no_mag, forward_axis=axis, pose_window=(0.5, 1.5), no_mag=True)
    # a shank whose thigh has no sensor: no joint to tie it to
    gap = {k: r for k, r in no_mag.items() if k != "left_thigh"}
    with pytest.raises(ValueError, match="left_shank needs left_thigh"):
        body.process_body(gap, no_mag=True)


@pytest.mark.kernel
def test_a_still_recording_has_no_lever_arms_and_says_which_joint() -> None:
    still = simulation(still_s=30.0)
    recs = {k: replace(r, mag=None) for k, r in recordings(still, 400).items()
            if k in SEGMENTS}
    with pytest.raises(ValueError, match=r"--no-mag: joint left_hip \(pelvis -> left_thigh\): "
                                         r"the sensors hardly rotate"):
        body.process_body(recs, no_mag=True)
