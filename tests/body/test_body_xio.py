"""The body model on the real x-IMU3 lower-body recording (first 4.5 s: stand, then walk)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.body import Skeleton, body_axes, calibrate, joint_angles, still_window, track
from margtrack.body.xio import from_device_frame, read_xio_orientations

RATE_HZ = 50.0


@pytest.fixture(scope="module")
def xio(xio_folder: Path) -> Path:
    return xio_folder


def test_device_frame_is_nwu(xio: Path) -> None:
    from margtrack.io import read_xio_quaternion, read_xio_sensor

    for sensor in ("pelvis", "left_upper_leg", "right_foot"):
        rec = read_xio_sensor(xio / sensor)
        _, q = read_xio_quaternion(xio / sensor)
        still = slice(0, 40)  # the first 0.8 s: standing
        acc = quat.rotate(q[still], rec.acc[still]).mean(axis=0)
        mag = quat.rotate(q[still], rec.mag[still]).mean(axis=0)
        # NWU: specific force straight up, the field's horizontal part along +x (north)
        assert np.degrees(np.arccos(acc[2] / np.linalg.norm(acc))) < 1.0
        assert abs(np.degrees(np.arctan2(mag[1], mag[0]))) < 5.0


def test_from_device_frame_of_a_level_sensor_facing_north() -> None:
    q_nwu = quat.identity()  # NWU: body x north, z up
    np.testing.assert_allclose(from_device_frame(q_nwu, "NWU", "ENU"),
                               [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(from_device_frame(q_nwu, "NWU", "NED"), [0, 1, 0, 0], atol=1e-15)
    with pytest.raises(ValueError, match="device_frame must be one of NWU, ENU, NED"):
        from_device_frame(q_nwu, "NUE", "ENU")


def test_walk_start_knee_and_hip_angles(xio: Path) -> None:
    t, names, q = read_xio_orientations(xio, RATE_HZ)
    np.testing.assert_allclose(np.diff(t), 1.0 / RATE_HZ, atol=1e-9)
    keep = t < t[0] + 4.5
    t, q = t[keep], q[keep]
    sk = Skeleton.from_height(1.75, "lower", "ENU")
    q = q[:, sk.order(names)]
    window = still_window(t, q, duration_s=1.0, max_motion_deg=2.0)
    assert window.start == 0
    cal = calibrate(sk, q[window], heading="pelvis", forward_axis=[0, 0, -1])
    assert cal.spread_deg.max() < 1.0
    # the thigh sensors sit symmetrically on the outer thighs: the bisector of their z axes,
    # horizontal, is the facing direction; the pelvis sensor's -z must agree with it
    right, forward, up = body_axes("ENU")
    z = quat.rotate(q[window][:, [sk.index("left_thigh"), sk.index("right_thigh")]],
                    [0.0, 0.0, 1.0]).mean(axis=0)
    z = z - np.outer(z @ up, up)
    bisector = z[0] / np.linalg.norm(z[0]) + z[1] / np.linalg.norm(z[1])
    bisector_deg = np.degrees(np.arctan2(bisector @ right, bisector @ forward))
    assert abs(bisector_deg - cal.facing_deg) < 15.0

    angles = joint_angles(sk, track(sk, cal, q).q_segment)
    deg = {j: angles.degrees(j) for j in angles.names}
    for j in deg:  # zero in the reference pose, up to the two sensors' spreads (< 0.5 deg each)
        assert np.abs(deg[j][window]).max() < 2 * cal.spread_deg.max(), j
    walk = t >= t[0] + 1.5
    # gait: knee flexion peaks of 40-70 deg in swing (here 63 deg left, 45 deg right), the
    # knee nearly straight in stance, hip flexion within -20..30 deg
    for side in ("left", "right"):
        knee = deg[f"{side}_knee"][walk, 0]
        hip = deg[f"{side}_hip"][walk, 0]
        assert 40.0 < knee.max() < 70.0, side
        assert knee.min() < 5.0, side
        assert -20.0 < hip.min() and hip.max() < 30.0, side
        assert hip.max() - hip.min() > 20.0, side


def test_read_xio_orientations_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        read_xio_orientations(tmp_path / "none", RATE_HZ)
    with pytest.raises(FileNotFoundError, match=r"no sensor folder with a Quaternion\.csv"):
        read_xio_orientations(tmp_path, RATE_HZ)
    with pytest.raises(ValueError, match="rate_hz must be a finite number > 0"):
        read_xio_orientations(tmp_path, 0.0)
