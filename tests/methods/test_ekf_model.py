"""Marins' EKF model (001 eqs. 9-19): discretisation, Jacobians, noise, one filter step."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.methods.ekf import kernel as k
from margtrack.single_frame.gauss_newton_kernel import gauss_newton_solve

pytestmark = pytest.mark.kernel

TAU = np.array([0.3, 0.5, 2.0])


def _transition(x, h, tau=TAU):
    xn, f, g, d = np.empty(7), np.empty((7, 7)), np.empty((4, 3)), np.empty((4, 3))
    k.transition(np.asarray(x, dtype=np.float64), h, tau, xn, f, g, d)
    return xn, f, g


def _paper_rhs(x, tau):
    """001 eqs. 9-15 as printed (noise-free), with 001's order [p, q, r, a, b, c, d]."""
    x1, x2, x3, x4, x5, x6, x7 = x
    s = 1.0 / (2.0 * np.sqrt(x4**2 + x5**2 + x6**2 + x7**2))
    return np.array([
        -x1 / tau[0], -x2 / tau[1], -x3 / tau[2],
        s * (x3 * x5 - x2 * x6 + x1 * x7),
        s * (-x3 * x4 + x1 * x6 + x2 * x7),
        s * (x2 * x4 - x1 * x5 + x3 * x7),
        s * (-x1 * x4 - x2 * x5 - x3 * x6),
    ])


def _to_paper(x):
    return np.r_[x[:3], x[4:7], x[3]]  # [ω, w, x, y, z] -> [ω, a, b, c, d]


def _from_paper(x):
    return np.r_[x[:3], x[6], x[3:6]]


RNG = np.random.default_rng(11)
STATES = [
    np.r_[1.3, -0.7, 2.1, quat.normalize(RNG.normal(size=4))],
    np.r_[1e-9, 0.0, -2e-9, quat.normalize(RNG.normal(size=4))],
    np.r_[30.0, -20.0, 10.0, quat.normalize(RNG.normal(size=4))],
    np.r_[1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0],  # 001 5.2's initial state, |q| = 2
]


@pytest.mark.parametrize("x", STATES)
def test_jacobian_matches_finite_differences(x):
    h = 0.01
    _, f, _ = _transition(x, h)
    fd = np.empty((7, 7))
    eps = 1e-6
    for j in range(7):
        dx = np.zeros(7)
        dx[j] = eps
        fd[:, j] = (_transition(x + dx, h)[0] - _transition(x - dx, h)[0]) / (2 * eps)
    # central differences: truncation ~eps² |f'''| and rounding ~1e-16/eps, both < 1e-9
    np.testing.assert_allclose(f, fd, atol=2e-9)


def test_rate_block_is_exact_and_quaternion_is_the_flow_of_eqs_12_15():
    # equal τ: the rate keeps its direction and the step is the exact solution of 9-15
    tau = np.full(3, 0.4)
    for x in STATES:
        h = 0.05
        xn, _, _ = _transition(x, h, tau)
        sol = solve_ivp(lambda t, y: _paper_rhs(y, tau), (0.0, h), _to_paper(x),
                        rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(xn, _from_paper(sol.y[:, -1]), atol=1e-12)
        np.testing.assert_allclose(xn[:3], np.exp(-h / tau) * x[:3], rtol=1e-15)
        # eqs. 12-15 keep |q| (q ⊗ (0, ω) is orthogonal to q)
        assert np.linalg.norm(xn[3:]) == pytest.approx(np.linalg.norm(x[3:]), rel=1e-14)


def test_small_step_derivative_is_the_papers_state_equations():
    # (f(x, h) - x)/h -> ẋ of eqs. 9-15 as printed, to first order in h
    for x in STATES[:2] + STATES[3:]:
        h = 1e-7
        xn, _, _ = _transition(x, h)
        np.testing.assert_allclose((xn - x) / h, _from_paper(_paper_rhs(_to_paper(x), TAU)),
                                   atol=1e-5 * (1 + np.abs(x).max() ** 2))


def test_unequal_time_constants_are_exact_to_second_order():
    x = STATES[0]
    for h in (0.01, 0.005):
        xn, _, _ = _transition(x, h)
        sol = solve_ivp(lambda t, y: _paper_rhs(y, TAU), (0.0, h), _to_paper(x),
                        rtol=1e-12, atol=1e-14)
        err = np.abs(xn - _from_paper(sol.y[:, -1])).max()
        # the rate axis turns within the step: error O(h³ |ω|²/τ), tiny at sample rates
        assert err < h**3 * np.linalg.norm(x[:3]) ** 2 / TAU.min()


@pytest.mark.parametrize("theta", [[0.3, -0.2, 0.5], [1e-4, 2e-4, -1e-4], [2.0, -1.0, 0.5]])
def test_exp_jacobian(theta):
    theta = np.array(theta)
    d = np.empty((4, 3))
    e = np.array(k.exp_jacobian(*theta, d))
    np.testing.assert_allclose(e, quat.from_rotvec(theta), atol=1e-15)
    fd = np.empty((4, 3))
    for j in range(3):
        dt = np.zeros(3)
        dt[j] = 1e-6
        fd[:, j] = (quat.from_rotvec(theta + dt) - quat.from_rotvec(theta - dt)) / 2e-6
    np.testing.assert_allclose(d, fd, atol=1e-9)


@pytest.mark.parametrize(("h", "tau"), [(0.01, 0.3), (0.0035, 5.0), (1e-3, 1e4), (0.2, 0.05)])
def test_axis_noise_is_van_loans_exact_discretisation(h, tau):
    # per axis: d[ω, φ] = [[-1/τ, 0], [1, 0]] [ω, φ] dt + [1/τ, 0] w_r, E w_r² = σ²
    sigma2 = 2.5
    a = np.array([[-1.0 / tau, 0.0], [1.0, 0.0]])
    b = np.array([[1.0 / tau], [0.0]])
    vl = scipy.linalg.expm(np.block([[-a, sigma2 * b @ b.T], [np.zeros((2, 2)), a.T]]) * h)
    phi = vl[2:, 2:].T
    q = phi @ vl[:2, 2:]
    var_w, cov_pw, var_p = k.axis_noise(h, tau, sigma2)
    np.testing.assert_allclose([var_w, cov_pw, var_p], [q[0, 0], q[1, 0], q[1, 1]], rtol=1e-7)


def test_process_noise_is_the_linear_noise_mapped_into_the_quaternion():
    x, h = STATES[0], 0.01
    _, f, g = _transition(x, h)
    rate_var = np.array([4.0, 1.0, 9.0])
    qn = np.empty((7, 7))
    k.process_noise(g, h, TAU, rate_var, qn)
    per_axis = np.array([k.axis_noise(h, TAU[i], rate_var[i]) for i in range(3)])
    t = np.zeros((7, 6))  # [Δω, Δφ] -> [Δω, G Δφ]
    t[:3, :3] = np.eye(3)
    t[3:, 3:] = g
    lin = np.zeros((6, 6))
    lin[:3, :3] = np.diag(per_axis[:, 0])
    lin[3:, :3] = lin[:3, 3:] = np.diag(per_axis[:, 1])
    lin[3:, 3:] = np.diag(per_axis[:, 2])
    np.testing.assert_allclose(qn, t @ lin @ t.T, atol=1e-18)
    assert np.linalg.eigvalsh(qn)[0] > -1e-18
    # G is ∂q⁺/∂φ: F_qω = G diag(c) with c = τ (1 - e^{-h/τ})
    np.testing.assert_allclose(f[3:, :3], g * TAU * (1 - np.exp(-h / TAU)), rtol=1e-14)


@pytest.mark.parametrize("scale", [1.0, 1.7])
def test_vector_measurement_and_its_jacobian(scale):
    q = scale * quat.normalize(np.array([0.3, -0.5, 0.7, 0.4]))
    v = np.array([0.2, 0.6, -0.77]) / np.linalg.norm([0.2, 0.6, -0.77])  # unit earth vector
    jac = np.empty((3, 4))
    z = np.array(k.vector_measurement(*q, *v, jac))
    # the body-frame reading of v at the orientation q/|q| (what the simulator produces)
    np.testing.assert_allclose(z, quat.rotate_inverse(q / scale, v), atol=1e-15)
    fd = np.empty((3, 4))
    for j in range(4):
        dq = np.zeros(4)
        dq[j] = 1e-6
        fd[:, j] = (np.array(k.vector_measurement(*(q + dq), *v, np.empty((3, 4))))
                    - np.array(k.vector_measurement(*(q - dq), *v, np.empty((3, 4))))) / 2e-6
    np.testing.assert_allclose(jac, fd, atol=1e-9)


def test_eq_19_as_printed_turns_the_reference_the_wrong_way():
    q = quat.normalize(np.array([0.3, -0.5, 0.7, 0.4]))
    w, x, y, z = q
    a, b, c, d = x, y, z, w  # 001's names
    h = np.array([0.0, 0.5, -0.866])
    printed = ((a**2 + d**2 - b**2 - c**2) * h[0] + 2 * (a * b - c * d) * h[1]
               + 2 * (a * c + b * d) * h[2])
    assert printed == pytest.approx(quat.rotate(q, h)[0], abs=1e-15)  # (R h)_1
    assert abs(printed - quat.rotate_inverse(q, h)[0]) > 0.1  # not the body reading
    jac = np.empty((3, 4))
    derived = k.vector_measurement(*q, *h, jac)[0]  # signs of the cd, bd terms flipped
    flipped = ((a**2 + d**2 - b**2 - c**2) * h[0] + 2 * (a * b + c * d) * h[1]
               + 2 * (a * c - b * d) * h[2])
    assert derived == pytest.approx(flipped, abs=1e-15)


def _kernel_step(approach, x0, p0, gyr, acc, mag, h, up, field, noise):
    """One predicted + corrected sample of the kernel's step from x0, P0 over h: x, P and
    the Gauss-Newton iterations (the row and coefficients set by hand, no screening)."""
    c = np.zeros(k.N_COEF)  # the rest null's minimum still start 0: off
    c[k.C_APPROACH] = approach
    c[k.C_TAU : k.C_TAU + 3] = TAU
    c[k.C_RATE_VAR : k.C_RATE_VAR + 3] = noise["rate"]
    c[k.C_GYR_VAR : k.C_GYR_VAR + 3] = noise["gyr"]
    c[k.C_QUAT_VAR], c[k.C_ACC_VAR], c[k.C_MAG_VAR] = noise["quat"], noise["acc"], noise["mag"]
    c[k.C_GRAVITY2], c[k.C_MAG_WEIGHT], c[k.C_GN_TOL], c[k.C_GN_MAX_IT] = 9.81**2, 1.0, 1e-12, 3
    c[k.C_UP : k.C_UP + 3] = up
    c[k.C_DIP] = np.arcsin(-field @ up)  # a given dip: its reference field is used
    c[k.C_FIELD : k.C_FIELD + 3] = field
    row = np.zeros(k.N_ROW)
    k._start(row, c, True, *x0[3:])
    row[k.E_X : k.E_X + 7] = x0
    row[k.E_P : k.E_P + 49] = p0.ravel()
    q_out, x_out = np.empty(4), np.empty(15)
    assert k._step(row, c, h, *gyr, *acc, *mag, True, q_out, x_out) == 0
    assert x_out[k.X_CODE] == k.OK
    x = row[k.E_X : k.E_X + 7].copy()
    return x, row[k.E_P : k.E_P + 49].reshape(7, 7).copy(), x_out[k.X_ITER]


def test_one_step_equals_the_textbook_ekf_equations():
    up = frames.up("ENU")
    field = frames.mag_reference("ENU", 60.0)
    q_true = quat.normalize(np.array([0.8, 0.1, -0.3, 0.5]))
    x0 = np.r_[0.4, -0.2, 0.3, quat.normalize(q_true + [0.02, -0.03, 0.01, 0.02])]
    p0 = np.diag([0.5, 0.4, 0.3, 0.02, 0.03, 0.02, 0.01])
    p0[0, 4] = p0[4, 0] = 0.01
    gyr = np.array([0.45, -0.1, 0.25])
    acc = 9.81 * quat.rotate_inverse(q_true, up) + [0.1, -0.2, 0.05]
    mag = 50.0 * quat.rotate_inverse(q_true, field) + [0.5, 0.2, -0.4]
    noise = {"rate": np.array([2.0, 1.0, 3.0]), "gyr": np.array([1e-4, 2e-4, 1e-4]),
             "quat": 1e-4, "acc": 0.01, "mag": 0.5 / 50.0**2}  # mag: relative to the norm
    h = 0.01
    xp, f, g = _transition(x0, h)
    qn = np.empty((7, 7))
    k.process_noise(g, h, TAU, noise["rate"], qn)
    pp = f @ p0 @ f.T + qn
    ua, um = acc / np.linalg.norm(acc), mag / np.linalg.norm(mag)
    for approach in (2, 1):
        if approach == 2:
            nq = xp[3:] / np.linalg.norm(xp[3:])
            ok, *qm, _, _ = gauss_newton_solve(*ua, *um, *up, *field, *nq, 1.0, 1e-12, 3)
            assert ok
            qm = np.array(qm) * np.sign(np.dot(qm, xp[3:]))
            hm = np.eye(7)
            innov = np.r_[gyr - xp[:3], qm - xp[3:]]
            r = np.r_[noise["gyr"] / h, np.full(4, noise["quat"] / h)]
        else:
            qv = xp[3:] / np.linalg.norm(xp[3:])
            pred = np.r_[quat.rotate_inverse(qv, up), quat.rotate_inverse(qv, field)]
            hm = np.zeros((9, 7))
            hm[:3, :3] = np.eye(3)
            for j in range(4):  # measurement Jacobian by finite differences, independent
                dq = np.zeros(4)
                dq[j] = 1e-7
                plus, minus = quat.normalize(xp[3:] + dq), quat.normalize(xp[3:] - dq)
                hm[3:, 3 + j] = (np.r_[quat.rotate_inverse(plus, up), quat.rotate_inverse(
                    plus, field)] - np.r_[quat.rotate_inverse(minus, up),
                                          quat.rotate_inverse(minus, field)]) / 2e-7
            innov = np.r_[gyr - xp[:3], np.r_[ua, um] - pred]
            r = np.r_[noise["gyr"] / h, np.full(3, noise["acc"] / h / 9.81**2),
                      np.full(3, noise["mag"] / h)]
        s = hm @ pp @ hm.T + np.diag(r)
        gain = pp @ hm.T @ np.linalg.inv(s)
        x = xp + gain @ innov
        x[3:] /= np.linalg.norm(x[3:])
        p = (np.eye(7) - gain @ hm) @ pp
        x_k, p_k, iterations = _kernel_step(approach, x0, p0, gyr, acc, mag, h, up, field, noise)
        tol = 1e-12 if approach == 2 else 1e-8  # approach 1: H by finite differences
        np.testing.assert_allclose(x_k, x, atol=tol)
        np.testing.assert_allclose(p_k, p, atol=tol * np.abs(p).max())
        assert (iterations >= 1) == (approach == 2)
