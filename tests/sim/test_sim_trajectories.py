"""Trajectories: hand values, analytic vs finite-difference acceleration, gyro convention."""

import numpy as np
import pytest

from margtrack import quaternion as qt
from margtrack.frames import up
from margtrack.sim import (
    Hold,
    Rotate,
    Trajectory,
    body_rate,
    constant_rotation,
    limb_swing,
    random_motion,
    rotation_sequence,
    static,
)

Q0 = qt.from_euler(np.radians([30.0, -20.0, 10.0]))


def integrate_series(q0, gyr, t):
    """Reference integration, one ``quaternion.integrate`` call per sample (i >= 1)."""
    q = np.empty((t.shape[0], 4))
    q[0] = q0
    for i in range(1, t.shape[0]):
        q[i] = qt.integrate(q[i - 1], gyr[i], t[i] - t[i - 1])
    return q


def test_static_is_exactly_still():
    traj = static(2.0, 100.0, q0=Q0)
    assert traj.n_samples == 201
    assert traj.t[-1] == pytest.approx(2.0, abs=1e-12)
    np.testing.assert_array_equal(traj.quat, np.tile(traj.quat[0], (201, 1)))
    np.testing.assert_allclose(traj.quat[0], Q0, atol=1e-15)
    np.testing.assert_array_equal(body_rate(traj), 0.0)
    np.testing.assert_array_equal(traj.acc_lin_m_s2, 0.0)


def test_constant_rotation_reaches_rate_times_duration_about_the_earth_axis():
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    traj = constant_rotation(axis, 9.0, 10.0, 100.0, q0=Q0)
    turn = qt.multiply(traj.quat[-1], qt.conjugate(traj.quat[0]))  # earth-frame rotation
    expected = qt.from_axis_angle(axis, np.radians(90.0))
    assert qt.angle_between(turn, expected) < 1e-12
    assert np.degrees(qt.angle_between(traj.quat[0], traj.quat[-1])) == pytest.approx(
        90.0, abs=1e-10
    )
    # an earth-fixed axis seen from the body: constant body rate R(q0)^T axis * rate
    gyr = body_rate(traj)
    np.testing.assert_allclose(
        gyr[1:], np.tile(qt.rotate_inverse(Q0, axis) * np.radians(9.0), (1000, 1)), atol=1e-10
    )
    np.testing.assert_array_equal(gyr[0], 0.0)


def test_constant_rotation_past_half_turn_and_negative_rate():
    traj = constant_rotation((0, 0, 1), -30.0, 10.0, 50.0)  # -300 deg = +60 deg
    expected = qt.from_axis_angle([0.0, 0.0, 1.0], np.radians(-300.0))
    assert qt.angle_between(traj.quat[-1], expected) < 1e-12
    np.testing.assert_allclose(body_rate(traj)[1:, 2], np.radians(-30.0), rtol=1e-10)


def roll_excursions(hold_s=15.0):
    """000's dynamic test: 0 to 45 deg roll at 10 deg/s, holds of 15 s."""
    x = (1.0, 0.0, 0.0)
    return [Rotate(x, 45.0, 10.0), Hold(hold_s), Rotate(x, -45.0, 10.0), Hold(hold_s)]


def test_rotation_sequence_000_roll_excursions():
    traj = rotation_sequence(roll_excursions(), 100.0)
    assert traj.t[-1] == pytest.approx(39.0)
    euler = np.degrees(qt.to_euler(traj.quat))
    roll = euler[:, 2]
    np.testing.assert_allclose(euler[:, :2], 0.0, atol=1e-12)
    i_top, i_back = 450, 1950  # t = 4.5 s (end of the first move) and 19.5 s + 4.5 s
    assert roll[i_top] == pytest.approx(45.0, abs=1e-10)
    assert roll[225] == pytest.approx(22.5, abs=1e-10)
    np.testing.assert_allclose(roll[i_top : i_back + 1], 45.0, atol=1e-10)
    assert roll[i_back + 450] == pytest.approx(0.0, abs=1e-10)
    gyr = body_rate(traj)
    np.testing.assert_allclose(gyr[1 : i_top + 1, 0], np.radians(10.0), rtol=1e-9)
    np.testing.assert_allclose(gyr[i_back + 1 : i_back + 451, 0], np.radians(-10.0), rtol=1e-9)
    # holds are exactly still: every gyro sample whose interval lies in a hold is 0.0
    np.testing.assert_array_equal(gyr[i_top + 1 : i_back + 1], 0.0)
    np.testing.assert_array_equal(gyr[i_back + 451 :], 0.0)
    tilted = body_rate(rotation_sequence(roll_excursions(), 100.0, q0=Q0))
    np.testing.assert_array_equal(tilted[i_top + 1 : i_back + 1], 0.0)
    assert np.degrees(np.linalg.norm(tilted[1])) == pytest.approx(10.0, rel=1e-9)


def test_rotation_sequence_turns_about_earth_axes():
    """Each step turns about an earth-fixed axis: the turn multiplies from the left."""
    q0 = qt.from_euler(np.radians([90.0, 0.0, 0.0]))
    traj = rotation_sequence(
        [Rotate((1, 0, 0), 30.0, 10.0), Rotate((0, 0, 1), -60.0, 30.0)], 100.0, q0=q0
    )
    first = qt.from_axis_angle([1.0, 0.0, 0.0], np.radians(30.0))
    second = qt.from_axis_angle([0.0, 0.0, 1.0], np.radians(-60.0))
    assert qt.angle_between(traj.quat[300], qt.multiply(first, q0)) < 1e-12
    assert qt.angle_between(traj.quat[-1], qt.multiply(second, qt.multiply(first, q0))) < 1e-12
    assert (
        np.degrees(qt.angle_between(traj.quat[-1], qt.multiply(q0, qt.multiply(first, second))))
        > 10
    )


def limb_fd_tolerance(amplitude_rad, omega, length, dt):
    """Bound on the central-difference error |(p+ - 2p + p-)/dt² - p''| <= dt²/12 max|p''''|.

    p = L u(θ(t)) with |u^(k)| = 1 (a point on a circle) and |θ^(k)| <= A ω^k, so by Faà di
    Bruno |p''''| <= L ω⁴ (A + 7A² + 6A³ + A⁴); rounding adds about 4 eps L / dt².
    """
    a = amplitude_rad
    fourth = length * omega**4 * (a + 7 * a**2 + 6 * a**3 + a**4)
    return dt**2 / 12.0 * fourth + 4.0 * np.finfo(float).eps * length / dt**2


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_limb_swing_acceleration_is_the_second_derivative_of_position(frame):
    rate_hz, amplitude_deg, frequency_hz, length_m = 1000.0, 30.0, 1.0, 0.4
    traj = limb_swing(
        2.0, rate_hz, amplitude_deg, frequency_hz, length_m, axis=(0, 1, 0), frame=frame
    )
    p, dt = traj.pos_m, 1.0 / rate_hz
    fd = (p[2:] - 2.0 * p[1:-1] + p[:-2]) / dt**2
    err = np.abs(fd - traj.acc_lin_m_s2[1:-1]).max()
    tol = limb_fd_tolerance(np.radians(amplitude_deg), 2 * np.pi * frequency_hz, length_m, dt)
    assert tol < 1e-3  # a missing centripetal term (θ̇² L, up to 4.3 m/s² here) would show
    assert err <= tol
    assert np.abs(traj.acc_lin_m_s2).max() > 1.0


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_limb_swing_geometry(frame):
    traj = limb_swing(
        2.0, 200.0, amplitude_deg=40.0, frequency_hz=0.5, length_m=0.3, q0=Q0, frame=frame
    )
    np.testing.assert_allclose(np.linalg.norm(traj.pos_m, axis=1), 0.3, rtol=1e-12)
    np.testing.assert_allclose(traj.pos_m[0], -0.3 * up(frame), atol=1e-15)
    # at the top of the swing (t = 0.5 s) the limb is 40 deg from vertical, at rest: only
    # the tangential acceleration A ω² L remains, perpendicular to the limb
    top = 100
    cos_angle = -traj.pos_m[top] @ up(frame) / 0.3
    assert np.degrees(np.arccos(cos_angle)) == pytest.approx(40.0, abs=1e-9)
    tangential = np.radians(40.0) * np.pi**2 * 0.3
    assert np.linalg.norm(traj.acc_lin_m_s2[top]) == pytest.approx(tangential, rel=1e-12)
    assert traj.acc_lin_m_s2[top] @ traj.pos_m[top] == pytest.approx(0.0, abs=1e-12)
    assert np.degrees(qt.angle_between(traj.quat[0], traj.quat[top])) == pytest.approx(
        40.0, abs=1e-9
    )
    # the sensor rides the limb rigidly: the limb seen from the body never changes ...
    limb_in_body = qt.rotate_inverse(traj.quat, traj.pos_m)
    np.testing.assert_allclose(limb_in_body, np.tile(limb_in_body[0], (401, 1)), atol=1e-14)
    # ... and it turns about the earth-frame swing axis
    turn = qt.multiply(traj.quat[top], qt.conjugate(traj.quat[0]))
    assert qt.angle_between(turn, qt.from_axis_angle([1.0, 0.0, 0.0], np.radians(40.0))) < 1e-12


def test_random_motion_is_deterministic_and_seed_dependent():
    a = random_motion(5.0, 100.0, seed=3, translation_m=0.1)
    b = random_motion(5.0, 100.0, seed=3, translation_m=0.1)
    c = random_motion(5.0, 100.0, seed=4, translation_m=0.1)
    np.testing.assert_array_equal(a.quat, b.quat)
    np.testing.assert_array_equal(a.acc_lin_m_s2, b.acc_lin_m_s2)
    assert np.degrees(qt.angle_between(a.quat, c.quat)).max() > 10.0
    assert np.abs(a.pos_m - c.pos_m).max() > 0.01


def test_random_motion_peak_rate_and_translation():
    traj = random_motion(
        20.0, 100.0, seed=1, max_rate_deg_s=150.0, bandwidth_hz=1.5, translation_m=0.05
    )
    speed = np.degrees(np.linalg.norm(body_rate(traj), axis=1))
    assert speed.max() == pytest.approx(150.0, rel=1e-9)
    assert np.median(speed) > 20.0  # it really moves, not one spike
    assert np.degrees(qt.angle_between(traj.quat[0], traj.quat)).max() > 90.0
    np.testing.assert_allclose(np.abs(traj.pos_m).max(axis=0), 0.05, rtol=1e-12)
    np.testing.assert_array_equal(traj.pos_m[0], 0.0)
    still = random_motion(20.0, 100.0, seed=1, max_rate_deg_s=150.0, bandwidth_hz=1.5)
    np.testing.assert_array_equal(np.abs(still.acc_lin_m_s2), 0.0)
    np.testing.assert_array_equal(still.quat, traj.quat)  # translation draws come after rotation


def test_random_motion_translation_acceleration_matches_finite_difference():
    """Central differences err by at most dt²/12 max|p''''| per axis, and for sines below
    ω_b = 2π bandwidth, |p''''| <= ω_b² Σ_k |c_k| with c_k the acceleration amplitudes; by
    Cauchy-Schwarz and Parseval Σ|c_k| <= sqrt(2K) rms <= sqrt(2K) max|a| (K = 6 sines),
    taken twice for the finite window. That bound holds after the 1 s fade-in; inside it the
    septic window adds to p'''', so there the bound uses max|p''''| measured by the fourth
    difference (times 2 for its own error)."""
    rate_hz, bandwidth_hz = 1000.0, 2.0
    traj = random_motion(10.0, rate_hz, seed=7, bandwidth_hz=bandwidth_hz, translation_m=0.1)
    dt, p, a = 1.0 / rate_hz, traj.pos_m, traj.acc_lin_m_s2
    fd = (p[2:] - 2.0 * p[1:-1] + p[:-2]) / dt**2
    err = np.abs(fd - a[1:-1])
    after = traj.t[1:-1] > 1.0 + 2 * dt
    peak = np.abs(a).max(axis=0)
    tol = dt**2 / 12 * (2 * np.pi * bandwidth_hz) ** 2 * np.sqrt(12.0) * peak * 2.0 + 1e-9
    assert np.all(err[after].max(axis=0) <= tol)
    fourth = np.abs(np.diff(p[: int(1.2 * rate_hz)], n=4, axis=0)).max(axis=0) / dt**4
    assert np.all(err[~after].max(axis=0) <= 2.0 * dt**2 / 12 * fourth + 1e-9)
    assert np.all(peak > 0.1)


def test_random_motion_translation_starts_at_rest():
    traj = random_motion(5.0, 100.0, seed=2, translation_m=0.05)
    np.testing.assert_array_equal(traj.pos_m[0], 0.0)
    np.testing.assert_array_equal(traj.acc_lin_m_s2[0], 0.0)
    assert np.abs(traj.acc_lin_m_s2[200:]).max() > 0.1


def test_body_rate_integrates_back_exactly():
    traj = random_motion(10.0, 100.0, seed=5, max_rate_deg_s=400.0, bandwidth_hz=3.0, q0=Q0)
    gyr = body_rate(traj)
    np.testing.assert_array_equal(gyr[0], 0.0)
    q = integrate_series(traj.quat[0], gyr, traj.t)
    assert qt.angle_between(q, traj.quat).max() < 1e-12
    np.testing.assert_allclose(q, traj.quat, atol=1e-12)  # same sign, not just same rotation


def test_trajectory_makes_quaternions_sign_continuous_and_is_read_only():
    traj = constant_rotation((0, 0, 1), 90.0, 1.0, 10.0)
    flipped = traj.quat * np.where(np.arange(11) % 2, -1.0, 1.0)[:, None]
    again = Trajectory(traj.t, flipped, traj.pos_m, traj.acc_lin_m_s2)
    np.testing.assert_allclose(again.quat, traj.quat, atol=1e-15)
    with pytest.raises(ValueError, match="read-only"):
        again.quat[0, 0] = 2.0


@pytest.mark.parametrize(
    ("build", "match"),
    [
        (
            lambda: Trajectory(
                [0.0, 1.0, 1.0], np.tile(qt.identity(), (3, 1)), np.zeros((3, 3)), np.zeros((3, 3))
            ),
            r"t\[2\]",
        ),
        (
            lambda: Trajectory(
                [0.0, 1.0], [[1.0, 0, 0, 0], [2.0, 0, 0, 0]], np.zeros((2, 3)), np.zeros((2, 3))
            ),
            "quat is not unit at sample 1",
        ),
        (
            lambda: Trajectory(
                [0.0, 1.0], np.tile(qt.identity(), (2, 1)), np.zeros((3, 3)), np.zeros((2, 3))
            ),
            "pos_m",
        ),
        (lambda: static(1.0, 0.0), "rate_hz"),
        (lambda: static(-1.0, 10.0), "duration_s"),
        (lambda: static(1.0, 10.0, q0=[1.0, 1.0, 0.0, 0.0]), "q0"),
        (lambda: constant_rotation((0, 0, 0), 10.0, 1.0, 10.0), "axis"),
        (lambda: constant_rotation((0, 0, 1), 2000.0, 1.0, 10.0), "rate_deg_s"),
        (lambda: Rotate((1, 0, 0), 45.0, 0.0), "rate_deg_s"),
        (lambda: Rotate((1, 0, 0), 0.0, 10.0), "angle_deg"),
        (lambda: Hold(-1.0), "duration_s"),
        (lambda: rotation_sequence([], 100.0), "steps"),
        (lambda: random_motion(1.0, 100.0, seed=-1), "seed"),
        (lambda: random_motion(1.0, 100.0, seed=0, bandwidth_hz=60.0), "bandwidth_hz"),
        (lambda: random_motion(1.0, 100.0, seed=0, translation_m=-0.1), "translation_m"),
        (lambda: limb_swing(1.0, 100.0, axis=(0, 0, 1)), "axis must be horizontal"),
        (lambda: limb_swing(1.0, 100.0, length_m=0.0), "length_m"),
        (lambda: limb_swing(1.0, 100.0, amplitude_deg=200.0), "amplitude_deg"),
        (lambda: limb_swing(1.0, 100.0, frame="NWU"), "frame"),
    ],
)
def test_bad_parameters_are_named(build, match):
    with pytest.raises(ValueError, match=match):
        build()
