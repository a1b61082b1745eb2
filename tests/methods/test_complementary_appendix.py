"""Bachmann filter (000, Appendix A): Jacobians by finite differences, the Gauss-Newton step,
and the compiled filter against a literal numpy transcription of eqs. 13-27."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.methods.bachmann import (
    Bachmann,
    BachmannAccMag,
    criterion,
    error_vector,
    gauss_newton_step,
    predicted_vectors,
    x_matrix,
    xv_matrix,
)

pytestmark = pytest.mark.kernel

M_ENU = frames.up("ENU")
N_ENU = frames.mag_reference("ENU", 60.0)
#: the field reference of these tests, with the screening's disturbance gate open: the
#: random signals below would trip it, and these tests compare the filter's equations
FIELD = {"mag_dip_ref_deg": 60.0, "mag_norm_tol": 1e9, "mag_dip_tol_deg": 360.0}
RNG = np.random.default_rng(7)
Q = quat.normalize(RNG.normal(size=4))


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _prediction(q):
    """[q*⊗m⊗q; q*⊗n⊗q] vector parts for any (not necessarily unit) q, the map X derives."""
    qc = quat.conjugate(q)
    out = []
    for ref in (M_ENU, N_ENU):
        out.append(quat.multiply(quat.multiply(qc, np.r_[0.0, ref]), q)[1:])
    return np.concatenate(out)


def test_x_matrix_is_the_derivative_of_the_prediction_by_central_differences():
    step = 1e-6
    fd = np.empty((6, 4))
    for j in range(4):
        e = np.zeros(4)
        e[j] = step
        fd[:, j] = (_prediction(Q + e) - _prediction(Q - e)) / (2 * step)
    # central differences of a quadratic map are exact up to rounding (~1e-10)
    np.testing.assert_allclose(x_matrix(Q, M_ENU, N_ENU), fd, atol=1e-9)


def test_xv_matrix_is_the_derivative_along_q_times_one_plus_v_and_equals_2_skew():
    step = 1e-6
    fd = np.empty((6, 3))
    for j in range(3):
        v = np.zeros(3)
        v[j] = step
        plus = _prediction(quat.multiply(Q, np.r_[1.0, v]))
        minus = _prediction(quat.multiply(Q, np.r_[1.0, -v]))
        fd[:, j] = (plus - minus) / (2 * step)
    xv = xv_matrix(Q, M_ENU, N_ENU)
    np.testing.assert_allclose(xv, fd, atol=1e-9)
    h_hat, b_hat = predicted_vectors(Q, M_ENU, N_ENU)
    np.testing.assert_allclose(xv, np.vstack([2 * _skew(h_hat), 2 * _skew(b_hat)]), atol=1e-14)


def test_error_vector_moves_by_minus_weighted_xv_so_rho_is_not_in_the_jacobian():
    rho = 0.4
    acc, mag = RNG.normal(size=3), RNG.normal(size=3)
    step = 1e-6
    fd = np.empty((6, 3))
    for j in range(3):
        v = np.zeros(3)
        v[j] = step
        plus = error_vector(quat.multiply(Q, np.r_[1.0, v]), acc, mag, M_ENU, N_ENU, rho)
        minus = error_vector(quat.multiply(Q, np.r_[1.0, -v]), acc, mag, M_ENU, N_ENU, rho)
        fd[:, j] = (plus - minus) / (2 * step)
    weights = np.r_[1.0, 1.0, 1.0, rho, rho, rho][:, None]
    np.testing.assert_allclose(fd, -weights * xv_matrix(Q, M_ENU, N_ENU), atol=1e-8)


def test_one_full_gauss_newton_step_converges_quadratically_with_rho_one():
    q_true = Q
    acc, mag = (quat.rotate_inverse(q_true, r) for r in (M_ENU, N_ENU))
    for angle in (1e-2, 1e-3):
        q_hat = quat.multiply(q_true, quat.from_rotvec(angle * np.array([0.6, -0.48, 0.64])))
        dv = gauss_newton_step(q_hat, acc, mag, M_ENU, N_ENU, 1.0)
        q_new = quat.normalize(quat.multiply(q_hat, np.r_[1.0, dv]))  # q̂ + Δq_full (eq. 24)
        # Gauss-Newton on a zero-residual problem: error after one step is O(angle²)
        assert quat.angle_between(q_new, q_true) < 2 * angle**2
        assert criterion(q_new, acc, mag, M_ENU, N_ENU, 1.0) < 1e-3 * criterion(
            q_hat, acc, mag, M_ENU, N_ENU, 1.0
        )


def test_a_heading_error_is_corrected_by_the_fraction_rho_of_a_full_step():
    q_true = quat.from_euler([0.3, 0.0, 0.0])
    acc, mag = (quat.rotate_inverse(q_true, r) for r in (M_ENU, N_ENU))
    heading_error = 1e-4  # rad, about the vertical (body z is vertical here)
    q_hat = quat.multiply(q_true, quat.from_rotvec([0.0, 0.0, heading_error]))
    for rho in (1.0, 0.5, 0.25):
        dv = gauss_newton_step(q_hat, acc, mag, M_ENU, N_ENU, rho)
        # q̂ ⊗ (1, Δv) turns by 2 Δv: a full step (rho = 1) removes the error
        assert 2 * dv[2] == pytest.approx(-rho * heading_error, rel=1e-3)
        assert abs(dv[0]) + abs(dv[1]) < 1e-3 * abs(dv[2])


# -- the compiled filter against eqs. 13-27 written out --------------------------------------
def _reference(q0, gyr, acc, mag, dt, gains, rhos, interval=1):
    """Literal Appendix A; between new corrections the earth-frame step is held."""
    q = np.array(q0, dtype=np.float64)
    quats, phis, held, phi = [], [], np.zeros(3), np.nan
    for i in range(len(acc)):
        if i % interval == 0:
            if mag is None:
                # X_v has rank 2 without a field: the minimum-norm least-squares step
                h_hat = predicted_vectors(q, M_ENU, N_ENU)[0]
                xv = 2 * _skew(h_hat)
                eps = acc[i] / np.linalg.norm(acc[i]) - h_hat
                dv = np.linalg.lstsq(xv, eps, rcond=1e-10)[0]
                phi = float(eps @ eps)
            else:
                dv = gauss_newton_step(q, acc[i], mag[i], M_ENU, N_ENU, rhos[i])  # eq. 23
                phi = criterion(q, acc[i], mag[i], M_ENU, N_ENU, rhos[i])  # eq. 19
            held = quat.rotate(q, dv)
        q_dot_eps = gains[i] * quat.multiply(np.r_[0.0, held], q)  # = k q̂⊗(0, Δv) (24-25)
        q_dot = 0.5 * quat.multiply(q, np.r_[0.0, gyr[i]]) if gyr is not None else 0.0  # 26
        q = quat.normalize(q + dt[i] * (q_dot + q_dot_eps))  # eq. 27
        quats.append(q)
        phis.append(phi)
    return np.array(quats), np.array(phis)


def _signals(n=300, seed=11):
    rng = np.random.default_rng(seed)
    gyr = rng.normal(scale=0.8, size=(n, 3))
    acc = rng.normal(scale=1.5, size=(n, 3)) + [0.0, 0.0, 9.81]
    mag = rng.normal(scale=3.0, size=(n, 3)) + 50 * N_ENU
    return gyr, acc, mag


@pytest.mark.parametrize("interval", [1, 3])
def test_compiled_filter_equals_the_literal_appendix(interval):
    gyr, acc, mag = _signals()
    dt = np.r_[0.0, np.full(len(acc) - 1, 0.01)]
    q0 = quat.from_euler([0.4, -0.2, 0.3])
    est = Bachmann(gain=3.0, mag_weight=0.6, correction_interval=interval, **FIELD)
    est.reset(q0)
    out = est.run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    n = len(acc)
    ref_q, ref_phi = _reference(q0, gyr, acc, mag, dt, [3.0] * n, [0.6] * n, interval)
    np.testing.assert_allclose(out.quat, ref_q, atol=1e-12)
    np.testing.assert_allclose(out.outputs["phi"], ref_phi, atol=1e-12)
    np.testing.assert_array_equal(out.outputs["new_correction"], np.arange(n) % interval == 0)


def test_compiled_filter_equals_the_appendix_without_magnetometer_and_without_gyro():
    gyr, acc, mag = _signals(200, seed=5)
    dt = np.r_[0.0, np.full(len(acc) - 1, 0.01)]
    q0 = quat.from_euler([0.1, 0.5, -0.3])
    n = len(acc)
    six = Bachmann(gain=2.0, **FIELD)
    six.reset(q0)
    ref = _reference(q0, gyr, acc, None, dt, [2.0] * n, [1.0] * n)[0]
    np.testing.assert_allclose(six.run(gyr=gyr, acc=acc, rate_hz=100.0).quat, ref, atol=1e-12)
    accmag = BachmannAccMag(gain=2.0, mag_weight=0.7, **FIELD)
    accmag.reset(q0)
    ref = _reference(q0, None, acc, mag, dt, [2.0] * n, [0.7] * n)[0]
    got = accmag.run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0).quat  # gyr is ignored
    np.testing.assert_allclose(got, ref, atol=1e-12)


def test_gain_and_mag_weight_changed_between_samples_take_effect_at_the_next_sample():
    gyr, acc, mag = _signals(120, seed=2)
    n = len(acc)
    dt = np.r_[0.0, np.full(n - 1, 0.01)]
    gains = np.where(np.arange(n) < 40, 1.0, np.where(np.arange(n) < 80, 8.0, 0.5))
    rhos = np.where(np.arange(n) < 60, 1.0, 0.25)
    q0 = quat.from_euler([0.2, 0.1, 0.0])
    est = Bachmann(gain=1.0, mag_weight=1.0, rate_hz=100.0, **FIELD)
    est.reset(q0)
    live = []
    for i in range(n):
        if i in (40, 60, 80):
            est.set_params(gain=float(gains[i]), mag_weight=float(rhos[i]))
        live.append(est.update(gyr[i], acc[i], mag[i]))
    ref = _reference(q0, gyr, acc, mag, dt, gains, rhos)[0]
    np.testing.assert_allclose(np.array(live), ref, atol=1e-12)
    fixed = _reference(q0, gyr, acc, mag, dt, [1.0] * n, [1.0] * n)[0]
    assert quat.angle_between(ref[-1], fixed[-1]) > 1e-3  # the changes mattered
