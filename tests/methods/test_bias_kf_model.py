"""Ang's filter model (003 eqs. 21-28, 38, 45-46): paper slips, Jacobians, covariances."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.methods.bias_kf import kernel as k

pytestmark = pytest.mark.kernel


def _qtilde(q):
    out = np.empty((4, 3))
    k.fill_qtilde(*q, out)
    return out


def _phi_q(theta):
    out = np.empty((4, 4))
    k.fill_phi_q(*theta, out)
    return out


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _omega_tilde(w, sign):
    """003 eq. 21 with ``sign`` in front of Ω× (printed: +1)."""
    m = np.zeros((4, 4))
    m[0, 1:] = -w
    m[1:, 0] = w
    m[1:, 1:] = sign * _skew(w)
    return m


Q = quat.normalize(np.array([0.3, -0.5, 0.7, 0.4]))
W = np.array([0.8, -1.3, 0.4])


def test_qtilde_is_right_multiplication_and_eq_24_printed_order_is_vector_first():
    # Q̃ b = q ⊗ (0, b); 003 eq. 24 prints the scalar row [-q1, -q2, -q3] last
    qt = _qtilde(Q)
    np.testing.assert_allclose(qt @ W, quat.multiply(Q, np.r_[0.0, W]), atol=1e-15)
    w, x, y, z = Q
    printed = np.array([[w, -z, y], [z, w, -x], [-y, x, w], [-x, -y, -z]])
    assert not np.allclose(printed @ W, quat.multiply(Q, np.r_[0.0, W]))
    np.testing.assert_array_equal(printed[[3, 0, 1, 2]], qt)  # the row swap
    np.testing.assert_allclose(qt.T @ qt, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(qt.T @ Q, 0.0, atol=1e-15)


def test_eq_21_needs_minus_cross_for_body_to_earth_kinematics():
    # q̇ = ½ q ⊗ (0, ω) is ½ Ω̃ q with -Ω× (derived); the printed +Ω× is ½ (0, ω) ⊗ q
    derived, printed = _omega_tilde(W, -1.0), _omega_tilde(W, +1.0)
    np.testing.assert_allclose(0.5 * derived @ Q, quat.rate(Q, W), atol=1e-15)
    np.testing.assert_allclose(
        0.5 * printed @ Q, 0.5 * quat.multiply(np.r_[0.0, W], Q), atol=1e-15
    )
    assert not np.allclose(printed @ Q, derived @ Q)
    # eq. 23: Ω̃(B) Q = Q̃ B holds with the derived signs
    np.testing.assert_allclose(derived @ Q, _qtilde(Q) @ W, atol=1e-15)


@pytest.mark.parametrize("theta", [[0.02, -0.01, 0.03], [1e-9, 0.0, -2e-9], [2.0, -1.0, 0.5]])
def test_phi_q_is_exact_orthogonal_integration(theta):
    theta = np.array(theta)
    phi = _phi_q(theta)
    np.testing.assert_allclose(phi @ Q, quat.integrate(Q, theta, 1.0), atol=1e-15)
    np.testing.assert_allclose(phi @ phi.T, np.eye(4), atol=1e-15)
    # eq. 27 form: cos(|Θ|/2) I + sin(|Θ|/2)/|Θ| Θ̃
    a = np.linalg.norm(theta)
    np.testing.assert_allclose(
        phi, np.cos(a / 2) * np.eye(4) + np.sin(a / 2) / a * _omega_tilde(theta, -1.0),
        atol=1e-15,
    )


def _propagate(x, gyr, dt):
    """The filter's mean prediction: q ⊗ exp((ω - b) dt / 2), b unchanged."""
    return np.r_[quat.integrate(x[:4], gyr - x[4:], dt), x[4:]]


@pytest.mark.parametrize("rate", [0.5, 8.0])
def test_transition_matrix_against_finite_differences(rate):
    # Φ = [[Φ_Q, -½ T Φ_Q Q̃], [0, I]] (eqs. 26-28 with T restored in eq. 28)
    dt = 1.0 / 286.0
    b = np.array([0.01, -0.02, 0.015])
    gyr = rate * np.array([0.6, -0.48, 0.64])
    x = np.r_[Q, b]
    v = (gyr - b) * dt
    phi = _phi_q(v)
    phi_b = -0.5 * dt * phi @ _qtilde(Q)
    jac = np.empty((7, 7))
    h = 1e-7
    for j in range(7):
        e = np.zeros(7)
        e[j] = h
        jac[:, j] = (_propagate(x + e, gyr, dt) - _propagate(x - e, gyr, dt)) / (2 * h)
    # the quaternion block is linear in q: Φ_Q exactly (to finite-difference rounding)
    np.testing.assert_allclose(jac[:4, :4], phi, atol=1e-8)
    np.testing.assert_allclose(jac[4:], np.c_[np.zeros((3, 4)), np.eye(3)], atol=1e-8)
    # Φ_B is first order: d exp(v/2)/dv - ½ R(exp(v/2))[0; I] = (0, ¼ v × ·) + O(v²),
    # so |J_b - Φ_B| <= T |v| / 4 (to O(v²)); and it is not exact (the bound is tight)
    gap = np.linalg.norm(jac[:4, 4:] - phi_b, 2)
    bound = dt * np.linalg.norm(v) / 4.0
    assert gap <= 1.05 * bound + 1e-8
    assert gap >= 0.9 * bound


def _mc_error_quaternions(cov3, n, seed):
    rng = np.random.default_rng(seed)
    theta = rng.multivariate_normal(np.zeros(3), cov3, size=n)
    return quat.multiply(Q, quat.from_rotvec(theta)) - Q


def test_quaternion_noise_covariance_matches_monte_carlo():
    # V = ¼ Q̃ Ξ Q̃ᵀ + E|θ|⁴/64 q qᵀ (eq. 46 plus the second-order term along q)
    cov3 = np.array([[4e-3, 1e-3, 0.0], [1e-3, 2e-3, -5e-4], [0.0, -5e-4, 1e-3]])
    out = np.empty((4, 4))
    k.fill_quat_noise(*Q, cov3, np.empty((4, 3)), out)
    d = _mc_error_quaternions(cov3, 400_000, 1)
    second_moment = d.T @ d / len(d)
    tangent = np.linalg.qr(np.c_[Q, np.eye(4)[:, :3]])[0][:, 1:]
    # tangential block: sampling error sqrt(2/N) ≈ 0.2 %, neglected O(|θ|²) ≈ 0.5 %
    np.testing.assert_allclose(
        tangent.T @ out @ tangent, tangent.T @ second_moment @ tangent,
        rtol=0.02, atol=0.02 * np.abs(out).max(),
    )
    # along q: E[(cos(|θ|/2) - 1)²] vs E|θ|⁴/64 (heavy-tailed estimate: a few % error)
    assert Q @ out @ Q == pytest.approx(Q @ second_moment @ Q, rel=0.05)
    assert np.min(np.linalg.eigvalsh(out)) > 0.0


def _triad_numpy(acc, mag):
    """TRIAD (003 eqs. 10-13) vectorised in numpy, ENU: body triad on gravity, then field."""

    def triad(a, b):
        r1 = a / np.linalg.norm(a, axis=-1, keepdims=True)
        r2 = np.cross(r1, b)
        r2 /= np.linalg.norm(r2, axis=-1, keepdims=True)
        return np.stack([r1, r2, np.cross(r1, r2)], axis=-1)

    ref = triad(frames.up("ENU"), frames.mag_reference("ENU", 0.0))
    return quat.from_matrix(ref @ np.swapaxes(triad(acc, mag), -1, -2))


def test_triad_error_covariance_eq_45_matches_monte_carlo():
    q = quat.normalize(np.array([0.9, 0.2, -0.3, 0.25]))
    z = quat.rotate_inverse(q, frames.up("ENU"))
    n = quat.rotate_inverse(q, frames.mag_reference("ENU", 60.0))
    sg, sn = 0.01, 0.03
    rng = np.random.default_rng(0)
    m = 200_000
    acc = 9.81 * (z + rng.normal(scale=sg, size=(m, 3)))
    mag = n + rng.normal(scale=sn, size=(m, 3))
    theta = quat.to_rotvec(quat.multiply(quat.conjugate(q), _triad_numpy(acc, mag)))
    out = np.empty((3, 3))
    k.fill_triad_cov(*z, *n, sg**2, sn**2, out)
    # sampling error of a covariance entry ~ sqrt(2/m) of the largest ≈ 0.3 %; 3x margin
    np.testing.assert_allclose(np.cov(theta.T), out, atol=0.01 * np.abs(out).max())


def _eq_38(c):
    q0 = np.sqrt(max(1.0 + np.trace(c), 0.0)) / 2.0
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.array([q0, (c[1, 2] - c[2, 1]) / (4 * q0), (c[2, 0] - c[0, 2]) / (4 * q0),
                         (c[0, 1] - c[1, 0]) / (4 * q0)])


def test_four_branch_quaternion_agrees_with_eq_38_and_survives_half_turns():
    # eq. 38 reads q from ᵂC_B = Rᵀ with q0 = sqrt(1 + tr)/2: valid only away from q0 = 0
    rng = np.random.default_rng(4)
    up, north = frames.up("ENU"), frames.mag_reference("ENU", 0.0)
    qs = quat.canonical(quat.normalize(rng.normal(size=(40, 4))))
    qs = np.concatenate([qs[qs[:, 0] > 0.1], quat.from_axis_angle([[1, 2, 0]], [np.pi])])
    for i, q in enumerate(qs):
        acc = quat.rotate_inverse(q, up)
        mag = quat.rotate_inverse(q, frames.mag_reference("ENU", 60.0))
        res = k._triad(*acc, *mag, up, north)
        assert res[0] == k.OK
        assert abs(np.dot(res[1:5], q)) == pytest.approx(1.0, abs=1e-12)
        eq38 = _eq_38(quat.to_matrix(q).T)
        if i < len(qs) - 1:
            np.testing.assert_allclose(res[1:5], eq38, atol=1e-12)
        else:  # the half turn: eq. 38 divides by ~0 and loses the axis
            assert not (np.all(np.isfinite(eq38)) and abs(np.dot(eq38, q)) > 0.999)


def _block_diag(a, b):
    out = np.zeros((a.shape[0] + b.shape[0],) * 2)
    out[: a.shape[0], : a.shape[0]] = a
    out[a.shape[0]:, a.shape[0]:] = b
    return out


def test_kernel_equals_a_plain_numpy_implementation_of_eqs_25_to_51():
    # oracle: 7x7 matrices, np.linalg.inv and the simple covariance update of eq. 51
    from margtrack import sim
    from margtrack.methods.bias_kf import BiasKalman, BiasKalmanParams, initial_covariance

    rec = sim.simulate(sim.random_motion(3.0, 100.0, seed=5), frame="ENU",
                       gyr_errors=sim.SensorErrors.mems_gyr(),
                       acc_errors=sim.SensorErrors.mems_acc(),
                       mag_errors=sim.SensorErrors.mems_mag(), seed=5)
    p = BiasKalmanParams.as_printed(gyr_noise_rad_s_sqrt_hz=(1e-3, 2e-3, 1.5e-3),
                                    acc_motion_fraction=0.05)
    est = BiasKalman(p).run(rec)
    t = 0.01
    up, north = frames.up("ENU"), frames.mag_reference("ENU", 0.0)
    q, b = est.quat[0].copy(), np.zeros(3)
    cov = initial_covariance(q, p.init_angle_std_rad, p.init_bias_std_rad_s)[0]
    gyr_var, walk_var = p.axis_variances()
    h = np.c_[np.eye(4), np.zeros((4, 3))]
    v, w4 = np.empty((4, 4)), np.empty((4, 4))
    xi = np.empty((3, 3))
    for i in range(1, rec.n_samples):
        phi = _phi_q((rec.gyr[i] - b) * t)
        f = np.eye(7)
        f[:4, :4], f[:4, 4:] = phi, -0.5 * t * phi @ _qtilde(q)  # eqs. 26-28
        q = phi @ q  # eq. 47
        k.fill_quat_noise(*q, np.diag(gyr_var * t), np.empty((4, 3)), w4)
        cov = f @ cov @ f.T + _block_diag(w4, np.diag(walk_var * t))  # eqs. 31, 48
        res = k._triad(*rec.acc[i], *rec.mag[i], up, north)
        z = np.array(res[1:5]) * np.sign(np.dot(res[1:5], q))  # eq. 38, sign nearest q⁻
        var_g = (p.acc_noise_m_s2_sqrt_hz**2 / t + (p.acc_motion_fraction * 9.80665) ** 2)
        k.fill_triad_cov(*res[5:11], var_g / 9.80665**2,
                         p.mag_relative_var() / t * np.sum(rec.mag[0] ** 2)
                         / np.sum(rec.mag[i] ** 2), xi)  # eq. 45, σ_M = σ_rel |m₀|
        k.fill_quat_noise(*q, xi, np.empty((4, 3)), v, 1.0)  # eq. 46
        gain = cov @ h.T @ np.linalg.inv(h @ cov @ h.T + v)  # eq. 49
        x = np.r_[q, b] + gain @ (z - q)  # eq. 50
        cov = (np.eye(7) - gain @ h) @ cov  # eq. 51
        cov = 0.5 * (cov + cov.T)
        q, b = x[:4] / np.linalg.norm(x[:4]), x[4:]
        np.testing.assert_allclose(est.quat[i], q, atol=1e-12)
        np.testing.assert_allclose(est.outputs["gyr_bias_rad_s"][i], b, atol=1e-12)
    np.testing.assert_allclose(est.outputs["cov_diag"][-1], np.diag(cov), rtol=1e-9)

