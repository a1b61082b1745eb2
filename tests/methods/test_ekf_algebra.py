"""The EKF's hand-derived sparse algebra against dense textbook EKF equations (7 and 10 states).

The oracle is the dense form the kernel used before (``F P Fᵀ + Q`` with full matrices, a
batch Joseph-form update with a matrix inverse), built here with numpy from the kernel's
public model functions (whose Jacobians other tests check by finite differences).
"""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import sim
from margtrack.estimator import skeleton as kc
from margtrack.estimator.triad_kernel import unit_pair
from margtrack.methods.ekf import MarinsEkf, model
from margtrack.methods.ekf import bias_kernel as kb
from margtrack.methods.ekf import kernel as k
from margtrack.single_frame.gauss_newton_kernel import gauss_newton_solve

pytestmark = pytest.mark.kernel

TAU = np.array([0.3, 0.5, 2.0])
RATE_VAR = np.array([2.0, 1.0, 3.0])
WALK_VAR = np.array([1e-6, 4e-6, 2.5e-7])


def _dense_transition(x, h, n):
    """x⁺, F (n x n), Q (n x n) of the model, dense (the bias a random walk for n = 10)."""
    xn, f7, g, d = np.empty(7), np.empty((7, 7)), np.empty((4, 3)), np.empty((4, 3))
    k.transition(x[:7].copy(), h, TAU, xn, f7, g, d)
    q7 = np.empty((7, 7))
    k.process_noise(g, h, TAU, RATE_VAR, q7)
    f, q = np.eye(n), np.zeros((n, n))
    f[:7, :7], q[:7, :7] = f7, q7
    if n == 10:
        q[7:, 7:] = np.diag(WALK_VAR * h)
    return np.r_[xn, x[7:]], f, q


def _f10(x, h):
    return _dense_transition(x, h, 10)[0]


@pytest.mark.parametrize("seed", [0, 1])
def test_predicted_covariance_is_f_p_ft_plus_q_with_f_by_finite_differences(seed):
    rng = np.random.default_rng(seed)
    x = np.r_[rng.normal(size=3), rng.normal(size=4) * 0.7, rng.normal(size=3) * 0.01]
    h = 0.01
    f = np.empty((10, 10))
    for j in range(10):  # the 10-state map's Jacobian, central differences
        dx = np.zeros(10)
        dx[j] = 1e-6
        f[:, j] = (_f10(x + dx, h) - _f10(x - dx, h)) / 2e-6
    _, f_model, q = _dense_transition(x, h, 10)
    np.testing.assert_allclose(f_model, f, atol=2e-9)
    a = np.exp(-h / TAU)
    c = -TAU * np.expm1(-h / TAU)
    _, g, fqq, _ = model.transition_terms(*x[:7], *a, *c)
    noise = np.array([k.axis_noise(h, TAU[i], RATE_VAR[i]) for i in range(3)])
    m = rng.normal(size=(10, 10))
    p0 = m @ m.T  # any symmetric positive definite P
    row = np.zeros(100)
    row[:] = p0.ravel()
    model.predict_covariance(row, 0, 10, tuple(a), tuple(c), g, fqq, tuple(noise[:, 0]),
                             tuple(noise[:, 1]), tuple(noise[:, 2]), tuple(WALK_VAR * h))
    model.mirror(row, 0, 10)
    expected = f @ p0 @ f.T + q
    np.testing.assert_allclose(row.reshape(10, 10), expected, atol=1e-8 * np.abs(expected).max())
    np.testing.assert_allclose(row.reshape(10, 10), f_model @ p0 @ f_model.T + q,
                               atol=1e-13 * np.abs(expected).max())


def _coefficients(approach, n):
    est = MarinsEkf(approach=approach, tau_s=tuple(TAU),
                    rate_noise_rad_s_sqrt_hz=tuple(np.sqrt(RATE_VAR)),
                    gyr_bias_walk_rad_s_sqrt_s=tuple(np.sqrt(WALK_VAR)),
                    gyr_noise_rad_s_sqrt_hz=(1e-3, 2e-3, 1.5e-3), quat_noise_per_sqrt_hz=0.05,
                    mag_dip_ref_deg=60.0, gyr_null_rest_s=0.0, gn_max_iterations=3,
                    init_bias_std_rad_s=0.02, bias_states=n == 10,
                    mag_disturbance_s=0.0)  # 001's fixed noise: the dense oracle's
    return est._coefs[kc.N_SCOEF:].copy()


def _dense_step(x, p, c, h, gyr, acc, mag, n):
    """One textbook EKF step: dense prediction, batch Joseph update, q normalised."""
    xp, f, q = _dense_transition(x, h, n)
    pp = f @ p @ f.T + q
    up, field = c[k.C_UP : k.C_UP + 3], c[k.C_FIELD : k.C_FIELD + 3]
    hg = np.zeros((3, n))
    hg[:, :3] = np.eye(3)
    if n == 10:
        hg[:, 7:] = np.eye(3)
    rows, innov = [hg], [gyr - hg @ xp]
    r = list(c[k.C_GYR_VAR : k.C_GYR_VAR + 3] / h)
    _, ax, ay, az, mx, my, mz = unit_pair(*acc, *mag)
    if c[k.C_APPROACH] == 2:
        qn = xp[3:7] / np.linalg.norm(xp[3:7])
        ok, *qm, _, _ = gauss_newton_solve(ax, ay, az, mx, my, mz, *up, *field, *qn,
                                           c[k.C_MAG_WEIGHT], c[k.C_GN_TOL],
                                           int(c[k.C_GN_MAX_IT]))
        assert ok
        qm = np.array(qm) * np.sign(np.dot(qm, xp[3:7]))
        hq = np.zeros((4, n))
        hq[:, 3:7] = np.eye(4)
        rows.append(hq)
        innov.append(qm - xp[3:7])
        r += [c[k.C_QUAT_VAR] / h] * 4
    else:
        for v, meas, var in ((up, (ax, ay, az), c[k.C_ACC_VAR] / h / c[k.C_GRAVITY2]),
                             (field, (mx, my, mz), c[k.C_MAG_VAR] / h)):
            jac = np.empty((3, 4))
            z = np.array(k.vector_measurement(*xp[3:7], *v, jac))
            hv = np.zeros((3, n))
            hv[:, 3:7] = jac
            rows.append(hv)
            innov.append(np.array(meas) - z)
            r += [var] * 3
    hm, nu, rm = np.vstack(rows), np.concatenate(innov), np.diag(r)
    gain = pp @ hm.T @ np.linalg.inv(hm @ pp @ hm.T + rm)
    a = np.eye(n) - gain @ hm
    x1 = xp + gain @ nu
    x1[3:7] /= np.linalg.norm(x1[3:7])
    return x1, a @ pp @ a.T + gain @ rm @ gain.T


@pytest.mark.parametrize("n", [7, 10])
@pytest.mark.parametrize("approach", [2, 1])
def test_many_steps_equal_the_dense_joseph_form_ekf(approach, n):
    # the 7-state kernel as it was before the sparse algebra (option off), and the bias one
    rec = sim.simulate(sim.random_motion(2.0, 100.0, seed=4, max_rate_deg_s=120.0,
                                         translation_m=0.02),
                       gyr_errors=sim.SensorErrors(bias=(0.02, -0.01, 0.015)),
                       acc_errors=sim.SensorErrors.mems_acc(),
                       mag_errors=sim.SensorErrors.mems_mag(), dip_deg=60.0, seed=4)
    mod = kb if n == 10 else k
    c = _coefficients(approach, n)
    row = np.zeros(mod.N_ROW)
    mod._start(row, c, True, *rec.quat_true[0])
    p_off = k.E_X + n
    x = row[k.E_X : k.E_X + n].copy()
    p = row[p_off : p_off + n * n].reshape(n, n).copy()
    np.testing.assert_array_equal(np.diag(p)[7:], np.full(n - 7, 0.02**2))
    q_out, x_out = np.empty(4), np.empty(30)
    worst_x = worst_p = 0.0
    for i in range(1, 150):
        h = rec.t[i] - rec.t[i - 1]
        flags = mod._step(row, c, h, *rec.gyr[i], *rec.acc[i], *rec.mag[i], True, q_out, x_out)
        assert flags == 0
        x, p = _dense_step(x, p, c, h, rec.gyr[i], rec.acc[i], rec.mag[i], n)
        xk = row[k.E_X : k.E_X + n]
        pk = row[p_off : p_off + n * n].reshape(n, n)
        np.testing.assert_array_equal(pk, pk.T)  # exactly symmetric
        worst_x = max(worst_x, np.abs(xk - x).max())
        worst_p = max(worst_p, np.abs(pk - p).max() / np.abs(p).max())
        np.testing.assert_allclose(q_out, x[3:7], atol=1e-12)
    tol = 1e-12 if approach == 2 else 1e-11  # approach 1's vector rows: more rounding
    assert worst_x < tol and worst_p < tol, (worst_x, worst_p)
    if n == 10:  # the filter's bias moved from 0 towards the simulated one
        assert np.all(np.abs(x[7:]) > 0.0)


@pytest.mark.parametrize("max_iterations", [0, 1, 2, 5, 50])
@pytest.mark.parametrize("tolerance", [0.0, 1e-14, 1e-4])
def test_inline_fit_is_the_shared_gauss_newton_solver(max_iterations, tolerance):
    """ekf_fit.fit (the step's inline Gauss-Newton fit, which forms the normal equations
    only where the next update is taken) returns the quaternion and the iteration count of
    gauss_newton_solve, from guesses near and far (halvings) and with vectors that do not
    fit one rotation (the cap, not the tolerance, ends it)."""
    from margtrack.methods.ekf.fit import fit

    rng = np.random.default_rng(7)
    up = np.array([0.0, 0.0, 1.0])
    field = np.array([0.0, np.cos(1.1), -np.sin(1.1)])
    iterations_seen = set()
    for trial in range(300):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        # body readings of the references at q, disturbed (more for later trials)
        noise = 0.002 * (1 + trial % 5) ** 2
        g = _rotate_to_body(q, up) + noise * rng.normal(size=3)
        m = _rotate_to_body(q, field) + noise * rng.normal(size=3)
        flag, ax, ay, az, mx, my, mz = unit_pair(*g, *m)
        assert flag == 0
        guess = q + (0.05 if trial % 3 else 1.5) * rng.normal(size=4)
        want = gauss_newton_solve(ax, ay, az, mx, my, mz, *up, *field, *guess, 0.8, tolerance,
                                  max_iterations)
        got = fit(ax, ay, az, mx, my, mz, *up, *field, *guess, 0.8, tolerance, max_iterations)
        assert got[0] == want[0]
        if tolerance > 0.0 or got[5] == want[5]:
            assert got[5] == want[5]
            np.testing.assert_allclose(got[1:5], want[1:5], rtol=0, atol=1e-12)
        else:
            # tolerance 0 stops where Q no longer falls (|ΔQ| ~ 1e-16): decided by the last
            # bits, which the solver's fastmath (FMA contraction, per CPU) may round apart;
            # one step more or less there moves the iterate by about √ΔQ
            assert abs(got[5] - want[5]) == 1
            np.testing.assert_allclose(got[1:5], want[1:5], rtol=0, atol=1e-8)
        iterations_seen.add(want[5])
    # the cap was hit (where the last normal equations are skipped)
    if max_iterations <= 2 or (tolerance == 0.0 and max_iterations <= 5):
        assert max(iterations_seen) == max_iterations


def _rotate_to_body(q, v):
    """R(q)ᵀ v for a unit quaternion q = [w, x, y, z] (body-to-earth)."""
    w, x, y, z = q
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])
    return r.T @ v
