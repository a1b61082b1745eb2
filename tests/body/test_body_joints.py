"""Joint angles: X-Y-Z Cardan decomposition (scipy oracle) and the clinical sign conventions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from margtrack import quaternion as quat
from margtrack.body import Skeleton, body_axes, cardan_xyz, joint_angles, positions

H = 1.75


def test_cardan_xyz_matches_scipy_intrinsic_xyz() -> None:
    rng = np.random.default_rng(20)
    q = quat.normalize(rng.normal(size=(500, 4)))
    expected = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler("XYZ")
    np.testing.assert_allclose(cardan_xyz(q), expected, atol=1e-10)
    np.testing.assert_array_equal(cardan_xyz(q), cardan_xyz(-q))


def test_cardan_xyz_at_gimbal_lock_reproduces_the_rotation() -> None:
    q = quat.multiply(quat.from_axis_angle([1, 0, 0], 0.3), quat.from_axis_angle([0, 1, 0],
                                                                               np.pi / 2))
    q = quat.multiply(q, quat.from_axis_angle([0, 0, 1], 0.5))
    a, b, c = cardan_xyz(q)
    assert b == pytest.approx(np.pi / 2) and c == 0.0
    back = Rotation.from_euler("XYZ", [a, b, c]).as_quat()[[3, 0, 1, 2]]
    assert quat.angle_between(back, q) < 1e-7


def pose_with(sk: Skeleton, rotations: dict[str, np.ndarray]) -> np.ndarray:
    """Segment orientations: each named segment's rotation applied to it and its children."""
    q = quat.identity((len(sk),))
    for i, name in enumerate(sk.names):
        p = sk.parents[i]
        own = rotations.get(name, quat.identity())
        q[i] = quat.multiply(q[p], own) if p >= 0 else own
    return q


def about(axis: np.ndarray, deg: float) -> np.ndarray:
    return quat.from_axis_angle(axis, np.radians(deg))


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_hip_signs_follow_the_distal_end(frame: str) -> None:
    sk = Skeleton.from_height(H, "lower", frame)
    right, forward, up = body_axes(frame)
    for side, lateral in (("right", right), ("left", -right)):
        thigh = f"{side}_thigh"
        i = sk.index(f"{side}_shank")  # the knee: the thigh's distal end
        rest = positions(sk, pose_with(sk, {}))[0][i]
        # flexion: 20 deg about the right axis swings the knee forward, both sides
        q = pose_with(sk, {thigh: about(right, 20.0)})
        assert (positions(sk, q)[0][i] - rest) @ forward > 0
        np.testing.assert_allclose(joint_angles(sk, q).degrees(f"{side}_hip"), [20, 0, 0],
                                   atol=1e-9)
        # abduction: the knee moves away from the midline, by thigh * sin 15 deg
        axis = forward if side == "left" else -forward
        q = pose_with(sk, {thigh: about(axis, 15.0)})
        moved = (positions(sk, q)[0][i] - rest) @ lateral
        assert moved == pytest.approx(0.245 * H * np.sin(np.radians(15.0)), abs=1e-12)
        np.testing.assert_allclose(joint_angles(sk, q).degrees(f"{side}_hip"), [0, 15, 0],
                                   atol=1e-9)
        # internal rotation: the toes turn towards the midline
        turn = about(up if side == "right" else -up, 25.0)
        q = pose_with(sk, {thigh: turn})
        foot = sk.index(f"{side}_foot")
        toe = positions(sk, q)[1][foot] - positions(sk, q)[0][foot]
        assert toe @ lateral < 0
        np.testing.assert_allclose(joint_angles(sk, q).degrees(f"{side}_hip"), [0, 0, 25],
                                   atol=1e-9)


def test_knee_ankle_and_arm_signs() -> None:
    sk = Skeleton.from_height(H, "full", "ENU")
    right, forward, up = body_axes("ENU")
    q = pose_with(sk, {
        "left_shank": about(right, -40.0),  # the shank swings back: knee flexion
        "right_foot": about(right, 10.0),  # toes up: dorsiflexion
        "left_foot": about(forward, -12.0),  # sole turns to the right, the midline: inversion
        "right_upper_arm": about(right, 70.0),  # arm forward: shoulder flexion
        "left_upper_arm": about(forward, 80.0),  # arm out to the left: abduction
        "right_forearm": about(right, 90.0),  # hand forward: elbow flexion
        "left_forearm": about(up, -30.0),  # palm (facing right) turns back: pronation
    })
    a = joint_angles(sk, q)
    expected = {
        "left_knee": [40, 0, 0], "right_ankle": [10, 0, 0], "left_ankle": [0, 12, 0],
        "right_shoulder": [70, 0, 0], "left_shoulder": [0, 80, 0], "right_elbow": [90, 0, 0],
        "left_elbow": [0, 0, 30], "right_hip": [0, 0, 0], "left_hip": [0, 0, 0],
        "right_knee": [0, 0, 0],
    }
    assert set(a.names) == set(expected)
    for joint, value in expected.items():
        np.testing.assert_allclose(a.degrees(joint), value, atol=1e-9, err_msg=joint)
    joints, _ = positions(sk, q)
    forearm = joints[sk.index("right_hand")] - joints[sk.index("right_forearm")]
    # shoulder flexion 70 + elbow flexion 90: the forearm is 160 deg from hanging down
    phi = np.radians(160.0)
    np.testing.assert_allclose(forearm, 0.146 * H * (np.sin(phi) * forward - np.cos(phi) * up),
                               atol=1e-12)
    assert a.columns()[:3] == ["right_hip_flexion", "right_hip_abduction",
                               "right_hip_internal_rotation"]


def test_joint_angles_in_ned_equal_those_in_enu() -> None:
    rng = np.random.default_rng(21)
    enu = Skeleton.from_height(H, "full", "ENU")
    ned = Skeleton.from_height(H, "full", "NED")
    q_enu = quat.from_rotvec(rng.normal(scale=0.5, size=(20, len(enu), 3)))
    # the same motion written in NED: q_ned = c ⊗ q_enu ⊗ c* (earth and segment axes)
    from margtrack.frames import convert

    c = convert(quat.identity(), "ENU", "NED")
    q_ned = quat.multiply(quat.multiply(c, q_enu), quat.conjugate(c))
    np.testing.assert_allclose(joint_angles(ned, q_ned).angles_rad,
                               joint_angles(enu, q_enu).angles_rad, atol=1e-12)


def test_joints_present_per_preset() -> None:
    names = {p: joint_angles(Skeleton.from_height(H, p), quat.identity((len(
        Skeleton.from_height(H, p)),))).names for p in ("lower", "left_arm", "right_leg")}
    assert names["lower"] == ("right_hip", "left_hip", "right_knee", "left_knee",
                              "right_ankle", "left_ankle")
    assert names["left_arm"] == ("left_elbow",)
    assert names["right_leg"] == ("right_knee", "right_ankle")
    with pytest.raises(ValueError, match="no joint 'left_hip'; this skeleton's joints: left_elbow"):
        joint_angles(Skeleton.from_height(H, "left_arm"), quat.identity((3,))).degrees("left_hip")
