"""Forward kinematics (000, eqs. 7, 11): hand-derived poses, scipy oracle, signs, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from margtrack import quaternion as quat
from margtrack.body import (
    Skeleton,
    body_axes,
    calibrate,
    joint_angles,
    positions,
    resample_orientations,
    track,
)

H = 1.75


def random_quats(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    return quat.normalize(rng.normal(size=(*shape, 4)))


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_reference_pose_gives_rest_positions_and_zero_angles(frame: str) -> None:
    rng = np.random.default_rng(10)
    sk = Skeleton.from_height(H, "full", frame)
    mount = random_quats(rng, (len(sk),))
    cal = calibrate(sk, mount)
    pose = track(sk, cal, mount)
    right, _, up = body_axes(frame)
    # hand-derived rest positions: right knee and right wrist
    knee = pose.joints_m[0, sk.index("right_shank")]
    np.testing.assert_allclose(knee, 0.0955 * H * right + 0.285 * H * up, atol=1e-12)
    wrist = pose.joints_m[0, sk.index("right_hand")]
    np.testing.assert_allclose(wrist, 0.1295 * H * right + (0.818 - 0.186 - 0.146) * H * up,
                               atol=1e-12)
    angles = joint_angles(sk, pose.q_segment)
    assert len(angles.names) == 10
    np.testing.assert_allclose(angles.angles_rad, 0.0, atol=1e-12)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_knee_flexion_of_30_deg_on_the_shank_sensor(frame: str) -> None:
    rng = np.random.default_rng(11)
    sk = Skeleton.from_height(H, "lower", frame)
    right, forward, up = body_axes(frame)
    mount = random_quats(rng, (len(sk),))
    cal = calibrate(sk, mount)
    q_true = quat.identity((len(sk),))
    shank = sk.index("left_shank")
    q_true[shank] = quat.from_axis_angle(right, np.radians(-30.0))  # shank swings back
    pose = track(sk, cal, quat.multiply(q_true, mount))
    # hand derivation: knee at (-hip_width/2) R + knee height U; the shank vector -L U turned
    # -30 deg about R becomes L (-sin 30 F - cos 30 U)
    length = (0.285 - 0.039) * H
    knee = -0.0955 * H * right + 0.285 * H * up
    ankle = knee + length * (-0.5 * forward - np.cos(np.radians(30.0)) * up)
    np.testing.assert_allclose(pose.joints_m[0, sk.index("left_foot")], ankle, atol=1e-12)
    angles = joint_angles(sk, pose.q_segment)
    np.testing.assert_allclose(angles.degrees("left_knee")[0], [30.0, 0.0, 0.0], atol=1e-9)
    # the foot stayed level, so the ankle is dorsiflexed by 30 deg; everything else is zero
    np.testing.assert_allclose(angles.degrees("left_ankle")[0], [30.0, 0.0, 0.0], atol=1e-9)
    for joint in ("left_hip", "right_hip", "right_knee", "right_ankle"):
        np.testing.assert_allclose(angles.degrees(joint), 0.0, atol=1e-9)


def test_positions_match_a_scipy_oracle() -> None:
    rng = np.random.default_rng(12)
    sk = Skeleton.from_height(H, "full", "NED")
    q = random_quats(rng, (25, len(sk)))
    root = rng.normal(size=(25, 3))
    joints, ends = positions(sk, q, root)
    rot = [Rotation.from_quat(q[:, i, [1, 2, 3, 0]]) for i in range(len(sk))]
    expected = np.empty_like(joints)
    expected[:, 0] = root
    for i in range(1, len(sk)):
        p = sk.parents[i]
        expected[:, i] = expected[:, p] + rot[p].apply(sk.offsets_m[i])
    np.testing.assert_allclose(joints, expected, atol=1e-12)
    for i in range(len(sk)):
        np.testing.assert_allclose(ends[:, i], expected[:, i] + rot[i].apply(sk.ends_m[i]),
                                   atol=1e-12)


def test_q_and_minus_q_give_identical_results() -> None:
    rng = np.random.default_rng(13)
    sk = Skeleton.from_height(H, "full")
    mount = random_quats(rng, (len(sk),))
    cal = calibrate(sk, mount)
    q_true = quat.from_rotvec(np.cumsum(rng.normal(scale=0.1, size=(30, len(sk), 3)), axis=0))
    q = quat.multiply(q_true, mount)
    flipped = q * rng.choice([-1.0, 1.0], size=(30, len(sk), 1))
    a, b = track(sk, cal, q), track(sk, cal, flipped)
    np.testing.assert_array_equal(a.q_segment, b.q_segment)
    np.testing.assert_array_equal(a.joints_m, b.joints_m)
    np.testing.assert_array_equal(
        joint_angles(sk, a.q_segment).angles_rad, joint_angles(sk, b.q_segment).angles_rad
    )
    # the flipped calibration input too
    c = track(sk, calibrate(sk, -mount), flipped)
    np.testing.assert_allclose(c.joints_m, a.joints_m, atol=1e-15)
    # continuity in time: consecutive frames of each segment on the same hemisphere
    assert np.all(np.sum(a.q_segment[1:] * a.q_segment[:-1], axis=-1) > 0)
    assert np.all(a.q_segment[0, :, 0] >= 0)


def test_frames_at_once_equal_frames_one_by_one() -> None:
    rng = np.random.default_rng(14)
    sk = Skeleton.from_height(H, "lower", "NED")
    cal = calibrate(sk, random_quats(rng, (len(sk),)))
    q = random_quats(rng, (12, len(sk)))
    pose = track(sk, cal, q)
    for n in range(12):
        one = track(sk, cal, q[n])
        np.testing.assert_allclose(one.joints_m[0], pose.joints_m[n], atol=1e-15)
        assert quat.angle_between(one.q_segment[0], pose.q_segment[n]).max() < 1e-12


def test_bad_input_is_rejected_with_a_clear_message() -> None:
    sk = Skeleton.from_height(H, "lower")
    q = quat.identity((5, len(sk)))
    cal = calibrate(sk, q)
    with pytest.raises(ValueError, match=r"has 6 sensors but the skeleton has 7 segments"):
        track(sk, cal, q[:, :6])
    bad = q.copy()
    bad[3, 4] *= 1.1
    with pytest.raises(ValueError, match=r"q_sensor\[3, 4\] \(frame 3, segment right_thigh\) is "
                                         r"not a unit quaternion: norm 1.1"):
        track(sk, cal, bad)
    bad[3, 4] = np.nan
    with pytest.raises(ValueError, match="not a unit quaternion: norm nan"):
        track(sk, cal, bad)
    with pytest.raises(ValueError, match=r"shape \(S, 4\) or \(N, S, 4\)"):
        track(sk, cal, q[..., :3])
    with pytest.raises(ValueError, match=r"root_position_m must be finite with shape"):
        positions(sk, q, np.zeros((4, 3)))


def test_resample_orientations_slerps_between_neighbours() -> None:
    t = np.array([0.0, 1.0, 3.0])
    q = quat.from_axis_angle([0, 0, 1], np.radians([0.0, 90.0, 90.0]))
    out = resample_orientations(t, -q, [0.5, 0.25, 2.0, 3.0])  # signs do not matter
    angles = np.degrees(quat.to_euler(out)[:, 0])
    np.testing.assert_allclose(angles, [45.0, 22.5, 90.0, 90.0], atol=1e-12)
    with pytest.raises(ValueError, match="never extrapolated"):
        resample_orientations(t, q, [3.5])
    with pytest.raises(ValueError, match="strictly increasing"):
        resample_orientations(t[::-1], q, [1.0])
