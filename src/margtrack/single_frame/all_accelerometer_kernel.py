"""Kernel of the all-accelerometer angular-velocity solver (003 eqs. 1-6).

Row ``k`` of the system pairs baseline ``P_k`` (rows ``P13, P23, P12``) with body axis
``k``: ``g_k(Ω) = [(Ω×Ω× + Ω̇×) P_k]_k`` with ``Ω̇ = (Ω - Ω_prev)/T`` (eq. 3), and the
residual ``f = A_D - g(Ω)`` (eq. 5) is driven to zero by Gauss-Newton or
Levenberg-Marquardt (eq. 6). The extracted eq. 5 repeats ``P23|y`` and ``a_12x`` in its
third row; eq. 4 (``A_D = [a13x, a23y, a12z]``) and Fig. 1 (sensors {1} and {2} both sense
z) make it ``a12z`` and ``P12|z``, as used here.
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator.jit import njit
from margtrack.methods.bias_kf.kernel import bias_kf


@njit(cache=True)
def residual_jacobian(omega, omega_prev, a_d, baselines, dt, r_out, j_out):
    """Residual ``r = A_D - g(Ω)`` (3,) and Jacobian ``J = ∂g/∂Ω`` (3, 3); returns |r|².

    ``Ω×(Ω×P) = Ω (Ω·P) - P |Ω|²``, so ``∂g_k/∂Ω_j = δ_kj (Ω·P) + Ω_k P_j - 2 P_k Ω_j
    + ε_kjb P_b / T`` (the last term from ``(Ω̇ × P)_k = ε_kab Ω̇_a P_b``).
    """
    w0, w1, w2 = omega[0], omega[1], omega[2]
    d0, d1, d2 = (w0 - omega_prev[0]) / dt, (w1 - omega_prev[1]) / dt, (w2 - omega_prev[2]) / dt
    ww = w0 * w0 + w1 * w1 + w2 * w2
    cost = 0.0
    for k in range(3):
        px, py, pz = baselines[k, 0], baselines[k, 1], baselines[k, 2]
        wp = w0 * px + w1 * py + w2 * pz
        if k == 0:
            tang = d1 * pz - d2 * py
            j_out[0, 0], j_out[0, 1], j_out[0, 2] = 0.0, pz / dt, -py / dt
            wk, pk = w0, px
        elif k == 1:
            tang = d2 * px - d0 * pz
            j_out[1, 0], j_out[1, 1], j_out[1, 2] = -pz / dt, 0.0, px / dt
            wk, pk = w1, py
        else:
            tang = d0 * py - d1 * px
            j_out[2, 0], j_out[2, 1], j_out[2, 2] = py / dt, -px / dt, 0.0
            wk, pk = w2, pz
        r_out[k] = a_d[k] - (wk * wp - pk * ww + tang)
        cost += r_out[k] * r_out[k]
        j_out[k, 0] += wk * px - 2.0 * pk * w0
        j_out[k, 1] += wk * py - 2.0 * pk * w1
        j_out[k, 2] += wk * pz - 2.0 * pk * w2
        j_out[k, k] += wp
    return cost


@njit(cache=True)
def _solve3(a, b, out):
    """Solve the 3x3 system ``a x = b`` by cofactors; returns False if ``a`` is singular."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    scale = 0.0
    for i in range(3):
        for j in range(3):
            scale = max(scale, abs(a[i, j]))
    if not abs(det) > 1e-300 + 1e-14 * scale * scale * scale:
        return False
    inv = 1.0 / det
    out[0] = inv * (c00 * b[0] + (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) * b[1]
                    + (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) * b[2])
    out[1] = inv * (c01 * b[0] + (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) * b[1]
                    + (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) * b[2])
    out[2] = inv * (c02 * b[0] + (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) * b[1]
                    + (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) * b[2])
    return True


@njit(cache=True)
def solve_rates(
    diff_acc, baselines, dt, omega_state, damping, max_iter, tol,
    omega_out, iters_out, converged_out, residual_out,
):  # fmt: skip
    """Angular velocity (N, 3) rad/s from differential accelerations (N, 3) m/s².

    ``omega_state`` (3,) in/out: Ω of the sample before the first (Ω(0) of eq. 3),
    replaced by the last solution. ``dt`` (N,) s; ``dt[i] <= 0`` outputs the state unchanged
    (first sample). Each sample starts from the previous Ω. ``damping`` = 0: Gauss-Newton,
    ``δ = (JᵀJ)⁻¹ Jᵀ r``; > 0: Levenberg-Marquardt with ``(JᵀJ + λ diag(JᵀJ)) δ = Jᵀ r``,
    starting at ``λ = damping``, divided by 10 after a step that lowers ``|r|²`` and
    multiplied by 10 (step rejected) otherwise. Stops when ``|δ| <= tol (1 + |Ω|)``.
    Outputs iterations (N,), converged (N,) bool and the final ``|r|`` (N,) m/s².
    """
    prev = omega_state.copy()
    om = omega_state.copy()
    trial = omega_state.copy()
    r = omega_state.copy()
    j = baselines.copy()
    jtj = baselines.copy()
    jtr = omega_state.copy()
    step = omega_state.copy()
    for i in range(diff_acc.shape[0]):
        h = dt[i]
        iters = 0
        done = True
        cost = 0.0
        if h > 0.0:
            for k in range(3):
                prev[k] = om[k]
            lam = damping
            cost = residual_jacobian(om, prev, diff_acc[i], baselines, h, r, j)
            done = False
            while iters < max_iter and not done:
                iters += 1
                for a in range(3):
                    jtr[a] = j[0, a] * r[0] + j[1, a] * r[1] + j[2, a] * r[2]
                    for b in range(3):
                        jtj[a, b] = j[0, a] * j[0, b] + j[1, a] * j[1, b] + j[2, a] * j[2, b]
                for a in range(3):
                    jtj[a, a] *= 1.0 + lam
                if not _solve3(jtj, jtr, step):
                    break
                size = math.sqrt(step[0] ** 2 + step[1] ** 2 + step[2] ** 2)
                for a in range(3):
                    trial[a] = om[a] + step[a]
                if damping > 0.0:
                    new_cost = residual_jacobian(trial, prev, diff_acc[i], baselines, h, r, j)
                    if new_cost < cost or new_cost == 0.0:
                        for a in range(3):
                            om[a] = trial[a]
                        cost = new_cost
                        lam *= 0.1
                    else:
                        # rejected: more damping; a step below tolerance means converged
                        lam *= 10.0
                        cost = residual_jacobian(om, prev, diff_acc[i], baselines, h, r, j)
                        norm = math.sqrt(om[0] ** 2 + om[1] ** 2 + om[2] ** 2)
                        done = size <= tol * (1.0 + norm)
                        continue
                else:
                    for a in range(3):
                        om[a] = trial[a]
                    cost = residual_jacobian(om, prev, diff_acc[i], baselines, h, r, j)
                norm = math.sqrt(om[0] ** 2 + om[1] ** 2 + om[2] ** 2)
                done = size <= tol * (1.0 + norm)
        for a in range(3):
            omega_out[i, a] = om[a]
        iters_out[i] = iters
        converged_out[i] = done
        residual_out[i] = math.sqrt(cost)
    for a in range(3):
        omega_state[a] = om[a]


@njit(cache=True)
def track(
    diff_acc, grav, mag, dt, baselines, omega_state, quat_state, bias_state, cov_state,
    up, north, gyr_var, bias_var, acc_var, acc_motion_var, gravity2, mag_var, feedback,
    damping, max_iter, tol, rate_out, quat_out, bias_out, cov_diag_out, flags,
):  # fmt: skip
    """Solver (:func:`solve_rates`) and bias Kalman filter sample by sample, one sensor.

    ``diff_acc``, ``grav``, ``mag`` (N, 3); ``omega_state`` (3,), ``quat_state`` (1, 4),
    ``bias_state`` (1, 3), ``cov_state`` (1, 7, 7) in/out. With ``feedback`` the filter's
    bias estimate is subtracted from the solver's previous rate after every sample and the
    bias state reset to zero (its covariance is unchanged: the error ``b - b̂`` is the same
    random variable), so the solver's backward difference (eq. 3) starts from the filtered
    rate. Outputs: rate_out (N, 3) the solver's rates as fed to the filter, quat_out (N, 4),
    bias_out (N, 3) the bias estimate before the reset, cov_diag_out (N, 7), flags (N,).
    """
    a1 = np.empty((1, 3))
    dt1 = np.empty(1)
    w1 = np.empty((1, 3))
    it1 = np.empty(1, dtype=np.int64)
    cv1 = np.empty(1, dtype=np.bool_)
    rs1 = np.empty(1)
    g3 = np.empty((1, 1, 3))
    a3 = np.empty((1, 1, 3))
    m3 = np.empty((1, 1, 3))
    q3 = np.empty((1, 1, 4))
    b3 = np.empty((1, 1, 3))
    c3 = np.empty((1, 1, 7))
    f2 = np.empty((1, 1), dtype=np.int8)
    for i in range(diff_acc.shape[0]):
        for k in range(3):
            a1[0, k] = diff_acc[i, k]
            a3[0, 0, k] = grav[i, k]
            m3[0, 0, k] = mag[i, k]
        dt1[0] = dt[i]
        solve_rates(a1, baselines, dt1, omega_state, damping, max_iter, tol, w1, it1, cv1, rs1)
        for k in range(3):
            g3[0, 0, k] = w1[0, k]
            rate_out[i, k] = w1[0, k]
        bias_kf(quat_state, bias_state, cov_state, g3, a3, m3, dt1, up, north, gyr_var,
                bias_var, acc_var, acc_motion_var, gravity2, mag_var, q3, b3, c3, f2)
        for k in range(4):
            quat_out[i, k] = q3[0, 0, k]
        for k in range(3):
            bias_out[i, k] = b3[0, 0, k]
        for k in range(7):
            cov_diag_out[i, k] = c3[0, 0, k]
        flags[i] = f2[0, 0]
        if feedback:
            for k in range(3):
                omega_state[k] -= bias_state[0, k]
                bias_state[0, k] = 0.0
