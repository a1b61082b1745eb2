"""Gradient filter kernel: 004's objective and Jacobian, Euler and acceleration outputs, frames."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.estimator import Flag
from margtrack.methods.gradient import ACC_IGNORED, MAG_IGNORED, MAG_REJECTED, Gradient
from margtrack.methods.gradient.kernel import objective_jacobian

pytestmark = pytest.mark.kernel


def _f_and_j(q, d, s):
    f = np.empty(3)
    j = np.empty((3, 4))
    objective_jacobian(np.asarray(q, float), np.asarray(d, float), np.asarray(s, float), f, j)
    return f, j


def _cases(n, seed):
    rng = np.random.default_rng(seed)
    return quat.normalize(rng.normal(size=(n, 4))), rng.normal(size=(n, 3)), rng.normal(size=(n, 3))


def test_objective_is_rotate_inverse_minus_measurement():
    # 004's f is q* ⊗ d ⊗ q - s; its extracted rows 2 and 3 have sign slips, ours must not
    for q, d, s in zip(*_cases(50, 1), strict=True):
        f, _ = _f_and_j(q, d, s)
        np.testing.assert_allclose(f, quat.rotate_inverse(q, d) - s, atol=1e-13)


def test_jacobian_matches_central_finite_differences():
    # f is quadratic in q, so central differences are exact up to rounding: O(eps_mach / h)
    h = 1e-6
    for q, d, s in zip(*_cases(50, 2), strict=True):
        _, j = _f_and_j(q, d, s)
        numeric = np.empty((3, 4))
        for k in range(4):
            step = np.zeros(4)
            step[k] = h
            numeric[:, k] = (_f_and_j(q + step, d, s)[0] - _f_and_j(q - step, d, s)[0]) / (2 * h)
        np.testing.assert_allclose(j, numeric, atol=1e-8)


def test_jacobian_equals_004_except_the_ocr_slip_in_the_last_entry():
    q1, q2, q3, q4 = quat.normalize([0.3, -0.5, 0.7, 0.2])
    xx, xy, xz = 0.4, -1.1, 0.8
    # 004 "General Optimization Algorithm", J_f as printed (x = reference direction)
    printed = np.array(
        [
            [2 * xy * q4 - 2 * xz * q3, 2 * xy * q3 + 2 * xz * q4,
             -4 * xx * q3 + 2 * xy * q2 - 2 * xz * q1, -4 * xx * q4 + 2 * xy * q1 + 2 * xz * q2],
            [-2 * xx * q4 + 2 * xz * q2, 2 * xx * q3 - 4 * xy * q2 + 2 * xz * q1,
             2 * xx * q2 + 2 * xz * q4, -2 * xx * q1 - 4 * xy * q4 + 2 * xz * q3],
            [2 * xx * q3 - 2 * xy * q2, 2 * xx * q4 - 2 * xy * q1 - 4 * xz * q2,
             2 * xx * q1 + 2 * xy * q4 - 4 * xz * q3, 2 * xx * q2 - 2 * xy * q3 - 3],
        ]
    )
    _, j = _f_and_j([q1, q2, q3, q4], [xx, xy, xz], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(j.ravel()[:-1], printed.ravel()[:-1], atol=1e-14)
    # the printed last entry is wrong; the derivative of 2x_y(q3 q4 - q1 q2) by q4 is +2x_y q3
    assert abs(printed[2, 3] - j[2, 3]) > 0.1
    assert j[2, 3] == pytest.approx(2 * xx * q2 + 2 * xy * q3, abs=1e-15)


def _one_step(frame, q0, acc, mag=None, **params):
    """Outputs of the first sample (dt = 0) for S sensors starting at q0 (S, 4)."""
    f = Gradient(frame=frame, **params)
    f.reset(q0)
    est = f.run(gyr=np.zeros((len(q0), 1, 3)), acc=acc[:, None], t=[0.0],
                mag=None if mag is None else mag[:, None])
    return est


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_euler_gravity_and_linear_acceleration_outputs(frame):
    rng = np.random.default_rng(3)
    q0 = quat.normalize(rng.normal(size=(200, 4)))
    acc = rng.normal(scale=12.0, size=(200, 3))
    est = _one_step(frame, q0, acc, gravity_m_s2=9.81)
    q = est.quat[:, 0]
    assert np.max(quat.angle_between(q, q0)) < 1e-12
    # 004's atan2/asin formulas are the ZYX angles of quaternion.to_euler
    np.testing.assert_allclose(est.outputs["euler_rad"][:, 0], quat.to_euler(q), atol=1e-10)
    up = frames.up(frame)
    np.testing.assert_allclose(
        est.outputs["gravity_body_m_s2"][:, 0], 9.81 * quat.rotate_inverse(q, up), atol=1e-12
    )
    np.testing.assert_allclose(
        est.outputs["lin_acc_earth_m_s2"][:, 0], quat.rotate(q, acc) - 9.81 * up, atol=1e-12
    )


@pytest.mark.parametrize("objective", ["forward", "forward_measured", "madgwick", "fixed"])
@pytest.mark.parametrize("integration", ["exact", "euler"])
def test_enu_and_ned_give_the_same_rotation(objective, integration):
    # the recursion runs in one internal frame, so the output frame is a pure conversion
    rng = np.random.default_rng(4)
    n = 300
    gyr = rng.normal(scale=2.0, size=(n, 3))
    acc = rng.normal(size=(n, 3)) + [0.0, 0.0, 9.8]
    mag = rng.normal(scale=5.0, size=(n, 3)) + [10.0, 20.0, -40.0]
    q0 = quat.normalize([0.9, 0.1, -0.2, 0.3])
    runs = {}
    for frame in ("ENU", "NED"):
        f = Gradient(frame=frame, beta=0.5, mag_objective=objective, integration=integration)
        f.reset(q0 if frame == "ENU" else frames.convert(q0, "ENU", "NED"))
        runs[frame] = f.run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    back = frames.convert(runs["NED"].quat, "NED", "ENU")
    assert np.max(quat.angle_between(back, runs["ENU"].quat)) < 1e-12


def test_degenerate_samples_are_flagged_not_nan():
    q0 = np.array([[1.0, 0.0, 0.0, 0.0]] * 3)
    acc = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 9.8], [0.0, 0.0, 9.8]])
    # sensor 1: zero field; sensor 2: field parallel to gravity (no forward component)
    mag = np.array([[20.0, 0.0, -40.0], [0.0, 0.0, 0.0], [0.0, 0.0, -40.0]])
    est = _one_step("ENU", q0, acc, mag)
    # sensor 0's field is given but unused without gravity, sensor 2's has no forward
    # component: the filter's own rejections (MAG_REJECTED), unlike sensor 1's zero field
    np.testing.assert_array_equal(
        est.outputs["ignored"][:, 0],
        [ACC_IGNORED | MAG_REJECTED, MAG_IGNORED, MAG_IGNORED | MAG_REJECTED],
    )
    assert np.all(np.isfinite(est.quat))
    # in the common schema (the screening flagged the zero acc and the zero field itself)
    np.testing.assert_array_equal(
        est.flags[:, 0],
        [Flag.ACC_IGNORED | Flag.MAG_IGNORED, Flag.MAG_IGNORED, Flag.MAG_IGNORED],
    )
    # Madgwick's full vector still uses a vertical field; a zero one is ignored
    est = _one_step("ENU", q0, acc, mag, mag_objective="madgwick")
    np.testing.assert_array_equal(
        est.outputs["ignored"][:, 0], [ACC_IGNORED | MAG_REJECTED, MAG_IGNORED, 0]
    )
    np.testing.assert_array_equal(
        est.flags[:, 0], [Flag.ACC_IGNORED | Flag.MAG_IGNORED, Flag.MAG_IGNORED, 0]
    )


def test_zero_accelerometer_step_is_pure_gyro_integration():
    gyr = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.5], [0.1, 0.4, -0.3]])
    f = Gradient(beta=1.0)
    q0 = quat.normalize([0.8, 0.2, 0.1, -0.4])
    f.reset(q0)
    est = f.run(gyr=gyr, acc=np.zeros((3, 3)), mag=np.ones((3, 3)), t=[0.0, 0.1, 0.3])
    expected = quat.integrate(quat.integrate(q0, gyr[1], 0.1), gyr[2], 0.2)
    assert quat.angle_between(est.quat[-1], expected) < 1e-12
    # the given field is not used without the accelerometer: flagged as such
    assert np.all(est.outputs["ignored"] == ACC_IGNORED | MAG_REJECTED)
    assert np.all(est.flags & (Flag.ACC_IGNORED | Flag.MAG_IGNORED))
