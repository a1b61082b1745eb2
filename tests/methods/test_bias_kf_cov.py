"""The bias filter's hand-derived covariance algebra against the dense matrices it replaces."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.methods.bias_kf import cov
from margtrack.methods.bias_kf import kernel as k

pytestmark = pytest.mark.kernel

P0, S0 = 0, 49  # P at row[0:49], the scratch after it
V0 = S0 + cov.N_SCRATCH  # a V (4, 4) after the scratch


def _row(p):
    row = np.full(V0 + 16, np.nan)  # scratch unset: every helper writes before it reads
    row[:49] = p.ravel()
    return row


def _spd(rng, scale_q=1e-4, scale_b=1e-6):
    a = rng.normal(size=(7, 7)) * np.sqrt(np.r_[np.full(4, scale_q), np.full(3, scale_b)])[:, None]
    return a @ a.T + np.diag(np.r_[np.full(4, 1e-9), np.full(3, 1e-12)])


def _qtilde(q):
    out = np.empty((4, 3))
    k.fill_qtilde(*q, out)
    return out


def _quat_noise(q, xi, along):
    out = np.empty((4, 4))
    k.fill_quat_noise(*q, xi, np.empty((4, 3)), out, along)
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_prediction_equals_the_dense_transition_of_eq_48(seed):
    # P⁻ = Φ P Φᵀ + diag(W, Ξ_B), Φ = [[Φ_Q, -½T Φ_Q Q̃(q)], [0, I]] (eqs. 26-28, 31)
    rng = np.random.default_rng(seed)
    p = _spd(rng)
    q = quat.normalize(rng.normal(size=4))
    h = 1.0 / 286.0
    theta = rng.normal(size=3) * 2.0 * h  # rad over the period
    xi = rng.uniform(1e-10, 1e-8, 3)
    walk = rng.uniform(1e-15, 1e-13, 3)
    row = _row(p)
    q_pred = cov.predict(row, P0, S0, h, *q, *theta, *xi, *walk)

    phi_q = np.empty((4, 4))
    k.fill_phi_q(*theta, phi_q)
    phi = np.eye(7)
    phi[:4, :4] = phi_q
    phi[:4, 4:] = -0.5 * h * phi_q @ _qtilde(q)
    expected_q = quat.normalize(phi_q @ q)
    expected = phi @ p @ phi.T
    expected[:4, :4] += _quat_noise(expected_q, np.diag(xi), -1.0)
    expected[4:, 4:] += np.diag(walk)
    np.testing.assert_allclose(q_pred, expected_q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(row[:49].reshape(7, 7), expected, rtol=1e-12,
                               atol=1e-14 * np.abs(expected).max())
    assert np.all(row[:49].reshape(7, 7) == row[:49].reshape(7, 7).T)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_update_equals_the_textbook_joseph_update_of_eqs_49_to_51(seed):
    # K = P Hᵀ (H P Hᵀ + V)⁻¹, dx = K ν, P⁺ = (I - KH) P (I - KH)ᵀ + K V Kᵀ, H = [I₄ 0]
    rng = np.random.default_rng(seed)
    p = _spd(rng)
    q = quat.normalize(rng.normal(size=4))
    xi = np.diag(rng.uniform(1e-5, 1e-3, 3))
    v = _quat_noise(q, xi, 1.0)
    innov = rng.normal(size=4) * 1e-2
    row = _row(p)
    row[V0:] = v.ravel()
    assert cov.kalman_update(row, P0, S0, V0, *innov)

    h = np.c_[np.eye(4), np.zeros((4, 3))]
    gain = p @ h.T @ np.linalg.inv(h @ p @ h.T + v)
    i_kh = np.eye(7) - gain @ h
    expected = i_kh @ p @ i_kh.T + gain @ v @ gain.T
    np.testing.assert_allclose(row[S0 + cov.F_DX : S0 + cov.F_DX + 7], gain @ innov,
                               rtol=1e-10, atol=1e-16)
    np.testing.assert_allclose(row[:49].reshape(7, 7), expected, rtol=1e-9,
                               atol=1e-12 * np.abs(expected).max())
    assert np.all(row[:49].reshape(7, 7) == row[:49].reshape(7, 7).T)
    assert np.linalg.eigvalsh(row[:49].reshape(7, 7))[0] > 0.0


def test_update_refuses_an_innovation_covariance_that_is_not_positive_definite():
    p = np.eye(7) * 1e-4
    v = -2e-4 * np.eye(4)  # S = P_qq + V = -1e-4 I
    row = _row(p)
    row[V0:] = v.ravel()
    assert not cov.kalman_update(row, P0, S0, V0, 0.1, 0.0, 0.0, 0.0)
    np.testing.assert_array_equal(row[:49], p.ravel())


@pytest.mark.parametrize("seed", [0, 1])
def test_decoupled_noise_is_eq_46_of_the_decoupled_angle_covariance(seed):
    # ¼ Q̃ (σ_G² (I - ẑẑᵀ) + σ_H² ẑẑᵀ) Q̃ᵀ + qqᵀ in closed form through Q̃ Q̃ᵀ = I - qqᵀ
    rng = np.random.default_rng(seed)
    q = quat.normalize(rng.normal(size=4))
    z = rng.normal(size=3)
    z /= np.linalg.norm(z)
    var_g, var_h = 2e-4, 3e-3
    xi = np.empty((3, 3))
    k.fill_decoupled_cov(*z, var_g, var_h, xi)
    row = np.zeros(16)
    cov.decoupled_noise(row, 0, *q, *cov.body_direction(*q, *z), var_g, var_h)
    np.testing.assert_allclose(row.reshape(4, 4), _quat_noise(q, xi, 1.0), rtol=0, atol=1e-15)
    np.testing.assert_allclose(cov.body_direction(*q, *z), _qtilde(q) @ z, atol=1e-15)


def test_tilt_variance_and_d2_equal_the_angle_covariance_formulas():
    # ½ (tr P_θ - ẑᵀ P_θ ẑ), P_θ = 4 Q̃ᵀ P_qq Q̃; d² = |θ⊥|² / (that + σ_G²)
    rng = np.random.default_rng(3)
    p = _spd(rng)
    q = quat.normalize(rng.normal(size=4))
    z = rng.normal(size=3)
    z /= np.linalg.norm(z)
    qt = _qtilde(q)
    p_theta = 4.0 * qt.T @ p[:4, :4] @ qt
    expected = 0.5 * (np.trace(p_theta) - z @ p_theta @ z)
    row = _row(p)
    got = cov.tilt_variance(row, P0, *q, *cov.body_direction(*q, *z))
    assert got == pytest.approx(expected, rel=1e-12)

    m = quat.multiply(q, quat.from_rotvec(np.array([0.02, -0.01, 0.03])))
    theta = 2.0 * quat.multiply(quat.conjugate(q), m)[1:]
    normal2 = theta @ theta - (theta @ z) ** 2
    d2 = cov.tilt_d2(row, P0, *q, *m, *z, 1e-4)
    assert d2 == pytest.approx(normal2 / (expected + 1e-4), rel=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_triad_noise_is_eq_46_of_eq_45s_angle_covariance(seed):
    # ¼ Q̃ Ξθ Q̃ᵀ + qqᵀ with eq. 45's Ξθ, written out here from the paper's formula
    rng = np.random.default_rng(seed)
    q = quat.normalize(rng.normal(size=4))
    z, n = rng.normal(size=3), rng.normal(size=3)
    z, n = z / np.linalg.norm(z), n / np.linalg.norm(n)
    var_g, var_n = 2e-4, 3e-3
    cross2 = np.sum(np.cross(z, n) ** 2)
    xi = var_g * np.eye(3) + ((var_n - var_g) * np.outer(z, z)
                              + var_g * (z @ n) * (np.outer(z, n) + np.outer(n, z))) / cross2
    expected = 0.25 * _qtilde(q) @ xi @ _qtilde(q).T + np.outer(q, q)
    row = np.zeros(16)
    cov.triad_noise(row, 0, *q, *z, *n, var_g, var_n)
    np.testing.assert_allclose(row.reshape(4, 4), expected, rtol=0, atol=1e-15)
    xi_kernel = np.empty((3, 3))
    k.fill_triad_cov(*z, *n, var_g, var_n, xi_kernel)  # the dense path it replaced
    np.testing.assert_allclose(row.reshape(4, 4), _quat_noise(q, xi_kernel, 1.0), rtol=0,
                               atol=1e-15)
