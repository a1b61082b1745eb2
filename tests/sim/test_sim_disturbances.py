"""Magnetic disturbances: shapes in time, frames, and their effect on a simulated recording."""

import math

import numpy as np
import pytest

from margtrack import quaternion as qt
from margtrack.frames import mag_reference, up
from margtrack.sim import (
    MagnetPass,
    RotatingField,
    VerticalTilt,
    magnet_pass,
    rotating_field,
    simulate,
    static,
    vertical_tilt,
)

Q0 = qt.from_euler(np.radians([40.0, -15.0, 25.0]))


def angle_deg(u, v):
    cos = np.sum(u * v, axis=-1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_rotating_field_about_the_vertical_turns_only_the_heading(frame):
    """002 III-C: the measured field turns by up to 360 deg; gravity is untouched."""
    traj = static(16.0, 50.0, q0=Q0)
    disturbance = rotating_field(start_s=2.0, rate_deg_s=30.0, angle_deg=360.0)
    clean = simulate(traj, frame=frame)
    rec = simulate(traj, frame=frame, mag_disturbances=[disturbance])
    np.testing.assert_array_equal(rec.acc, clean.acc)
    np.testing.assert_array_equal(rec.gyr, clean.gyr)
    field = qt.rotate(traj.quat, rec.mag)  # back to the earth frame
    ref = mag_reference(frame, 60.0, 50.0)
    np.testing.assert_allclose(field[:, 2], ref[2], atol=1e-12)  # dip unchanged
    np.testing.assert_allclose(np.linalg.norm(field, axis=1), 50.0, atol=1e-12)
    turned = np.arctan2(field[:, 1], field[:, 0]) - np.arctan2(ref[1], ref[0])
    expected = np.radians(np.clip(30.0 * (traj.t - 2.0), 0.0, 360.0))
    np.testing.assert_allclose(np.angle(np.exp(1j * (turned - expected))), 0.0, atol=1e-12)
    # before the start and after the full turn the body reads the undisturbed field
    np.testing.assert_allclose(rec.mag[traj.t <= 2.0], clean.mag[traj.t <= 2.0], atol=1e-12)
    np.testing.assert_allclose(rec.mag[traj.t >= 14.0], clean.mag[traj.t >= 14.0], atol=1e-12)
    i = int(np.flatnonzero(traj.t == 5.0)[0])  # 90 deg turned
    assert np.abs(rec.mag[i] - clean.mag[i]).max() > 10.0


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_rotating_field_turns_the_body_frame_direction_by_the_stated_angle(frame):
    """About an axis perpendicular to the field the body-frame vector turns by exactly φ."""
    ref = mag_reference(frame, 60.0, 50.0)
    axis = np.cross(ref, up(frame))
    traj = static(4.0, 50.0, q0=Q0)
    disturbance = RotatingField(start_s=1.0, rate_deg_s=45.0, angle_deg=-120.0, axis=tuple(axis))
    clean = simulate(traj, frame=frame)
    rec = simulate(traj, frame=frame, mag_disturbances=[disturbance])
    expected = np.clip(45.0 * (traj.t - 1.0), 0.0, 120.0)
    np.testing.assert_allclose(angle_deg(rec.mag, clean.mag), expected, atol=1e-5)
    np.testing.assert_allclose(np.degrees(disturbance.angle_rad(traj.t)), -expected, atol=1e-12)
    np.testing.assert_array_equal(rec.acc, clean.acc)
    # the sense: a negative angle turns the field by -120 deg about the axis
    turn = qt.from_axis_angle(axis, np.radians(-120.0))
    np.testing.assert_allclose(rec.mag[-1], qt.rotate_inverse(Q0, qt.rotate(turn, ref)), atol=1e-12)


def test_magnet_pass_is_a_raised_cosine_bump_and_zero_outside():
    d = magnet_pass(t_center_s=5.0, duration_s=2.0, peak_ut=80.0, direction=(0.0, 0.0, 2.0))
    assert isinstance(d, MagnetPass) and d.direction == (0.0, 0.0, 1.0)
    t = np.array([0.0, 3.99, 4.0, 4.5, 5.0, 5.5, 6.0, 9.0])
    field = d.earth_field_ut(t, np.zeros(3), "NED")
    np.testing.assert_allclose(field[:, 2], [0.0, 0.0, 0.0, 40.0, 80.0, 40.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_array_equal(field[:, :2], 0.0)
    traj = static(10.0, 20.0, q0=Q0)
    rec = simulate(traj, frame="ENU", mag_disturbances=[d])
    clean = simulate(traj, frame="ENU")
    outside = np.abs(traj.t - 5.0) >= 1.0
    np.testing.assert_array_equal(rec.mag[outside], clean.mag[outside])
    centre = int(np.flatnonzero(traj.t == 5.0)[0])
    np.testing.assert_allclose(
        rec.mag[centre] - clean.mag[centre], qt.rotate_inverse(Q0, [0.0, 0.0, 80.0]), atol=1e-12
    )


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_vertical_tilt_adds_a_downward_field_and_keeps_the_horizontal(frame):
    d = vertical_tilt(start_s=1.0, down_ut=20.0, ramp_s=2.0)
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    ref = mag_reference(frame, 60.0, 50.0)
    field = d.earth_field_ut(t, ref, frame)
    down = -up(frame)
    np.testing.assert_allclose(field, np.outer([0.0, 0.0, 10.0, 20.0, 20.0], down), atol=1e-12)
    jump = VerticalTilt(start_s=1.0, down_ut=-5.0, ramp_s=0.0)
    np.testing.assert_allclose(jump.profile(t), [0.0, 1.0, 1.0, 1.0, 1.0])
    traj = static(5.0, 10.0, q0=Q0)
    rec = simulate(traj, frame=frame, mag_disturbances=[d])
    earth = qt.rotate(traj.quat, rec.mag)
    np.testing.assert_allclose(earth[:, :2], np.tile(ref[:2], (traj.n_samples, 1)), atol=1e-12)
    np.testing.assert_allclose(earth[-1] @ down, ref @ down + 20.0, atol=1e-12)


def test_disturbances_add_up_and_are_recorded_in_meta():
    a = magnet_pass(2.0, 1.0, 30.0, (1.0, 0.0, 0.0))
    b = vertical_tilt(0.0, 5.0, ramp_s=0.0)
    traj = static(4.0, 10.0)
    rec = simulate(traj, frame="NED", mag_disturbances=[a, b])
    ref = mag_reference("NED", 60.0, 50.0)
    expected = ref + a.earth_field_ut(traj.t, ref, "NED") + b.earth_field_ut(traj.t, ref, "NED")
    np.testing.assert_allclose(rec.mag, expected, atol=1e-12)
    kinds = [d["type"] for d in rec.meta["mag_disturbances"]]
    assert kinds == ["MagnetPass", "VerticalTilt"]
    assert rec.meta["mag_disturbances"][0]["peak_ut"] == 30.0


@pytest.mark.parametrize(
    ("build", "match"),
    [
        (lambda: magnet_pass(1.0, 0.0, 10.0, (1, 0, 0)), "duration_s must be a finite number > 0"),
        (lambda: magnet_pass(1.0, 1.0, math.inf, (1, 0, 0)), "peak_ut"),
        (lambda: magnet_pass(1.0, 1.0, 10.0, (0, 0, 0)), "direction"),
        (lambda: rotating_field(0.0, 0.0), "rate_deg_s must be a finite number > 0"),
        (lambda: rotating_field(0.0, 10.0, angle_deg=0.0), "angle_deg"),
        (lambda: rotating_field(0.0, 10.0, axis=(1.0, 2.0)), "axis"),
        (lambda: vertical_tilt(0.0, 1.0, ramp_s=-1.0), "ramp_s must be a finite number >= 0"),
        (lambda: vertical_tilt(math.nan, 1.0), "start_s"),
    ],
)
def test_bad_parameters_are_named(build, match):
    with pytest.raises(ValueError, match=match):
        build()
