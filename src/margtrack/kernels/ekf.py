"""Kernel of Marins' 7-state quaternion EKF, both approaches (001 sections 3-4).

State per sensor: ``x = [ω (3), q (4)]``: the body angular rate ``[p, q, r]`` in rad/s and
the quaternion, here in margtrack's order ``[w, x, y, z]`` (001 lists the scalar ``d``
last), body-to-earth, Hamilton, and the full 7x7 covariance ``P``.

Process model (001 eqs. 9-15): ``ω̇ = (-ω + w_r)/τ`` per axis with white ``w_r`` of density
``σ`` (rad/s/√Hz), and ``q̇ = q ⊗ (0, ω) / (2|q|)`` (the quaternion product of eq. 7 with
eq. 8's normalisation in the denominator, as eqs. 12-15 write it). Eqs. 12-15 keep ``|q|``
constant (``q ⊗ (0, ω)`` is orthogonal to ``q``), so for a known rate history their flow
is ``q ⊗ exp(φ / (2|q|))`` with ``φ`` the integral of the rate.

Discretisation over a sample interval ``h`` (:func:`transition`, :func:`process_noise`):

- rate, exact: ``ω⁺ = a ω`` with ``a = exp(-h/τ)``;
- quaternion, the exact flow of eqs. 12-15 along the model's noise-free rate, whose
  integral is ``φ = c ω``, ``c = τ (1 - a)``: ``q⁺ = q ⊗ exp(c ω / (2|q|))`` (exact when τ
  is equal on the three axes; otherwise the rate axis turns within the interval and this
  is exact to second order in the angle);
- noise, exact for the linear part: the per-axis covariances of the rate increment and of
  its integral over the interval (Van Loan), ``Var Δω = σ²(1 - a²)/(2τ)``,
  ``Cov(Δφ, Δω) = σ²(1 - a)²/2``, ``Var Δφ = σ² τ (x - 2(1 - e⁻ˣ) + (1 - e⁻²ˣ)/2)`` with
  ``x = h/τ``; the quaternion's share is linearised, ``Δq = G Δφ`` with
  ``G = ∂q⁺/∂φ``.

The Jacobian ``F = ∂x⁺/∂x`` of that map is exact (tests compare it with finite
differences): ``F_ωω = diag(a)``, ``F_qω = G diag(c)``,
``F_qq = R(E) - (q⁺ ⊗ (0, θ/2)) qᵀ/|q|²`` with ``E = exp(θ/2)``, ``θ = c ω/|q|`` and
``R(E) q = q ⊗ E``.

Measurements:

- approach 2 (001 4.3, the paper's choice): ``z = [gyro, q_GN]``, ``H = I₇``, with ``q_GN``
  the Gauss-Newton quaternion (001 eqs. 20-23, :func:`gauss_newton_solve`) started from
  the predicted quaternion, its sign chosen nearest the prediction (002's closing remark);
- approach 1 (001 4.1): ``z = [gyro, â, m̂]``, the unit accelerometer and magnetometer
  vectors, ``h(x) = [ω, R(q)ᵀ u/|q|², R(q)ᵀ m_ref/|q|²]`` (eq. 19's form, with ``u`` up and
  ``m_ref`` the unit reference field) and its Jacobian (:func:`vector_measurement`).
  Eq. 19 as printed is ``(R h)₁``, the first component of ``h`` turned from body to
  earth; a body-frame reading of an earth vector is ``Rᵀ h`` (with eq. 6's ``R`` and eq.
  20's ``M`` mapping body to earth), so the ``cd`` and ``bd`` terms change sign here.

Both updates use the Joseph form ``P = (I - KH) P (I - KH)ᵀ + K R Kᵀ`` with ``S`` factored
by Cholesky, and mirror ``P`` so it is exactly symmetric; then ``q`` is normalised (001
Fig. 3).

Screened samples (``margtrack.estimator.screening``) and degenerate pairs:

- a zero magnetometer (no usable field): the gyroscope and the gravity direction alone,
  approach 1's accelerometer rows ``z = [gyro, â]``. In approach 2 their noise is twice
  the angular noise of the Gauss-Newton quaternion (a component error ε is a rotation of
  2ε, so a unit vector's component variance would be ``4 quat_var / h``; it is
  ``16 quat_var / h``): the screening drops the field mostly in fast motion, where the
  accelerometer is far from gravity too. On BROAD (16 trials, whose disturbed samples
  take this path) the mean total RMSE is 3.91 deg with 16, 4.00 with 4, 3.91 with 100,
  and 3.92 with the gyroscope alone; on 90 s of simulated motion with a clipped field
  (ignored on 97 % of the samples) 7.75 deg with 16, 7.68 with 4, 8.63 gyro alone;
- a zero accelerometer, a pair along one line, or a failed Gauss-Newton fit: the
  gyroscope alone (``H = [I₃ 0]``);
- the gyroscope measurement is limited to ±``MAX_RATE_RAD_S`` per axis (the screening
  replaces absurd rates first; this keeps every product finite on its own), and an
  update that would leave a zero or non-finite quaternion is undone (``NOT_PD``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from margtrack.kernels._linalg import add_kalman_gain, cholesky
from margtrack.kernels._quat import mul
from margtrack.kernels.davenport import reference_field
from margtrack.kernels.gauss_newton import gauss_newton_solve
from margtrack.kernels.triad import OK, PARALLEL, SOLVER_FAILED, ZERO_ACC, ZERO_MAG, unit_pair

#: flag: the innovation covariance was not positive definite (or the update would leave
#: a zero or non-finite quaternion): the update was skipped
NOT_PD = 5
#: the gyroscope measurement is limited to this, rad/s per axis (no sensor reaches it)
MAX_RATE_RAD_S = 1e6

__all__ = [
    "MAX_RATE_RAD_S",
    "NOT_PD",
    "OK",
    "PARALLEL",
    "SOLVER_FAILED",
    "ZERO_ACC",
    "ZERO_MAG",
    "axis_noise",
    "exp_jacobian",
    "marins_ekf",
    "process_noise",
    "transition",
    "vector_measurement",
]


@njit(cache=True)
def exp_jacobian(tx, ty, tz, out):
    """``E = exp(θ/2)`` for a rotation vector θ (rad), and ``∂E/∂θ`` (4, 3) into ``out``.

    ``E = [cos(α/2), s θ]`` with ``α = |θ|``, ``s = sin(α/2)/α``; ``∂E_w/∂θ = -½ s θᵀ`` and
    ``∂(s θ)/∂θ = s I + (s'/α) θ θᵀ`` (series below α = 0.01). Returns E's 4 components.
    """
    a2 = tx * tx + ty * ty + tz * tz
    alpha = math.sqrt(a2)
    if alpha < 1e-2:
        s = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
        ds = -1.0 / 24.0 + a2 / 960.0 - a2 * a2 / 107520.0
    else:
        sin_h, cos_h = math.sin(0.5 * alpha), math.cos(0.5 * alpha)
        s = sin_h / alpha
        ds = (0.5 * cos_h * alpha - sin_h) / (alpha * a2)
    t = (tx, ty, tz)
    for j in range(3):
        out[0, j] = -0.5 * s * t[j]
        for i in range(3):
            out[1 + i, j] = ds * t[i] * t[j] + (s if i == j else 0.0)
    return math.cos(0.5 * alpha), s * tx, s * ty, s * tz


@njit(cache=True)
def transition(x, h, tau_s, x_next, f, g, d):
    """One step of the discretised process model and its Jacobian (module docstring).

    x (7,) ``[ω (rad/s), q]`` (any non-zero ``|q|``); h > 0 interval, s; tau_s (3,) time
    constants, s. Fills x_next (7,), f = ∂x_next/∂x (7, 7) and g = ∂q⁺/∂φ (4, 3), the
    quaternion's response to a change of the integrated rate φ (rad), for the noise;
    d (4, 3) is a work buffer (it receives ∂E/∂θ).
    """
    w, qx, qy, qz = x[3], x[4], x[5], x[6]
    n2 = w * w + qx * qx + qy * qy + qz * qz
    nq = math.sqrt(n2)
    for r in range(7):
        for c in range(7):
            f[r, c] = 0.0
    for k in range(3):
        a = math.exp(-h / tau_s[k])
        x_next[k] = a * x[k]  # eqs. 9-11, exact
        f[k, k] = a
        f[3, k] = -tau_s[k] * math.expm1(-h / tau_s[k])  # c = τ(1 - a); scaled below
    c0, c1, c2 = f[3, 0], f[3, 1], f[3, 2]
    t0, t1, t2 = c0 * x[0] / nq, c1 * x[1] / nq, c2 * x[2] / nq  # θ = c ω / |q|
    e0, e1, e2, e3 = exp_jacobian(t0, t1, t2, d)
    pw, px, py, pz = mul(w, qx, qy, qz, e0, e1, e2, e3)  # eqs. 12-15, exact flow
    x_next[3], x_next[4], x_next[5], x_next[6] = pw, px, py, pz
    lq = ((w, -qx, -qy, -qz), (qx, w, -qz, qy), (qy, qz, w, -qx), (qz, -qy, qx, w))
    coef = (c0, c1, c2)
    for r in range(4):  # G = L(q) ∂E/∂θ / |q|;  F_qω = G diag(c)
        for c in range(3):
            g[r, c] = (lq[r][0] * d[0, c] + lq[r][1] * d[1, c] + lq[r][2] * d[2, c]
                       + lq[r][3] * d[3, c]) / nq
            f[3 + r, c] = g[r, c] * coef[c]
    # F_qq = R(E) - (q⁺ ⊗ (0, θ/2)) qᵀ / |q|²  (the |q| in θ = c ω / |q|)
    re = ((e0, -e1, -e2, -e3), (e1, e0, e3, -e2), (e2, -e3, e0, e1), (e3, e2, -e1, e0))
    u = mul(pw, px, py, pz, 0.0, 0.5 * t0, 0.5 * t1, 0.5 * t2)
    q = (w, qx, qy, qz)
    for r in range(4):
        for c in range(4):
            f[3 + r, 3 + c] = re[r][c] - u[r] * q[c] / n2


@njit(cache=True)
def axis_noise(h, tau_s, rate_var):
    """Covariances of one axis' rate increment Δω and its integral Δφ over an interval.

    Returns ``(Var Δω (rad/s)², Cov(Δφ, Δω) rad²/s, Var Δφ rad²)`` for the driving-noise
    density² ``rate_var`` ((rad/s)²/Hz), exact for ``ω̇ = (-ω + w_r)/τ`` (001 eq. 9).
    """
    xk = h / tau_s
    em1 = math.expm1(-xk)  # -(1 - a)
    var_w = -rate_var * math.expm1(-2.0 * xk) / (2.0 * tau_s)
    cov_pw = 0.5 * rate_var * em1 * em1
    if xk < 1e-2:  # x - 2(1 - e⁻ˣ) + (1 - e⁻²ˣ)/2 by its series (cancellation)
        x3 = xk * xk * xk
        gx = x3 * (1.0 / 3.0 - xk / 4.0 + xk * xk * 7.0 / 60.0 - x3 / 24.0
                   + x3 * xk * 31.0 / 2520.0)
    else:
        gx = xk + 2.0 * em1 - 0.5 * math.expm1(-2.0 * xk)
    return var_w, cov_pw, rate_var * tau_s * gx


@njit(cache=True)
def process_noise(g, h, tau_s, rate_var, out):
    """Process noise covariance (7, 7) over one interval (module docstring), into ``out``.

    g (4, 3) from :func:`transition`; h s; tau_s (3,) s; rate_var (3,) ``σ²`` of the
    driving noise, (rad/s)²/Hz. Exact for the rate and its integral; ``Δq = G Δφ``.
    """
    for r in range(7):
        for c in range(7):
            out[r, c] = 0.0
    v0 = axis_noise(h, tau_s[0], rate_var[0])
    v1 = axis_noise(h, tau_s[1], rate_var[1])
    v2 = axis_noise(h, tau_s[2], rate_var[2])
    cov_pw = (v0[1], v1[1], v2[1])
    var_p = (v0[2], v1[2], v2[2])
    out[0, 0], out[1, 1], out[2, 2] = v0[0], v1[0], v2[0]
    for k in range(3):
        for r in range(4):
            out[3 + r, k] = g[r, k] * cov_pw[k]
            out[k, 3 + r] = out[3 + r, k]
    for r in range(4):
        for c in range(4):
            out[3 + r, 3 + c] = (g[r, 0] * var_p[0] * g[c, 0] + g[r, 1] * var_p[1] * g[c, 1]
                                 + g[r, 2] * var_p[2] * g[c, 2])


@njit(cache=True)
def vector_measurement(w, x, y, z, vx, vy, vz, jac):
    """Body-frame reading ``R(q)ᵀ v / |q|²`` of a unit earth vector v, and its Jacobian.

    (001 eq. 19, derived sign.) Returns the 3 components; fills jac (3, 4) = ∂/∂q. With
    ``p = q* ⊗ v`` the unnormalised reading is ``vec(p ⊗ q)`` and its derivative along
    ``e_k`` is ``2 vec(p ⊗ e_k)``; dividing by ``|q|²`` subtracts ``2 z q_k / |q|²``.
    """
    n2 = w * w + x * x + y * y + z * z
    p0, p1, p2, p3 = mul(w, -x, -y, -z, 0.0, vx, vy, vz)
    _, gx, gy, gz = mul(p0, p1, p2, p3, w, x, y, z)
    zx, zy, zz = gx / n2, gy / n2, gz / n2
    cols = ((p1, p2, p3), (p0, p3, -p2), (-p3, p0, p1), (p2, -p1, p0))  # vec(p ⊗ e_k)
    q = (w, x, y, z)
    zv = (zx, zy, zz)
    for k in range(4):
        for i in range(3):
            jac[i, k] = 2.0 * (cols[k][i] - zv[i] * q[k]) / n2
    return zx, zy, zz


@njit(cache=True)
def _joseph(p, a, gain, r, m, zmat):
    """P ← A P Aᵀ + K diag(r) Kᵀ (A = I - KH given), upper triangle mirrored."""
    n = p.shape[0]
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += a[i, k] * p[k, j]
            zmat[i, j] = acc
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for k in range(n):
                acc += zmat[i, k] * a[j, k]
            for k in range(m):
                acc += gain[i, k] * r[k] * gain[j, k]
            p[i, j] = acc
    for i in range(n):
        for j in range(i):
            p[i, j] = p[j, i]


@njit(cache=True)
def _update(p, hm, r, innov, m, dense, x, buf):
    """Kalman update in Joseph form; False (nothing changed) if S is not positive definite.

    p (7, 7) in/out, r (m,) diagonal of R, innov (m,), x (7,) state in/out, buf work
    arrays. ``dense``: H is hm[:m] (approach 1, m = 9; gyro and gravity, m = 6); otherwise
    ``H = [I_m 0]`` (approach 2: m = 7, H = I; gyroscope alone: m = 3), and no product
    with H is formed.
    """
    s, chol, y, gain, a, zmat = buf
    n = p.shape[0]
    if dense:
        for i in range(n):  # zmat[:, :m] = P Hᵀ, a[:m] = H P
            for j in range(m):
                acc = 0.0
                for k in range(n):
                    acc += p[i, k] * hm[j, k]
                zmat[i, j] = acc
                a[j, i] = acc
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for k in range(n):
                    acc += hm[i, k] * zmat[k, j]
                s[i, j] = acc
    else:
        for i in range(m):
            for j in range(n):
                a[i, j] = p[i, j]
            for j in range(m):
                s[i, j] = p[i, j]
    for i in range(m):
        s[i, i] += r[i]
    if not cholesky(s, m, chol):
        return False
    add_kalman_gain(chol, m, a, innov, x, y, gain)
    for i in range(n):  # A = I - K H
        for j in range(n):
            acc = 1.0 if i == j else 0.0
            if dense:
                for k in range(m):
                    acc -= gain[i, k] * hm[k, j]
            elif j < m:
                acc -= gain[i, j]
            a[i, j] = acc
    _joseph(p, a, gain, r, m, zmat)
    return True


@njit(cache=True)
def _predict_covariance(p, f, qn, fp):
    """P ← F P Fᵀ + Q in place, using F's structure (F_ωω diagonal, F_ωq = 0); fp buffer."""
    n = p.shape[0]
    for i in range(n):
        for j in range(n):
            if i < 3:
                fp[i, j] = f[i, i] * p[i, j]
            else:
                acc = 0.0
                for k in range(n):
                    acc += f[i, k] * p[k, j]
                fp[i, j] = acc
    for i in range(n):
        for j in range(i, n):
            if j < 3:
                acc = fp[i, j] * f[j, j]
            else:
                acc = 0.0
                for k in range(n):
                    acc += fp[i, k] * f[j, k]
            p[i, j] = acc + qn[i, j]
            p[j, i] = p[i, j]


@njit(cache=True)
def marins_ekf(
    approach, quat_state, rate_state, cov_state, dip_state, gyr, acc, mag, dt, up, north,
    dip_rad, tau_s, rate_var, gyr_var, quat_var, acc_var, mag_var, gravity2, mag_weight,
    gn_tolerance, gn_max_iterations, quat_out, rate_out, cov_diag_out, iterations_out, flags,
):  # fmt: skip
    """Run the EKF (``approach`` 1 or 2) for S sensors over N samples, state in place.

    quat_state (S, 4), rate_state (S, 3) rad/s, cov_state (S, 7, 7) (order ω, q),
    dip_state (S,) rad (NaN: measure from the first valid sample when dip_rad is NaN).
    gyr (S, N, 3) rad/s, acc (S, N, 3) m/s², mag (S, N, 3) any unit; dt (N,) s (0: output
    the state as it is). up, north (3,) unit earth vectors. tau_s (3,) s; rate_var (3,)
    driving-noise density², (rad/s)²/Hz; gyr_var (3,) (rad/s)²/Hz, quat_var 1/Hz,
    acc_var (m/s²)²/Hz, mag_var 1/Hz: measurement-noise densities² (a sample's variance
    is density²/dt; the accelerometer's is divided by g² for the unit vector, the
    magnetometer's is relative to the field norm already). Outputs: quat_out (S, N, 4)
    unit, rate_out (S, N, 3), cov_diag_out (S, N, 7), iterations_out (S, N) Gauss-Newton
    updates, flags (S, N) int8 (ZERO_MAG: updated from gyro and accelerometer; ZERO_ACC,
    PARALLEL, SOLVER_FAILED: from the gyro alone; NOT_PD: not updated).
    """
    n_sensors, n = acc.shape[0], acc.shape[1]
    x = np.empty(7)
    xn = np.empty(7)
    f = np.empty((7, 7))
    fp = np.empty((7, 7))
    qn = np.empty((7, 7))
    g = np.empty((4, 3))
    d = np.empty((4, 3))
    q_prior = np.empty(4)
    r = np.empty(9)
    innov = np.empty(9)
    hm = np.zeros((9, 7))
    buf = (np.empty((9, 9)), np.zeros((9, 9)), np.empty((9, 7)), np.empty((7, 9)),
           np.empty((9, 7)), np.empty((7, 9)))
    for k in range(3):
        hm[k, k] = 1.0
    ux, uy, uz = up[0], up[1], up[2]
    for s in range(n_sensors):
        hx, hy, hz, _, _ = reference_field(acc[s], mag[s], dip_rad, dip_state[s:s + 1],
                                           ux, uy, uz, north[0], north[1], north[2])
        for k in range(3):
            x[k] = rate_state[s, k]
        for k in range(4):
            x[3 + k] = quat_state[s, k]
        p = cov_state[s]
        for i in range(n):
            h = dt[i]
            flag = OK
            iterations = 0
            if h > 0.0:
                # -- prediction: x⁺ = f(x), P = F P Fᵀ + Q ------------------------------
                transition(x, h, tau_s, xn, f, g, d)
                process_noise(g, h, tau_s, rate_var, qn)
                _predict_covariance(p, f, qn, fp)
                for k in range(7):
                    x[k] = xn[k]
                # -- measurement ---------------------------------------------------------
                for k in range(3):
                    rate = min(max(gyr[s, i, k], -MAX_RATE_RAD_S), MAX_RATE_RAD_S)
                    innov[k] = rate - x[k]
                    r[k] = gyr_var[k] / h
                    q_prior[k] = x[3 + k]
                q_prior[3] = x[6]
                m = 3
                res = unit_pair(acc[s, i, 0], acc[s, i, 1], acc[s, i, 2],
                                mag[s, i, 0], mag[s, i, 1], mag[s, i, 2])
                flag = res[0]
                if flag == ZERO_MAG:  # gravity direction alone (module docstring)
                    na = math.sqrt(acc[s, i, 0] ** 2 + acc[s, i, 1] ** 2 + acc[s, i, 2] ** 2)
                    za = vector_measurement(x[3], x[4], x[5], x[6], ux, uy, uz, hm[3:6, 3:])
                    var = 16.0 * quat_var / h if approach == 2 else acc_var / h / gravity2
                    for k in range(3):
                        innov[3 + k] = acc[s, i, k] / na - za[k]
                        r[3 + k] = var
                    m = 6
                elif flag == OK:
                    ax, ay, az, mx, my, mz = res[1], res[2], res[3], res[4], res[5], res[6]
                    if approach == 2:
                        nq = math.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2 + x[6] ** 2)
                        ok, gw, gx, gy, gz, iterations, _ = gauss_newton_solve(
                            ax, ay, az, mx, my, mz, ux, uy, uz, hx, hy, hz, x[3] / nq,
                            x[4] / nq, x[5] / nq, x[6] / nq, mag_weight, gn_tolerance,
                            gn_max_iterations,
                        )
                        if ok:
                            if gw * x[3] + gx * x[4] + gy * x[5] + gz * x[6] < 0.0:
                                gw, gx, gy, gz = -gw, -gx, -gy, -gz  # sign nearest q⁻
                            innov[3], innov[4] = gw - x[3], gx - x[4]
                            innov[5], innov[6] = gy - x[5], gz - x[6]
                            for k in range(3, 7):
                                r[k] = quat_var / h
                            m = 7
                        else:
                            flag = SOLVER_FAILED
                    else:
                        za = vector_measurement(x[3], x[4], x[5], x[6], ux, uy, uz, hm[3:6, 3:])
                        zm = vector_measurement(x[3], x[4], x[5], x[6], hx, hy, hz, hm[6:, 3:])
                        meas = (ax, ay, az, mx, my, mz)
                        for k in range(3):
                            innov[3 + k] = meas[k] - za[k]
                            innov[6 + k] = meas[3 + k] - zm[k]
                            r[3 + k] = acc_var / h / gravity2
                            r[6 + k] = mag_var / h
                        m = 9
                if not _update(p, hm, r, innov, m, m == 6 or m == 9, x, buf):
                    flag = NOT_PD
                nq = math.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2 + x[6] ** 2)
                if not (nq > 0.0 and nq < math.inf):  # undo: keep the predicted attitude
                    flag = NOT_PD
                    for k in range(4):
                        x[3 + k] = q_prior[k]
                    nq = math.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2 + x[6] ** 2)
                for k in range(3, 7):  # normalise after the update (001 Fig. 3)
                    x[k] /= nq
            nq = math.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2 + x[6] ** 2)
            for k in range(4):
                quat_out[s, i, k] = x[3 + k] / nq
            for k in range(3):
                rate_out[s, i, k] = x[k]
            for k in range(7):
                cov_diag_out[s, i, k] = p[k, k]
            iterations_out[s, i] = iterations
            flags[s, i] = flag
        for k in range(3):
            rate_state[s, k] = x[k]
        for k in range(4):
            quat_state[s, k] = x[3 + k]
