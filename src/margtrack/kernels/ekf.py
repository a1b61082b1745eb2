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

On ``kernels/contract.py``: :func:`_start`, :func:`_step`, :func:`_hold` over one sensor's
row and the four entry points ``run``, ``update``, ``update_one``, ``start``. Row layout
after the contract's slots (offsets ``E_*``):

- ``E_X`` (7) the state ``[ω, q]`` (q body to earth in the output frame, any non-zero
  norm in a state set by hand); ``E_P`` (49) its covariance, row-major;
- ``E_DIP`` the dip measured at the sensor's first valid sample, rad (NaN: not yet, or
  given); ``E_FIELD`` (3) the unit field reference from it;
- ``E_NULL`` (``rest_null.N_REST_NULL``) the gyro null from the still start;
- ``E_DT``, ``E_GEN``, ``E_K`` (15): the interval-dependent constants (per axis ``a``,
  ``c``, Var Δω, Cov(Δφ, Δω), Var Δφ) of the interval ``E_DT`` and the coefficient
  generation ``E_GEN`` they were computed for: recomputed only when either changes.

The buffers of one prediction and update (``W_*``, ``N_WORK``) are allocated per step, not
kept in the row. A restart keeps ``E_DIP``, ``E_FIELD`` and ``E_NULL`` (what is known of
the sensor) and starts the state and the covariance afresh. Extra outputs per sample
(``x_out``, offsets ``X_*``): the rate state (3), the covariance diagonal (7), the
Gauss-Newton iterations, the ``degenerate`` code and the gyro null (3). Coefficients:
``C_*``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from margtrack.kernels import contract, rest_null
from margtrack.kernels._quat import mul
from margtrack.kernels.davenport import field_from_dip, measured_dip
from margtrack.kernels.gauss_newton import gauss_newton_solve
from margtrack.kernels.screen import ACC_IGNORED, MAG_IGNORED
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
    "process_noise",
    "run",
    "start",
    "transition",
    "update",
    "update_one",
    "vector_measurement",
]

# The numerics work on flat buffers: the sensor's row ``st`` (state and covariance) and
# the step's work buffer ``b``, with the offsets of their vectors and row-major matrices: a
# (7, 7) matrix at ``p`` has entry (i, j) at ``b[p + 7 i + j]``. Two-dimensional views of
# a row would cost a reshape each, per sample, several times the arithmetic they save; the
# helpers are inlined so the offsets are constants (about 30 % faster than calls). Strides:
# 7 for P, F, Q, F P, H (9 x 7), Y (9 x 7) and A (9 x 7); 9 for S, its Cholesky factor,
# the gain K (7 x 9) and Z (7 x 9); 3 for G and ∂E/∂θ (4 x 3).


@njit(cache=True, inline="always")
def _exp_jacobian(tx, ty, tz, b, d):
    """:func:`exp_jacobian` into ``b[d:]`` (4 x 3, stride 3)."""
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
        b[d + j] = -0.5 * s * t[j]
        for i in range(3):
            b[d + 3 * (1 + i) + j] = ds * t[i] * t[j] + (s if i == j else 0.0)
    return math.cos(0.5 * alpha), s * tx, s * ty, s * tz


@njit(cache=True)
def exp_jacobian(tx, ty, tz, out):
    """``E = exp(θ/2)`` for a rotation vector θ (rad), and ``∂E/∂θ`` (4, 3) into ``out``.

    ``E = [cos(α/2), s θ]`` with ``α = |θ|``, ``s = sin(α/2)/α``; ``∂E_w/∂θ = -½ s θᵀ`` and
    ``∂(s θ)/∂θ = s I + (s'/α) θ θᵀ`` (series below α = 0.01). Returns E's 4 components.
    """
    buf = np.empty(12)
    e = _exp_jacobian(tx, ty, tz, buf, 0)
    for r in range(4):
        for c in range(3):
            out[r, c] = buf[3 * r + c]
    return e


@njit(cache=True, inline="always")
def _transition(st, x, b, xn, f, g, d, a0, a1, a2, c0, c1, c2):
    """:func:`transition` on buffers: x (7) in ``st``; xn (7), f (7 x 7), g, d (4 x 3) in
    ``b``; given the interval's constants per axis, ``a = exp(-h/τ)`` and ``c = τ (1 - a)``
    (the integral of the decaying rate)."""
    w, qx, qy, qz = st[x + 3], st[x + 4], st[x + 5], st[x + 6]
    n2 = w * w + qx * qx + qy * qy + qz * qz
    nq = math.sqrt(n2)
    for k in range(49):
        b[f + k] = 0.0
    b[xn], b[xn + 1], b[xn + 2] = a0 * st[x], a1 * st[x + 1], a2 * st[x + 2]  # eqs. 9-11
    b[f], b[f + 8], b[f + 16] = a0, a1, a2
    t0, t1, t2 = c0 * st[x] / nq, c1 * st[x + 1] / nq, c2 * st[x + 2] / nq  # θ = c ω / |q|
    e0, e1, e2, e3 = _exp_jacobian(t0, t1, t2, b, d)
    pw, px, py, pz = mul(w, qx, qy, qz, e0, e1, e2, e3)  # eqs. 12-15, exact flow
    b[xn + 3], b[xn + 4], b[xn + 5], b[xn + 6] = pw, px, py, pz
    lq = ((w, -qx, -qy, -qz), (qx, w, -qz, qy), (qy, qz, w, -qx), (qz, -qy, qx, w))
    coef = (c0, c1, c2)
    for r in range(4):  # G = L(q) ∂E/∂θ / |q|;  F_qω = G diag(c)
        for c in range(3):
            gv = (lq[r][0] * b[d + c] + lq[r][1] * b[d + 3 + c] + lq[r][2] * b[d + 6 + c]
                  + lq[r][3] * b[d + 9 + c]) / nq
            b[g + 3 * r + c] = gv
            b[f + 7 * (3 + r) + c] = gv * coef[c]
    # F_qq = R(E) - (q⁺ ⊗ (0, θ/2)) qᵀ / |q|²  (the |q| in θ = c ω / |q|)
    re = ((e0, -e1, -e2, -e3), (e1, e0, e3, -e2), (e2, -e3, e0, e1), (e3, e2, -e1, e0))
    u = mul(pw, px, py, pz, 0.0, 0.5 * t0, 0.5 * t1, 0.5 * t2)
    q = (w, qx, qy, qz)
    for r in range(4):
        for c in range(4):
            b[f + 7 * (3 + r) + 3 + c] = re[r][c] - u[r] * q[c] / n2


@njit(cache=True)
def transition(x, h, tau_s, x_next, f, g, d):
    """One step of the discretised process model and its Jacobian (module docstring).

    x (7,) ``[ω (rad/s), q]`` (any non-zero ``|q|``); h > 0 interval, s; tau_s (3,) time
    constants, s. Fills x_next (7,), f = ∂x_next/∂x (7, 7) and g = ∂q⁺/∂φ (4, 3), the
    quaternion's response to a change of the integrated rate φ (rad), for the noise;
    d (4, 3) receives ∂E/∂θ.
    """
    b = np.zeros(7 + 7 + 49 + 12 + 12)
    b[:7] = x
    a = [math.exp(-h / tau_s[k]) for k in range(3)]
    c = [-tau_s[k] * math.expm1(-h / tau_s[k]) for k in range(3)]
    _transition(b, 0, b, 7, 14, 63, 75, a[0], a[1], a[2], c[0], c[1], c[2])
    x_next[:] = b[7:14]
    for r in range(7):
        for k in range(7):
            f[r, k] = b[14 + 7 * r + k]
    for r in range(4):
        for k in range(3):
            g[r, k] = b[63 + 3 * r + k]
            d[r, k] = b[75 + 3 * r + k]


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


@njit(cache=True, inline="always")
def _process_noise(b, g, q, vw0, vw1, vw2, cpw0, cpw1, cpw2, vp0, vp1, vp2):
    """:func:`process_noise` on the buffer (g 4 x 3, q 7 x 7 offsets), given the interval's
    :func:`axis_noise` per axis (Var Δω, Cov(Δφ, Δω), Var Δφ)."""
    for k in range(49):
        b[q + k] = 0.0
    cov_pw = (cpw0, cpw1, cpw2)
    var_p = (vp0, vp1, vp2)
    b[q], b[q + 8], b[q + 16] = vw0, vw1, vw2
    for k in range(3):
        for r in range(4):
            b[q + 7 * (3 + r) + k] = b[g + 3 * r + k] * cov_pw[k]
            b[q + 7 * k + 3 + r] = b[q + 7 * (3 + r) + k]
    for r in range(4):
        for c in range(4):
            b[q + 7 * (3 + r) + 3 + c] = (
                b[g + 3 * r] * var_p[0] * b[g + 3 * c]
                + b[g + 3 * r + 1] * var_p[1] * b[g + 3 * c + 1]
                + b[g + 3 * r + 2] * var_p[2] * b[g + 3 * c + 2]
            )


@njit(cache=True)
def process_noise(g, h, tau_s, rate_var, out):
    """Process noise covariance (7, 7) over one interval (module docstring), into ``out``.

    g (4, 3) from :func:`transition`; h s; tau_s (3,) s; rate_var (3,) ``σ²`` of the
    driving noise, (rad/s)²/Hz. Exact for the rate and its integral; ``Δq = G Δφ``.
    """
    v0 = axis_noise(h, tau_s[0], rate_var[0])
    v1 = axis_noise(h, tau_s[1], rate_var[1])
    v2 = axis_noise(h, tau_s[2], rate_var[2])
    b = np.empty(12 + 49)
    for r in range(4):
        for k in range(3):
            b[3 * r + k] = g[r, k]
    _process_noise(b, 0, 12, v0[0], v1[0], v2[0], v0[1], v1[1], v2[1], v0[2], v1[2], v2[2])
    for r in range(7):
        for k in range(7):
            out[r, k] = b[12 + 7 * r + k]


@njit(cache=True, inline="always")
def _vector_measurement(w, x, y, z, vx, vy, vz, b, jac, stride):
    """:func:`vector_measurement` with the Jacobian into ``b[jac:]`` (3 x 4, ``stride``)."""
    n2 = w * w + x * x + y * y + z * z
    p0, p1, p2, p3 = mul(w, -x, -y, -z, 0.0, vx, vy, vz)
    _, gx, gy, gz = mul(p0, p1, p2, p3, w, x, y, z)
    zx, zy, zz = gx / n2, gy / n2, gz / n2
    cols = ((p1, p2, p3), (p0, p3, -p2), (-p3, p0, p1), (p2, -p1, p0))  # vec(p ⊗ e_k)
    q = (w, x, y, z)
    zv = (zx, zy, zz)
    for k in range(4):
        for i in range(3):
            b[jac + stride * i + k] = 2.0 * (cols[k][i] - zv[i] * q[k]) / n2
    return zx, zy, zz


@njit(cache=True)
def vector_measurement(w, x, y, z, vx, vy, vz, jac):
    """Body-frame reading ``R(q)ᵀ v / |q|²`` of a unit earth vector v, and its Jacobian.

    (001 eq. 19, derived sign.) Returns the 3 components; fills jac (3, 4) = ∂/∂q. With
    ``p = q* ⊗ v`` the unnormalised reading is ``vec(p ⊗ q)`` and its derivative along
    ``e_k`` is ``2 vec(p ⊗ e_k)``; dividing by ``|q|²`` subtracts ``2 z q_k / |q|²``.
    """
    b = np.empty(12)
    z3 = _vector_measurement(w, x, y, z, vx, vy, vz, b, 0, 4)
    for i in range(3):
        for k in range(4):
            jac[i, k] = b[4 * i + k]
    return z3


@njit(cache=True, inline="always")
def _cholesky(b, s, m, chol):
    """Lower Cholesky factor of S[:m, :m] (stride 9) into chol (stride 9); False if S is not
    positive definite (as ``_linalg.cholesky``)."""
    for r in range(m):
        for c in range(r + 1):
            acc = b[s + 9 * r + c]
            for k in range(c):
                acc -= b[chol + 9 * r + k] * b[chol + 9 * c + k]
            if r == c:
                if not acc > 0.0:
                    return False
                b[chol + 10 * r] = math.sqrt(acc)
            else:
                b[chol + 9 * r + c] = acc / b[chol + 10 * c]
    return True


@njit(cache=True, inline="always")
def _add_kalman_gain(b, chol, m, rhs, innov, st, x, y, gain):
    """K = rhsᵀ S⁻¹ (S = chol cholᵀ, rhs = H P (m x 7, stride 7)) into gain (7 x m, stride
    9); x (in ``st``) += K ν (as ``_linalg.add_kalman_gain``; y (stride 7) a buffer)."""
    for c in range(7):  # Y = S⁻¹ rhs
        for r in range(m):
            acc = b[rhs + 7 * r + c]
            for k in range(r):
                acc -= b[chol + 9 * r + k] * b[y + 7 * k + c]
            b[y + 7 * r + c] = acc / b[chol + 10 * r]
        for r in range(m - 1, -1, -1):
            acc = b[y + 7 * r + c]
            for k in range(r + 1, m):
                acc -= b[chol + 9 * k + r] * b[y + 7 * k + c]
            b[y + 7 * r + c] = acc / b[chol + 10 * r]
    for i in range(7):
        acc = 0.0
        for k in range(m):
            b[gain + 9 * i + k] = b[y + 7 * k + i]
            acc += b[y + 7 * k + i] * b[innov + k]
        st[x + i] += acc


@njit(cache=True, inline="always")
def _joseph(st, p, b, a, gain, r, m, zmat):
    """P (in ``st``) ← A P Aᵀ + K diag(r) Kᵀ (A = I - KH given, stride 7; the rest in
    ``b``), upper triangle mirrored."""
    for i in range(7):
        for j in range(7):
            acc = 0.0
            for k in range(7):
                acc += b[a + 7 * i + k] * st[p + 7 * k + j]
            b[zmat + 9 * i + j] = acc
    for i in range(7):
        for j in range(i, 7):
            acc = 0.0
            for k in range(7):
                acc += b[zmat + 9 * i + k] * b[a + 7 * j + k]
            for k in range(m):
                acc += b[gain + 9 * i + k] * b[r + k] * b[gain + 9 * j + k]
            st[p + 7 * i + j] = acc
    for i in range(7):
        for j in range(i):
            st[p + 7 * i + j] = st[p + 7 * j + i]


@njit(cache=True, inline="always")
def _update(st, b, m, dense):
    """Kalman update in Joseph form; False (nothing changed) if S is not positive definite.

    The state at E_X and P at E_P of ``st``, in/out; the work buffers in ``b`` at W_*:
    R's diagonal at W_R, the innovation at W_INNOV (m). ``dense``: H is the first m
    rows at W_HM (approach 1, m = 9; gyro and gravity, m = 6); otherwise ``H = [I_m 0]``
    (approach 2: m = 7, H = I; gyroscope alone: m = 3), and no product with H is formed.
    """
    p, hm, a, s, zmat = E_P, W_HM, W_A, W_S, W_Z
    if dense:
        for i in range(7):  # Z[:, :m] = P Hᵀ, A[:m] = H P
            for j in range(m):
                acc = 0.0
                for k in range(7):
                    acc += st[p + 7 * i + k] * b[hm + 7 * j + k]
                b[zmat + 9 * i + j] = acc
                b[a + 7 * j + i] = acc
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for k in range(7):
                    acc += b[hm + 7 * i + k] * b[zmat + 9 * k + j]
                b[s + 9 * i + j] = acc
    else:
        for i in range(m):
            for j in range(7):
                b[a + 7 * i + j] = st[p + 7 * i + j]
            for j in range(m):
                b[s + 9 * i + j] = st[p + 7 * i + j]
    for i in range(m):
        b[s + 10 * i] += b[W_R + i]
    chol, gain = W_CHOL, W_GAIN
    if not _cholesky(b, s, m, chol):
        return False
    _add_kalman_gain(b, chol, m, a, W_INNOV, st, E_X, W_Y, gain)
    for i in range(7):  # A = I - K H
        for j in range(7):
            acc = 1.0 if i == j else 0.0
            if dense:
                for k in range(m):
                    acc -= b[gain + 9 * i + k] * b[hm + 7 * k + j]
            elif j < m:
                acc -= b[gain + 9 * i + j]
            b[a + 7 * i + j] = acc
    _joseph(st, p, b, a, gain, W_R, m, zmat)
    return True


@njit(cache=True, inline="always")
def _predict_covariance(st, p, b, f, qn, fp):
    """P (in ``st``) ← F P Fᵀ + Q in place, using F's structure (F_ωω diagonal, F_ωq = 0);
    F, Q and the buffer fp in ``b``."""
    for i in range(7):
        for j in range(7):
            if i < 3:
                b[fp + 7 * i + j] = b[f + 8 * i] * st[p + 7 * i + j]
            else:
                acc = 0.0
                for k in range(7):
                    acc += b[f + 7 * i + k] * st[p + 7 * k + j]
                b[fp + 7 * i + j] = acc
    for i in range(7):
        for j in range(i, 7):
            if j < 3:
                acc = b[fp + 7 * i + j] * b[f + 8 * j]
            else:
                acc = 0.0
                for k in range(7):
                    acc += b[fp + 7 * i + k] * b[f + 7 * j + k]
            st[p + 7 * i + j] = acc + b[qn + 7 * i + j]
            st[p + 7 * j + i] = st[p + 7 * i + j]


# -- coefficients (after the contract's screening coefficients) ---------------------------
C_APPROACH = 0  # 1 or 2
C_TAU = 1  # 3: τ per axis, s
C_RATE_VAR = 4  # 3: driving-noise density², (rad/s)²/Hz
C_GYR_VAR = 7  # 3: gyroscope noise density², (rad/s)²/Hz
C_QUAT_VAR = 10  # 1/Hz
C_ACC_VAR = 11  # (m/s²)²/Hz
C_MAG_VAR = 12  # 1/Hz (relative to the field norm)
C_GRAVITY2 = 13  # g², (m/s²)²
C_MAG_WEIGHT = 14  # ρ
C_GN_TOL = 15
C_GN_MAX_IT = 16
C_UP = 17  # 3: unit earth up
C_NORTH = 20  # 3: unit earth north (horizontal)
C_DIP = 23  # the given dip, rad (NaN: measure each sensor's)
C_FIELD = 24  # 3: the unit field reference of the given dip
C_INIT_RATE_VAR = 27  # (rad/s)²
C_INIT_QUAT_VAR = 28
C_GEN = 29  # generation of these coefficients (keys the row's interval constants)
C_NULL = 30  # rest_null.N_RC: the gyro null's coefficients
N_COEF = C_NULL + rest_null.N_RC

# -- one sensor's row (after the contract's slots; see the module docstring) -------------
E_X = contract.N_CONTRACT  # 7: [ω (rad/s), q]
E_P = E_X + 7  # 49: covariance, row-major
E_DIP = E_P + 49  # measured dip, rad (NaN: not yet)
E_FIELD = E_DIP + 1  # 3: unit field reference from it (NaN: not known)
E_NULL = E_FIELD + 3  # rest_null.N_REST_NULL: the gyro null from the still start
E_DT = E_NULL + rest_null.N_REST_NULL  # interval of the constants below, s (NaN: none)
E_GEN = E_DT + 1  # coefficient generation they were computed with
E_K = E_GEN + 1  # 15: a (3), c (3), Var Δω (3), Cov(Δφ, Δω) (3), Var Δφ (3)
N_ROW = E_K + 15
# the work buffers of one step (allocated per step: kept in every sensor's row they would
# multiply the memory a many-sensor run streams through per sample)
W_XN = 0  # 7
W_F = W_XN + 7  # 7 x 7
W_G = W_F + 49  # 4 x 3
W_D = W_G + 12  # 4 x 3
W_QN = W_D + 12  # 7 x 7
W_FP = W_QN + 49  # 7 x 7
W_R = W_FP + 49  # 9
W_INNOV = W_R + 9  # 9
W_HM = W_INNOV + 9  # 9 x 7
W_S = W_HM + 63  # 9 x 9
W_CHOL = W_S + 81  # 9 x 9
W_Y = W_CHOL + 81  # 9 x 7
W_GAIN = W_Y + 63  # 7 x 9
W_A = W_GAIN + 63  # 9 x 7
W_Z = W_A + 63  # 7 x 9
N_WORK = W_Z + 63

# -- extra outputs per sample ---------------------------------------------------------
X_RATE = 0  # 3
X_COV = 3  # 7: the covariance diagonal
X_ITER = 10
X_CODE = 11
X_NULL = 12  # 3

#: flag bits of each degenerate code (margtrack.estimator.flags): OK 0, ZERO_ACC, ZERO_MAG
#: (the screening's flag stands; the accelerometer was used), PARALLEL, SOLVER_FAILED, NOT_PD
_BOTH = ACC_IGNORED | MAG_IGNORED


@njit(cache=True, inline="always")
def _code_flags(code):
    if code == ZERO_ACC:
        return ACC_IGNORED
    if code == OK or code == ZERO_MAG:
        return 0
    return _BOTH


@njit(cache=True, inline="always")
def _start(row, coef, first, qw, qx, qy, qz):
    """(Re)start at q with zero rate and the initial covariance; the first start also
    forgets the dip and the gyro null (a restart keeps them)."""
    for k in range(3):
        row[E_X + k] = 0.0
    row[E_X + 3], row[E_X + 4], row[E_X + 5], row[E_X + 6] = qw, qx, qy, qz
    for k in range(49):
        row[E_P + k] = 0.0
    for k in range(3):
        row[E_P + 8 * k] = coef[C_INIT_RATE_VAR]
    for k in range(3, 7):
        row[E_P + 8 * k] = coef[C_INIT_QUAT_VAR]
    row[E_DT] = math.nan
    if first:
        row[E_DIP] = math.nan
        row[E_FIELD] = row[E_FIELD + 1] = row[E_FIELD + 2] = math.nan
        rest_null.fresh_one(row, E_NULL)


@njit(cache=True, inline="always")
def _outputs(row, x_out, iterations, code, nx, ny, nz):
    for k in range(3):
        x_out[X_RATE + k] = row[E_X + k]
    for k in range(7):
        x_out[X_COV + k] = row[E_P + 8 * k]
    x_out[X_ITER] = iterations
    x_out[X_CODE] = code
    x_out[X_NULL], x_out[X_NULL + 1], x_out[X_NULL + 2] = nx, ny, nz


@njit(cache=True, inline="always")
def _work():
    """The work buffers of one step (``W_*``), H's constant part set: its rows 0-2 are
    ``[I₃ 0]``, its rate columns of rows 3-8 zero (the rest is filled per update)."""
    b = np.empty(N_WORK)
    for k in range(63):
        b[W_HM + k] = 0.0
    for k in range(3):
        b[W_HM + 8 * k] = 1.0
    return b


@njit(cache=True)
def _step(row, coef, h, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """One screened sample: predict over h (0: output the state as it is), update from the
    gyroscope and the accelerometer/magnetometer pair (module docstring); the flag bits.

    Not inlined into the entry points (unlike ``_start`` and ``_hold``): compiled once and
    called, which takes the kernels' compilation from about 70 s to 14 s at no measurable
    cost per sample (the step itself is about 1.5 µs).
    """
    nx, ny, nz = rest_null.step_one(
        row, E_NULL, coef, C_NULL, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, h
    )
    gyr = (g0 - nx, g1 - ny, g2 - nz)
    ux, uy, uz = coef[C_UP], coef[C_UP + 1], coef[C_UP + 2]
    # the field reference: the given dip's, or from the sensor's first valid sample
    if math.isnan(coef[C_DIP]):
        if math.isnan(row[E_DIP]):
            res = unit_pair(a0, a1, a2, m0, m1, m2)
            if res[0] == OK:
                dip = measured_dip(res[1], res[2], res[3], res[4], res[5], res[6])
                row[E_DIP] = dip
                row[E_FIELD], row[E_FIELD + 1], row[E_FIELD + 2] = field_from_dip(
                    math.sin(dip), math.cos(dip), ux, uy, uz,
                    coef[C_NORTH], coef[C_NORTH + 1], coef[C_NORTH + 2],
                )
        hx, hy, hz = row[E_FIELD], row[E_FIELD + 1], row[E_FIELD + 2]
    else:
        hx, hy, hz = coef[C_FIELD], coef[C_FIELD + 1], coef[C_FIELD + 2]
    x = row[E_X : E_X + 7]  # (one-dimensional views of the row cost nothing)
    flag = OK
    iterations = 0
    if h > 0.0:
        # -- prediction: x⁺ = f(x), P = F P Fᵀ + Q ----------------------------------------
        if row[E_DT] != h or row[E_GEN] != coef[C_GEN]:  # the interval's constants
            for k in range(3):
                tau = coef[C_TAU + k]
                row[E_K + k] = math.exp(-h / tau)
                row[E_K + 3 + k] = -tau * math.expm1(-h / tau)
                vw, cpw, vp = axis_noise(h, tau, coef[C_RATE_VAR + k])
                row[E_K + 6 + k], row[E_K + 9 + k], row[E_K + 12 + k] = vw, cpw, vp
            row[E_DT] = h
            row[E_GEN] = coef[C_GEN]
        k0 = E_K
        b = _work()
        _transition(row, E_X, b, W_XN, W_F, W_G, W_D, row[k0], row[k0 + 1],
                    row[k0 + 2], row[k0 + 3], row[k0 + 4], row[k0 + 5])
        _process_noise(b, W_G, W_QN, row[k0 + 6], row[k0 + 7], row[k0 + 8],
                       row[k0 + 9], row[k0 + 10], row[k0 + 11], row[k0 + 12], row[k0 + 13],
                       row[k0 + 14])
        _predict_covariance(row, E_P, b, W_F, W_QN, W_FP)
        for k in range(7):
            x[k] = b[W_XN + k]
        # -- measurement -----------------------------------------------------------------
        r = b[W_R : W_R + 9]
        innov = b[W_INNOV : W_INNOV + 9]
        hm = W_HM
        for k in range(3):
            rate = min(max(gyr[k], -MAX_RATE_RAD_S), MAX_RATE_RAD_S)
            innov[k] = rate - x[k]
            r[k] = coef[C_GYR_VAR + k] / h
        pw, px, py, pz = x[3], x[4], x[5], x[6]
        m = 3
        approach = coef[C_APPROACH]
        res = unit_pair(a0, a1, a2, m0, m1, m2)
        flag = res[0]
        if flag == ZERO_MAG:  # gravity direction alone (module docstring)
            na = math.sqrt(a0 ** 2 + a1 ** 2 + a2 ** 2)
            za = _vector_measurement(x[3], x[4], x[5], x[6], ux, uy, uz, b, hm + 24, 7)
            if approach == 2.0:
                var = 16.0 * coef[C_QUAT_VAR] / h
            else:
                var = coef[C_ACC_VAR] / h / coef[C_GRAVITY2]
            acc = (a0, a1, a2)
            for k in range(3):
                innov[3 + k] = acc[k] / na - za[k]
                r[3 + k] = var
            m = 6
        elif flag == OK:
            ax, ay, az, mx, my, mz = res[1], res[2], res[3], res[4], res[5], res[6]
            if approach == 2.0:
                nq = math.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2 + x[6] ** 2)
                ok, gw, gx, gy, gz, iterations, _ = gauss_newton_solve(
                    ax, ay, az, mx, my, mz, ux, uy, uz, hx, hy, hz, x[3] / nq,
                    x[4] / nq, x[5] / nq, x[6] / nq, coef[C_MAG_WEIGHT], coef[C_GN_TOL],
                    int(coef[C_GN_MAX_IT]),
                )
                if ok:
                    if gw * x[3] + gx * x[4] + gy * x[5] + gz * x[6] < 0.0:
                        gw, gx, gy, gz = -gw, -gx, -gy, -gz  # sign nearest q⁻
                    innov[3], innov[4] = gw - x[3], gx - x[4]
                    innov[5], innov[6] = gy - x[5], gz - x[6]
                    for k in range(3, 7):
                        r[k] = coef[C_QUAT_VAR] / h
                    m = 7
                else:
                    flag = SOLVER_FAILED
            else:  # H's rows 3-5 and 6-8, columns 3-6 (offsets 7·3 + 3 and 7·6 + 3)
                za = _vector_measurement(x[3], x[4], x[5], x[6], ux, uy, uz, b, hm + 24, 7)
                zm = _vector_measurement(x[3], x[4], x[5], x[6], hx, hy, hz, b, hm + 45, 7)
                meas = (ax, ay, az, mx, my, mz)
                for k in range(3):
                    innov[3 + k] = meas[k] - za[k]
                    innov[6 + k] = meas[3 + k] - zm[k]
                    r[3 + k] = coef[C_ACC_VAR] / h / coef[C_GRAVITY2]
                    r[6 + k] = coef[C_MAG_VAR] / h
                m = 9
        if not _update(row, b, m, m == 6 or m == 9):
            flag = NOT_PD
        nq = math.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2 + x[6] ** 2)
        if not (nq > 0.0 and nq < math.inf):  # undo: keep the predicted attitude
            flag = NOT_PD
            x[3], x[4], x[5], x[6] = pw, px, py, pz
            nq = math.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2 + x[6] ** 2)
        for k in range(3, 7):  # normalise after the update (001 Fig. 3)
            x[k] /= nq
    nq = math.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2 + x[6] ** 2)
    for k in range(4):
        q_out[k] = x[3 + k] / nq
    _outputs(row, x_out, iterations, flag, nx, ny, nz)
    return _code_flags(flag)


@njit(cache=True, inline="always")
def _hold(row, coef, x_out):
    """Outputs of a held sample (a sensor waiting for a usable sample): the state's."""
    k = E_NULL + rest_null.RN_NULL
    _outputs(row, x_out, 0, OK, row[k], row[k + 1], row[k + 2])


@njit(cache=True)
def run(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples (``contract.run_series``)."""
    contract.run_series(_start, _step, _hold, rows, clock, coefs, t, gyr, acc, mag, has,
                        q_out, x_out, flags_out)


@njit(cache=True, parallel=True)
def run_many(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples, shared among threads (``contract.run_series_parallel``)."""
    contract.run_series_parallel(_start, _step, _hold, rows, clock, coefs, t, gyr, acc, mag, has,
                                 q_out, x_out, flags_out)


@njit(cache=True)
def update(rows, clock, coefs, dt, gyr, acc, mag, has, q_out, x_out, flags_out):
    """One sample of S sensors (``contract.update_samples``)."""
    contract.update_samples(_start, _step, _hold, rows, clock, coefs, dt, gyr, acc, mag, has,
                            q_out, x_out, flags_out)


@njit(cache=True)
def update_one(rows, clock, coefs, dt, g, a, m, has, out):
    """One sample of one sensor (``contract.update_one``); returns the flags."""
    return contract.update_one(_start, _step, _hold, rows, clock, coefs, dt, g, a, m, has, out)


@njit(cache=True)
def start(rows, coefs, quat0):
    """Start S sensors at quat0 (S, 4) (``contract.start_rows``)."""
    contract.start_rows(_start, rows, coefs, quat0)
