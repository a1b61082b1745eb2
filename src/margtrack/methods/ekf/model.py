"""The algebra of Marins' EKF (001 eqs. 9-19), hand-derived for its sparse structure.

State ``x = [ω (3), q (4)]`` (001), or ``[ω, q, b (3)]`` with a gyroscope bias (the
option of :mod:`margtrack.methods.ekf.bias_kernel`, in the spirit of 003): ``n`` = 7 or 10; the
covariance ``P`` is kept in full (both triangles, exactly mirrored), row-major with stride
``n``, in a sensor's row. See :mod:`margtrack.methods.ekf.kernel` for the model and its
discretisation; this module has the arithmetic.

Structure used (instead of generic n x n products):

- the transition ``F = [[diag(a), 0, 0], [G diag(c), F_qq, 0], [0, 0, I₃]]`` (the bias
  row only for n = 10): ``F P Fᵀ`` is formed in place by blocks (:func:`predict_covariance`:
  the quaternion rows of ``F P``, then the upper triangle of the result from them), ``Q``
  added on the way (its blocks ``diag(Var Δω)``, ``G diag(Cov(Δφ, Δω))``,
  ``G diag(Var Δφ) Gᵀ``, ``diag(σ_b² h)``): about 300 multiplications for n = 7 against
  the 900 of dense products;
- the measurement noise is diagonal, so the update is a sequence of scalar updates
  (:func:`scalar_update`), one per measured component, each ``s = hᵀ P h + r``,
  ``x += P h ν / s``, ``P -= (P h)(P h)ᵀ / s``: in exact arithmetic the batch update (the
  Kalman update of independent measurements may be applied one at a time); numerically
  it is the elimination step of a Cholesky factorisation of ``[[H P Hᵀ + R, H P], [P Hᵀ,
  P]]``, whose trailing block is ``P⁺``: backward stable, symmetric by construction, and
  ``P⁺`` positive definite as long as the pivots ``s`` are (each ``s >= r > 0``). Its
  rows ``h`` are sparse: a unit vector (a rate or quaternion component: 001 approach 2
  has ``H = I₇``), a rate plus a bias component (the gyroscope with the bias state), or
  four numbers on the quaternion (approach 1's vector readings). For ``h = e_k`` the row
  ``k`` of ``P⁺`` is ``P_k r / s`` (no cancellation where ``r << P_kk``).

Between the prediction and the end of the updates only P's upper triangle is kept
(:func:`mirror` completes it once). No buffers are allocated: small matrices are tuples
(registers), the rest lives in the row (a scratch slot ``ph`` of n numbers for ``P h``).
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit
from margtrack.estimator.quat_kernel import mul
from margtrack.estimator.triad_kernel import FASTMATH

__all__ = [
    "axis_noise",
    "exp_jacobian",
    "mirror",
    "predict_covariance",
    "process_noise",
    "scalar_update",
    "transition",
    "transition_terms",
    "vector_measurement",
    "vector_reading",
]


@njit(cache=True, inline="always")
def exp_half(tx, ty, tz):
    """``E = exp(θ/2)`` (4-tuple) and ``D = ∂E/∂θ`` (4 x 3 tuple) for a rotation vector θ.

    ``E = [cos(α/2), s θ]`` with ``α = |θ|``, ``s = sin(α/2)/α``; ``∂E_w/∂θ = -½ s θᵀ`` and
    ``∂(s θ)/∂θ = s I + (s'/α) θ θᵀ`` (series below α = 0.01).
    """
    a2 = tx * tx + ty * ty + tz * tz
    alpha = math.sqrt(a2)
    if alpha < 1e-2:
        s = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
        ds = -1.0 / 24.0 + a2 / 960.0 - a2 * a2 / 107520.0
    else:
        sin_h, cos_h = math.sin(0.5 * alpha), math.cos(0.5 * alpha)
        ia = 1.0 / alpha
        s = sin_h * ia
        ds = (0.5 * cos_h * alpha - sin_h) * (ia * ia * ia)
    e = (math.cos(0.5 * alpha), s * tx, s * ty, s * tz)
    d = (
        (-0.5 * s * tx, -0.5 * s * ty, -0.5 * s * tz),
        (ds * tx * tx + s, ds * tx * ty, ds * tx * tz),
        (ds * ty * tx, ds * ty * ty + s, ds * ty * tz),
        (ds * tz * tx, ds * tz * ty, ds * tz * tz + s),
    )
    return e, d


@njit(cache=True)
def exp_jacobian(tx, ty, tz, out):
    """``E = exp(θ/2)`` for a rotation vector θ (rad), and ``∂E/∂θ`` (4, 3) into ``out``.

    Returns E's 4 components (:func:`exp_half`).
    """
    e, d = exp_half(tx, ty, tz)
    for r in range(4):
        for c in range(3):
            out[r, c] = d[r][c]
    return e


@njit(cache=True, inline="always")
def _g_row(l0, l1, l2, l3, d, inq):
    """One row of ``G = L(q) ∂E/∂θ / |q|`` from a row of ``L(q)`` (inq = 1/|q|)."""
    return (
        (l0 * d[0][0] + l1 * d[1][0] + l2 * d[2][0] + l3 * d[3][0]) * inq,
        (l0 * d[0][1] + l1 * d[1][1] + l2 * d[2][1] + l3 * d[3][1]) * inq,
        (l0 * d[0][2] + l1 * d[1][2] + l2 * d[2][2] + l3 * d[3][2]) * inq,
    )


@njit(cache=True, inline="always")
def _f_row(e0, e1, e2, e3, u, q0, q1, q2, q3, in2):
    """One row of ``F_qq = R(E) - u qᵀ / |q|²`` from a row of ``R(E)`` (in2 = 1/|q|²)."""
    un = u * in2
    return (e0 - un * q0, e1 - un * q1, e2 - un * q2, e3 - un * q3)


@njit(cache=True, inline="always")
def transition_terms(w0, w1, w2, qw, qx, qy, qz, a0, a1, a2, c0, c1, c2):
    """One step of the process model (:mod:`margtrack.methods.ekf.kernel`) and its Jacobian blocks.

    Given the rate ω (rad/s), the quaternion q (any non-zero norm) and the interval's
    constants per axis ``a = exp(-h/τ)``, ``c = τ (1 - a)``: returns ``x⁺`` (7-tuple),
    ``G = ∂q⁺/∂φ`` (4 x 3; ``F_qω = G diag(c)``), ``F_qq`` (4 x 4) and ``∂E/∂θ`` (4 x 3).
    """
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    inq = 1.0 / math.sqrt(n2)  # (one division: multiplications by it below)
    in2 = inq * inq
    t0, t1, t2 = c0 * w0 * inq, c1 * w1 * inq, c2 * w2 * inq  # θ = c ω / |q|
    e, d = exp_half(t0, t1, t2)
    e0, e1, e2, e3 = e
    pw, px, py, pz = mul(qw, qx, qy, qz, e0, e1, e2, e3)  # eqs. 12-15, exact flow
    xn = (a0 * w0, a1 * w1, a2 * w2, pw, px, py, pz)  # eqs. 9-11
    g = (  # G = L(q) ∂E/∂θ / |q|
        _g_row(qw, -qx, -qy, -qz, d, inq),
        _g_row(qx, qw, -qz, qy, d, inq),
        _g_row(qy, qz, qw, -qx, d, inq),
        _g_row(qz, -qy, qx, qw, d, inq),
    )
    # F_qq = R(E) - (q⁺ ⊗ (0, θ/2)) qᵀ / |q|²  (the |q| in θ = c ω / |q|)
    u0, u1, u2, u3 = mul(pw, px, py, pz, 0.0, 0.5 * t0, 0.5 * t1, 0.5 * t2)
    f = (
        _f_row(e0, -e1, -e2, -e3, u0, qw, qx, qy, qz, in2),
        _f_row(e1, e0, e3, -e2, u1, qw, qx, qy, qz, in2),
        _f_row(e2, -e3, e0, e1, u2, qw, qx, qy, qz, in2),
        _f_row(e3, e2, -e1, e0, u3, qw, qx, qy, qz, in2),
    )
    return xn, g, f, d


@njit(cache=True)
def transition(x, h, tau_s, x_next, f, g, d):
    """One step of the discretised process model and its Jacobian (7-state, for tests).

    x (7,) ``[ω (rad/s), q]`` (any non-zero ``|q|``); h > 0 interval, s; tau_s (3,) time
    constants, s. Fills x_next (7,), f = ∂x_next/∂x (7, 7) and g = ∂q⁺/∂φ (4, 3), the
    quaternion's response to a change of the integrated rate φ (rad), for the noise;
    d (4, 3) receives ∂E/∂θ.
    """
    a = [math.exp(-h / tau_s[k]) for k in range(3)]
    c = [-tau_s[k] * math.expm1(-h / tau_s[k]) for k in range(3)]
    xn, gt, ft, dt = transition_terms(x[0], x[1], x[2], x[3], x[4], x[5], x[6],
                                      a[0], a[1], a[2], c[0], c[1], c[2])
    for k in range(7):
        x_next[k] = xn[k]
    f[:, :] = 0.0
    for k in range(3):
        f[k, k] = a[k]
    for r in range(4):
        for k in range(3):
            g[r, k] = gt[r][k]
            d[r, k] = dt[r][k]
            f[3 + r, k] = gt[r][k] * c[k]
        for k in range(4):
            f[3 + r, 3 + k] = ft[r][k]


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
    """Process noise covariance (7, 7) over one interval into ``out`` (for tests).

    g (4, 3) from :func:`transition`; h s; tau_s (3,) s; rate_var (3,) ``σ²`` of the
    driving noise, (rad/s)²/Hz. Exact for the rate and its integral; ``Δq = G Δφ``.
    """
    out[:, :] = 0.0
    for k in range(3):
        vw, cpw, vp = axis_noise(h, tau_s[k], rate_var[k])
        out[k, k] = vw
        for r in range(4):
            out[3 + r, k] = out[k, 3 + r] = g[r, k] * cpw
            for c in range(4):
                out[3 + r, 3 + c] += g[r, k] * vp * g[c, k]


@njit(cache=True, fastmath=FASTMATH, inline="always")
def predict_covariance(st, p, n, a, c, g, f, vw, cpw, vp, vb):
    """``P ← F P Fᵀ + Q`` in place (module docstring), P at ``st[p:]`` (n x n, stride n).

    Reads the full P; writes the upper triangle of the result (the lower one is left
    stale: the updates read the upper one, :func:`mirror` completes it). a, c (3-tuples)
    the interval's constants; g (4 x 3) ``G``, f (4 x 4) ``F_qq`` from
    :func:`transition_terms`; vw, cpw, vp (3-tuples) :func:`axis_noise` per axis; vb
    (3-tuple) the bias increments' variances ``σ_b² h`` (n = 10 only). With
    ``M_q = G diag(c) P_ω + F_qq P_q`` (the quaternion rows of F P, into P's own rows):
    ``P⁺_ωω = a_i a_j P_ij``, ``P⁺_ωq = (M_qω diag(a))ᵀ``, ``P⁺_qq = M_qω (G diag(c))ᵀ +
    M_qq F_qqᵀ``, ``P⁺_ωb = diag(a) P_ωb``, ``P⁺_qb = M_qb``, ``P⁺_bb = P_bb``, plus Q.
    """
    gc = (
        (g[0][0] * c[0], g[0][1] * c[1], g[0][2] * c[2]),
        (g[1][0] * c[0], g[1][1] * c[1], g[1][2] * c[2]),
        (g[2][0] * c[0], g[2][1] * c[1], g[2][2] * c[2]),
        (g[3][0] * c[0], g[3][1] * c[1], g[3][2] * c[2]),
    )
    for j in range(n):  # M_q = F_q P, column by column into rows 3-6
        o = p + j
        p0, p1, p2 = st[o], st[o + n], st[o + 2 * n]
        q0, q1, q2, q3 = st[o + 3 * n], st[o + 4 * n], st[o + 5 * n], st[o + 6 * n]
        for r in range(4):
            st[o + (3 + r) * n] = (gc[r][0] * p0 + gc[r][1] * p1 + gc[r][2] * p2
                                   + f[r][0] * q0 + f[r][1] * q1 + f[r][2] * q2
                                   + f[r][3] * q3)
    for r in range(4):  # P⁺_qq (upper), from row r of M_q (its ω and q columns)
        o = p + (3 + r) * n
        m0, m1, m2 = st[o], st[o + 1], st[o + 2]
        m3, m4, m5, m6 = st[o + 3], st[o + 4], st[o + 5], st[o + 6]
        for s in range(r, 4):
            st[o + 3 + s] = (
                m0 * gc[s][0] + m1 * gc[s][1] + m2 * gc[s][2] + m3 * f[s][0] + m4 * f[s][1]
                + m5 * f[s][2] + m6 * f[s][3]
                + (g[r][0] * vp[0] * g[s][0] + g[r][1] * vp[1] * g[s][1]
                   + g[r][2] * vp[2] * g[s][2])
            )
    for i in range(3):  # the rate rows: P⁺_ωω, P⁺_ωq = a_i M_qω[r, i], P⁺_ωb
        o = p + i * n
        for j in range(i, 3):
            st[o + j] = a[i] * st[o + j] * a[j]
        st[o + i] += vw[i]
        for r in range(4):
            st[o + 3 + r] = st[p + (3 + r) * n + i] * a[i] + g[r][i] * cpw[i]
        for j in range(7, n):
            st[o + j] = a[i] * st[o + j]
    for k in range(7, n):  # P⁺_bb = P_bb + σ_b² h
        st[p + k * (n + 1)] += vb[k - 7]


@njit(cache=True, fastmath=FASTMATH, inline="always")
def mirror(st, p, n):
    """Copy P's upper triangle to its lower one (P at ``st[p:]``, n x n)."""
    for i in range(n):
        for j in range(i + 1, n):
            st[p + j * n + i] = st[p + i * n + j]


@njit(cache=True, inline="always")
def _sym(st, p, n, i, j):
    """``P[i, j]`` from the upper triangle."""
    return st[p + i * n + j] if i <= j else st[p + j * n + i]


@njit(cache=True, fastmath=FASTMATH, inline="always")
def scalar_update(st, x, p, n, ph, i0, i1, h0, h1, h2, h3, nu, r):
    """One scalar measurement ``z = hᵀ x + v``, ``Var v = r``: x, P in place (docstring).

    x at ``st[x:]`` (n), P at ``st[p:]`` (n x n, the upper triangle read and written),
    scratch ``st[ph:]`` (n). The row h is ``e_i0`` (``i1 < 0``), ``e_i0 + e_i1`` (a rate and
    its bias), or, with ``i0 < 0``, ``(h0, h1, h2, h3)`` on the quaternion's components
    3-6. ``nu`` is the innovation against the current x. Returns False (nothing changed)
    unless ``0 < s < inf``.
    """
    if i0 >= 0:
        for j in range(i0):  # P h = row i0 (+ row i1) of P, from the upper triangle
            st[ph + j] = st[p + j * n + i0]
        for j in range(i0, n):
            st[ph + j] = st[p + i0 * n + j]
        if i1 >= 0:
            for j in range(i1):
                st[ph + j] += st[p + j * n + i1]
            for j in range(i1, n):
                st[ph + j] += st[p + i1 * n + j]
            s = st[ph + i0] + st[ph + i1] + r
        else:
            s = st[ph + i0] + r
    else:
        for j in range(n):
            st[ph + j] = (_sym(st, p, n, j, 3) * h0 + _sym(st, p, n, j, 4) * h1
                          + _sym(st, p, n, j, 5) * h2 + _sym(st, p, n, j, 6) * h3)
        s = h0 * st[ph + 3] + h1 * st[ph + 4] + h2 * st[ph + 5] + h3 * st[ph + 6] + r
    if not (s > 0.0 and s < math.inf):
        return False
    inv = 1.0 / s
    kv = nu * inv
    for j in range(n):
        st[x + j] += st[ph + j] * kv
    unit = i0 >= 0 and i1 < 0  # h = e_i0: row i0 is set below, skipped here
    for i in range(n):
        if unit and i == i0:
            continue
        ki = st[ph + i] * inv
        o = p + i * n
        for j in range(i, n):
            if not (unit and j == i0):
                st[o + j] -= ki * st[ph + j]
    if unit:  # row i0 of P⁺ is P_i0 r / s: without the cancellation
        scale = r * inv
        for j in range(i0):
            st[p + j * n + i0] = st[ph + j] * scale
        for j in range(i0, n):
            st[p + i0 * n + j] = st[ph + j] * scale
    return True


@njit(cache=True, inline="always")
def vector_reading(w, x, y, z, vx, vy, vz):
    """Body-frame reading ``R(q)ᵀ v / |q|²`` of a unit earth vector v (3-tuple) and its
    Jacobian ∂/∂q (3 x 4 tuple); 001 eq. 19 with the derived sign (kernel docstring).

    With ``p = q* ⊗ v`` the unnormalised reading is ``vec(p ⊗ q)`` and its derivative
    along ``e_k`` is ``2 vec(p ⊗ e_k)``; dividing by ``|q|²`` subtracts ``2 z q_k / |q|²``.
    """
    n2 = w * w + x * x + y * y + z * z
    p0, p1, p2, p3 = mul(w, -x, -y, -z, 0.0, vx, vy, vz)
    _, gx, gy, gz = mul(p0, p1, p2, p3, w, x, y, z)
    in2 = 1.0 / n2
    zx, zy, zz = gx * in2, gy * in2, gz * in2
    # columns vec(p ⊗ e_k): k = w (p1, p2, p3), x (p0, p3, -p2), y (-p3, p0, p1),
    # z (p2, -p1, p0)
    i2 = 2.0 * in2
    jac = (
        (i2 * (p1 - zx * w), i2 * (p0 - zx * x), i2 * (-p3 - zx * y),
         i2 * (p2 - zx * z)),
        (i2 * (p2 - zy * w), i2 * (p3 - zy * x), i2 * (p0 - zy * y),
         i2 * (-p1 - zy * z)),
        (i2 * (p3 - zz * w), i2 * (-p2 - zz * x), i2 * (p1 - zz * y),
         i2 * (p0 - zz * z)),
    )
    return (zx, zy, zz), jac


@njit(cache=True)
def vector_measurement(w, x, y, z, vx, vy, vz, jac):
    """Body-frame reading ``R(q)ᵀ v / |q|²`` of a unit earth vector v, and its Jacobian.

    (001 eq. 19, derived sign; :func:`vector_reading`.) Returns the 3 components; fills
    jac (3, 4) = ∂/∂q.
    """
    zv, jt = vector_reading(w, x, y, z, vx, vy, vz)
    for i in range(3):
        for k in range(4):
            jac[i, k] = jt[i][k]
    return zv
