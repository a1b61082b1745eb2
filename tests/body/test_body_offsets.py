"""Sensor-to-segment offsets (000, eq. 10): averaging, mounting invariance, heading choices."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from margtrack import quaternion as quat
from margtrack.body import (
    Skeleton,
    average_quaternions,
    body_axes,
    calibrate,
    joint_angles,
    positions,
    segment_orientations,
    still_window,
    track,
)

H = 1.75


def random_quats(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    return quat.normalize(rng.normal(size=(*shape, 4)))


def test_average_matches_scipy_mean_and_ignores_signs() -> None:
    rng = np.random.default_rng(1)
    center = random_quats(rng, (3,))
    noise = quat.from_rotvec(rng.normal(scale=0.05, size=(200, 3, 3)))
    q = quat.multiply(center, noise)
    mean = average_quaternions(q)
    flipped = average_quaternions(q * rng.choice([-1.0, 1.0], size=(200, 3, 1)))
    np.testing.assert_array_equal(mean, flipped)
    for s in range(3):
        ref = Rotation.from_quat(q[:, s, [1, 2, 3, 0]]).mean().as_quat()[[3, 0, 1, 2]]
        assert quat.angle_between(mean[s], ref) < 1e-9
    assert np.all(mean[:, 0] >= 0)
    one = average_quaternions(q[:, 0])  # (N, 4) form
    np.testing.assert_allclose(one, mean[0], atol=1e-15)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_north_offsets_are_the_conjugate_of_the_reference_pose(frame: str) -> None:
    sk = Skeleton.from_height(H, "lower", frame)
    q_ref = random_quats(np.random.default_rng(2), (len(sk),))
    cal = calibrate(sk, q_ref)
    np.testing.assert_allclose(
        quat.canonical(cal.offsets), quat.canonical(quat.conjugate(q_ref)), atol=1e-12
    )  # 000 eq. 10
    np.testing.assert_array_equal(cal.heading_quat, [1, 0, 0, 0])
    assert cal.facing_deg == 0.0


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_random_mountings_cancel(frame: str) -> None:
    rng = np.random.default_rng(3)
    sk = Skeleton.from_height(H, "full", frame)
    mount = random_quats(rng, (len(sk),))  # q_sensor = q_segment ⊗ q_mount
    q_true = quat.from_rotvec(rng.normal(scale=0.8, size=(40, len(sk), 3)))
    reference = np.broadcast_to(mount, (60, len(sk), 4))  # segments at the identity
    cal = calibrate(sk, reference)
    q_seg = segment_orientations(sk, cal, quat.multiply(q_true, mount))
    assert quat.angle_between(q_seg, q_true).max() < 1e-9
    np.testing.assert_allclose(quat.canonical(cal.offsets), quat.canonical(quat.conjugate(mount)),
                               atol=1e-12)


def test_noisy_reference_window_is_averaged() -> None:
    rng = np.random.default_rng(4)
    sk = Skeleton.from_height(H, "lower")
    mount = random_quats(rng, (len(sk),))
    sigma = np.radians(0.2)  # per-axis orientation noise of the reference samples
    n = 100
    noisy = quat.multiply(mount, quat.from_rotvec(rng.normal(scale=sigma, size=(n, len(sk), 3))))
    cal = calibrate(sk, noisy)
    q_seg = segment_orientations(sk, cal, mount)
    # the mean's error has per-axis std sigma/sqrt(n): its angle is below 5 sigma*sqrt(3/n)
    assert quat.angle_between(q_seg, quat.identity()).max() < 5 * sigma * np.sqrt(3 / n)
    # spread: the largest of n chi(3)-distributed angles (scale sigma), about 3.5 sigma
    assert np.degrees(sigma) < cal.spread_deg.min() and cal.spread_deg.max() < np.degrees(6 * sigma)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_pelvis_heading_when_the_person_faces_east(frame: str) -> None:
    rng = np.random.default_rng(5)
    sk = Skeleton.from_height(H, "lower", frame)
    right, forward, up = body_axes(frame)
    q_h = quat.from_axis_angle(up, -np.pi / 2)  # turn from north towards east
    np.testing.assert_allclose(quat.rotate(q_h, forward), right, atol=1e-15)  # faces east
    mount = random_quats(rng, (len(sk),))
    q_ref = quat.multiply(q_h, mount)
    forward_axis = quat.rotate_inverse(mount[0], forward)  # the pelvis sensor's forward axis
    cal = calibrate(sk, q_ref, heading="pelvis", forward_axis=3.0 * forward_axis)
    assert cal.facing_deg == pytest.approx(90.0, abs=1e-9)
    assert quat.angle_between(cal.heading_quat, q_h) < 1e-9
    # reference pose: zero angles, rest positions turned about the root to face east
    pose = track(sk, cal, q_ref)
    rest_joints, _ = positions(sk, quat.identity((len(sk),)))
    root = sk.root_position_m
    np.testing.assert_allclose(pose.joints_m[0], root + quat.rotate(q_h, rest_joints - root),
                               atol=1e-12)
    toe = pose.ends_m[0, sk.index("right_foot")] - pose.joints_m[0, sk.index("right_foot")]
    assert toe @ right == pytest.approx(0.152 * H, abs=1e-12)  # toes point east
    np.testing.assert_allclose(joint_angles(sk, pose.q_segment).angles_rad, 0.0, atol=1e-12)
    # a right knee flexion of 30 deg: the shank turns -30 deg about the subject's right (south)
    q_true = np.broadcast_to(q_h, (len(sk), 4)).copy()
    q_true[sk.index("right_shank")] = quat.multiply(q_h, quat.from_axis_angle(right, -np.pi / 6))
    q_sensor = quat.multiply(q_true, mount)
    knee = joint_angles(sk, segment_orientations(sk, cal, q_sensor)).degrees("right_knee")
    np.testing.assert_allclose(knee, [30.0, 0.0, 0.0], atol=1e-9)
    # with the paper's north reference the same flexion is decomposed about the wrong axes:
    # the knee seems adducted by 30 deg and not flexed
    north = calibrate(sk, q_ref)
    wrong = joint_angles(sk, segment_orientations(sk, north, q_sensor)).degrees("right_knee")
    np.testing.assert_allclose(wrong, [0.0, -30.0, 0.0], atol=1e-9)


def test_pelvis_heading_uses_the_root_without_a_pelvis() -> None:
    sk = Skeleton.from_height(H, "right_arm", "NED")
    _, forward, up = body_axes("NED")
    q_h = quat.from_axis_angle(up, np.radians(40.0))  # faces 40 deg west of north
    cal = calibrate(sk, np.broadcast_to(q_h, (3, 4)), heading="pelvis", forward_axis=forward)
    assert cal.facing_deg == pytest.approx(-40.0, abs=1e-9)


def test_calibration_errors() -> None:
    sk = Skeleton.from_height(H, "lower")
    q = quat.identity((10, len(sk)))
    with pytest.raises(ValueError, match="heading='pelvis' needs forward_axis"):
        calibrate(sk, q, heading="pelvis")
    with pytest.raises(ValueError, match="within 78 deg of the vertical"):
        calibrate(sk, q, heading="pelvis", forward_axis=[0.1, 0, 1])
    with pytest.raises(ValueError, match="heading must be 'north' or 'pelvis'"):
        calibrate(sk, q, heading="east")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="forward_axis is only used with heading='pelvis'"):
        calibrate(sk, q, forward_axis=[1, 0, 0])
    moved = q.copy()
    moved[5, 2] = quat.from_axis_angle([1, 0, 0], np.radians(20.0))
    with pytest.raises(ValueError, match=r"sensor left_shank turned 1[0-9]\.[0-9] deg"):
        calibrate(sk, moved)
    with pytest.raises(ValueError, match="has 6 sensors but the skeleton has 7 segments"):
        calibrate(sk, q[:, :6])
    other = Skeleton.from_height(H, "lower", "NED")
    with pytest.raises(ValueError, match="calibrate with this skeleton"):
        segment_orientations(other, calibrate(sk, q), q)


def test_still_window_skips_the_motion() -> None:
    t = np.arange(300) / 100.0
    angle = np.where(t < 0.8, np.sin(2 * np.pi * 2 * t), 0.0)  # moves, then holds still
    q = quat.from_axis_angle([0, 0, 1], angle)[:, None, :]
    w = still_window(t, np.concatenate([q, q], axis=1), duration_s=1.0, max_motion_deg=1.0)
    assert 0.75 <= t[w.start] <= 0.85 and t[w.stop - 1] - t[w.start] == pytest.approx(0.99)
    moving = quat.from_axis_angle([0, 0, 1], t)[:, None, :]
    with pytest.raises(ValueError, match=r"no still window of 1\.0 s found"):
        still_window(t, moving)
    with pytest.raises(ValueError, match="t_s must be strictly increasing"):
        still_window(t[::-1], q)
