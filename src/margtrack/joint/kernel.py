"""The per-sample loop of the joint filter: a multiplicative EKF over two orientations.

State: the two sensors' orientations ``q₁``, ``q₂`` (sensor to earth, ENU, ``[w, x, y, z]``)
and the covariance ``P`` of their errors ``ε₁``, ``ε₂``, each a rotation vector in the earth
frame: ``R_true = Exp(ε) R̂`` (a left, earth-frame error, not the body-frame error of
Weygers & Kok 2020's MEKF-acc: see below). Turning both sensors about the vertical changes
no measurement's likelihood (the global heading is unobservable without a magnetometer), so
the parent's heading error is not a state: ``P`` is (5, 5) over
``(ε₁ₓ, ε₁ᵧ, ε₂ₓ, ε₂ᵧ, ψ)``, ``ψ = ε₂_z - ε₁_z`` the relative heading error, carried by the
child. The parent's heading follows its gyroscope alone.

Prediction over ``dt`` (docs/joint.md, eq. 1): ``q ← q ⊗ Exp(ω̄ dt)`` with the trapezoid
rate ``ω̄ = (ω_{k-1} + ω_k) / 2`` for samples that are instantaneous rates, or ``ω̄ = ω_k``
for samples that are the mean rate since the previous one (``gyr_timing``). An earth-frame
error is not moved by the body's own rotation, so the error transition is the identity and,
with isotropic gyroscope noise, ``P ← P + σ_g² dt diag(1, 1, 1, 1, 2)`` (ψ takes both
sensors' heading noise): no matrix products.

Update with the joint-centre specific forces ``c₁``, ``c₂`` (sensor frames; eq. 2), in the
earth frame ``v_i = R̂_i c_i``. Both sensors see the same centre, ``v₁ = v₂ = g ẑ + a_J``
with ``a_J`` the centre's acceleration: the difference is the link measurement, the mean
the inclination measurement (independent for equal noise on ``v₁`` and ``v₂``)::

    link:  0 = v₁ - v₂,                 H = [-[v₁]×,     [v₂]×    ]   (std link_noise)
    incl:  0 = ((v₁ + v₂) / 2)ₓ,ᵧ,      H = rows x, y of [-[v₁]×/2, -[v₂]×/2]
                                        (std incl_noise, grown by |mean| - g)

using ``∂(Exp(ε) R̂ c)/∂ε = -[R̂ c]×`` (the columns of ``ε₁_z`` dropped, those of ``ε₂_z``
taken by ψ). The inclination measurement is the mean's horizontal part only: its vertical
part is how hard the joint accelerates up or down, and to first order says nothing about
the tilts. The five rows are applied one at a time (their noise is diagonal, so this
equals the joint update and needs no matrix inverse), then the correction is folded into
the orientations, ``R̂ ← Exp(δε) R̂``, renormalised once per sample.

The relative heading (rotation about the vertical) is observable only while the joint
centre accelerates horizontally.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["centre_forces", "filter_pass", "rate_derivative"]

# coefficient slots of filter_pass (one float64 array, so the signature stays short)
C_GYR_VAR = 0  # σ_g², (rad/s)²/Hz
C_LINK_VAR = 1  # σ_link², (m/s²)²
C_INCL_VAR = 2  # σ_incl², (m/s²)²
C_INCL_GAIN = 3  # inclination variance per (m/s²)² of |mean| - g
C_GRAVITY = 4  # g, m/s²
C_P0_INCL = 5  # first inclination variance, rad²
C_P0_HEADING = 6  # first relative heading variance, rad²
C_GYR_PREV = 7  # weight of the previous rate sample in an interval's rate (0.5 or 0)
N_COEFFS = 8


@numba.njit(cache=True)
def _rotate_by(q: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    """out = R(q) v for a unit quaternion q = [w, x, y, z]."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    a, b, c = v[0], v[1], v[2]
    out[0] = (1 - 2 * (y * y + z * z)) * a + 2 * (x * y - w * z) * b + 2 * (x * z + w * y) * c
    out[1] = 2 * (x * y + w * z) * a + (1 - 2 * (x * x + z * z)) * b + 2 * (y * z - w * x) * c
    out[2] = 2 * (x * z - w * y) * a + 2 * (y * z + w * x) * b + (1 - 2 * (x * x + y * y)) * c


@numba.njit(cache=True)
def _times_exp(q: np.ndarray, vx: float, vy: float, vz: float, left: bool,
               renormalise: bool) -> None:
    """q ← q ⊗ Exp(v) (``left`` False) or Exp(v) ⊗ q (``left`` True).

    Below 0.5 rad (a sample's turn, a correction) cos(θ/2) and sin(θ/2)/θ come from their
    Taylor series to θ⁶ (error below 1e-9 there): no trigonometry in the loop. The caller
    renormalises once per sample (``renormalise`` on its last product).
    """
    a2 = vx * vx + vy * vy + vz * vz
    if a2 < 0.25:
        d0 = 1.0 - a2 / 8.0 + a2 * a2 / 384.0 - a2 * a2 * a2 / 46080.0
        s = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0 - a2 * a2 * a2 / 645120.0
    else:
        angle = np.sqrt(a2)
        s = np.sin(0.5 * angle) / angle
        d0 = np.cos(0.5 * angle)
    d1, d2, d3 = vx * s, vy * s, vz * s
    a0, a1, a2, a3 = q[0], q[1], q[2], q[3]
    if left:
        a0, a1, a2, a3, d0, d1, d2, d3 = d0, d1, d2, d3, a0, a1, a2, a3
    w = a0 * d0 - a1 * d1 - a2 * d2 - a3 * d3
    x = a0 * d1 + a1 * d0 + a2 * d3 - a3 * d2
    y = a0 * d2 - a1 * d3 + a2 * d0 + a3 * d1
    z = a0 * d3 + a1 * d2 - a2 * d1 + a3 * d0
    if renormalise:
        inv = 1.0 / np.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w * inv, x * inv, y * inv, z * inv
    q[0], q[1], q[2], q[3] = w, x, y, z


@numba.njit(cache=True)
def _level(c: np.ndarray, q: np.ndarray, v: np.ndarray) -> None:
    """q ← the shortest earth-frame turn taking R(q) c to +z (up), applied to q: the tilt
    the specific force ``c`` (sensor frame) gives, the heading kept as far as it can be.
    ``v`` is scratch (3,)."""
    _rotate_by(q, c, v)
    norm = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    ux, uy, uz = v[0] / norm, v[1] / norm, v[2] / norm
    if uz < -0.999999:  # upside down: half a turn about x
        w, x, y = 0.0, 1.0, 0.0
    else:  # axis u × ẑ = (uy, -ux, 0), angle acos(uz): [1 + uz, uy, -ux, 0] normalised
        w, x, y = 1.0 + uz, uy, -ux
    n = np.sqrt(w * w + x * x + y * y)
    w, x, y = w / n, x / n, y / n
    a0, a1, a2, a3 = q[0], q[1], q[2], q[3]
    q[0] = w * a0 - x * a1 - y * a2
    q[1] = w * a1 + x * a0 + y * a3
    q[2] = w * a2 - x * a3 + y * a0
    q[3] = w * a3 + x * a2 - y * a1
    inv = 1.0 / np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for i in range(4):
        q[i] *= inv


@numba.njit(cache=True)
def _reset_cov(p: np.ndarray, coeffs: np.ndarray) -> None:
    """P at a (re)start: inclinations and the relative heading uncertain."""
    p[:, :] = 0.0
    for i in range(4):
        p[i, i] = coeffs[C_P0_INCL]
    p[4, 4] = coeffs[C_P0_HEADING]


@numba.njit(cache=True)
def rate_derivative(t: np.ndarray, gyr: np.ndarray) -> np.ndarray:
    """ω̇ (N, 3) rad/s² from rates ``gyr`` (N, 3) rad/s at times ``t`` (N,) s.

    A five-point central difference on a uniform clock (step within 0.1 % of the median's;
    error O(dt⁴), noise gain ``√130 / (12 dt)``), a second-order central difference on an
    irregular one; the first and last two samples use second-order one-sided differences.
    Central differences look two samples ahead: an online output waits for the gyroscope's
    next two samples.
    """
    n = t.shape[0]
    out = np.zeros((n, 3))
    if n < 3:
        return out
    dt = np.diff(t)
    step = np.median(dt)
    uniform = n >= 5 and np.max(np.abs(dt - step)) <= 1e-3 * step
    for k in range(n):
        if uniform and 2 <= k < n - 2:
            for i in range(3):
                out[k, i] = (gyr[k - 2, i] - 8.0 * gyr[k - 1, i] + 8.0 * gyr[k + 1, i]
                             - gyr[k + 2, i]) / (12.0 * step)
            continue
        # three-point second-order differences on any spacing (numpy.gradient's formulas)
        j = min(max(k, 1), n - 2)
        h1, h2 = t[j] - t[j - 1], t[j + 1] - t[j]
        if k == j:  # central
            a, b, c = -h2 / (h1 * (h1 + h2)), (h2 - h1) / (h1 * h2), h1 / (h2 * (h1 + h2))
        elif k < j:  # first sample, forward
            a = -(2 * h1 + h2) / (h1 * (h1 + h2))
            b = (h1 + h2) / (h1 * h2)
            c = -h1 / (h2 * (h1 + h2))
        else:  # last sample, backward
            a = h2 / (h1 * (h1 + h2))
            b = -(h1 + h2) / (h1 * h2)
            c = (2 * h2 + h1) / (h2 * (h1 + h2))
        for i in range(3):
            out[k, i] = a * gyr[j - 1, i] + b * gyr[j, i] + c * gyr[j + 1, i]
    return out


@numba.njit(cache=True)
def centre_forces(t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Joint-centre specific forces ``c = a - ω×(ω×r) - ω̇×r`` (2, N, 3) m/s².

    t (N,) s; gyr, acc (2, N, 3) rad/s and m/s² in each sensor's frame; r (2, 3) m, joint
    centre to each sensor (:mod:`margtrack.joint.lever_arms`).
    """
    n = t.shape[0]
    c = np.empty((2, n, 3))
    for s in range(2):
        wd = rate_derivative(t, gyr[s])
        rx, ry, rz = r[s, 0], r[s, 1], r[s, 2]
        for k in range(n):
            wx, wy, wz = gyr[s, k, 0], gyr[s, k, 1], gyr[s, k, 2]
            ax, ay, az = wd[k, 0], wd[k, 1], wd[k, 2]
            ux, uy, uz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx  # ω × r
            c[s, k, 0] = acc[s, k, 0] - (wy * uz - wz * uy) - (ay * rz - az * ry)
            c[s, k, 1] = acc[s, k, 1] - (wz * ux - wx * uz) - (az * rx - ax * rz)
            c[s, k, 2] = acc[s, k, 2] - (wx * uy - wy * ux) - (ax * ry - ay * rx)
    return c


@numba.njit(cache=True)
def _set_rows(v1: np.ndarray, v2: np.ndarray, h: np.ndarray) -> None:
    """The measurement rows (link x, y, z, then inclination x, y, and z, unused) at ``v₁``,
    ``v₂``, over the six error components ``(ε₁, ε₂)``.

    Row ``j`` involves only the two axes other than ``j % 3`` of each sensor (a cross
    product's row): the update reads those four columns only, mapped onto the state.
    """
    for blk in range(2):
        v = v1 if blk == 0 else v2
        col = 3 * blk
        sign = -1.0 if blk == 0 else 1.0  # link rows: sign · [v]×
        h[0, col + 1] = -sign * v[2]
        h[0, col + 2] = sign * v[1]
        h[1, col + 0] = sign * v[2]
        h[1, col + 2] = -sign * v[0]
        h[2, col + 0] = -sign * v[1]
        h[2, col + 1] = sign * v[0]
        # inclination rows: -[v]× / 2
        h[3, col + 1] = 0.5 * v[2]
        h[3, col + 2] = -0.5 * v[1]
        h[4, col + 0] = -0.5 * v[2]
        h[4, col + 2] = 0.5 * v[0]
        h[5, col + 0] = 0.5 * v[1]
        h[5, col + 1] = -0.5 * v[0]


@numba.njit(cache=True)
def _row(p: np.ndarray, dx: np.ndarray, ph: np.ndarray, y: float, r: float,
         c0: int, h0: float, c1: int, h1: float, c2: int, h2: float, c3: int,
         h3: float) -> None:
    """One scalar measurement ``y = h·ε + noise(r)`` with ``h`` non-zero at c0..c3 only:
    the Kalman update of ``P`` (5, 5) and of the correction ``dx`` gathered so far."""
    ph0 = p[0, c0] * h0 + p[0, c1] * h1 + p[0, c2] * h2 + p[0, c3] * h3
    ph1 = p[1, c0] * h0 + p[1, c1] * h1 + p[1, c2] * h2 + p[1, c3] * h3
    ph2 = p[2, c0] * h0 + p[2, c1] * h1 + p[2, c2] * h2 + p[2, c3] * h3
    ph3 = p[3, c0] * h0 + p[3, c1] * h1 + p[3, c2] * h2 + p[3, c3] * h3
    ph4 = p[4, c0] * h0 + p[4, c1] * h1 + p[4, c2] * h2 + p[4, c3] * h3
    ph[0], ph[1], ph[2], ph[3], ph[4] = ph0, ph1, ph2, ph3, ph4
    innov = y - (h0 * dx[c0] + h1 * dx[c1] + h2 * dx[c2] + h3 * dx[c3])
    inv = 1.0 / (r + h0 * ph[c0] + h1 * ph[c1] + h2 * ph[c2] + h3 * ph[c3])
    for a in range(5):
        gain = ph[a] * inv
        dx[a] += gain * innov
        p[a, 0] -= gain * ph0
        p[a, 1] -= gain * ph1
        p[a, 2] -= gain * ph2
        p[a, 3] -= gain * ph3
        p[a, 4] -= gain * ph4


@numba.njit(cache=True)
def filter_pass(
    t: np.ndarray,
    gyr: np.ndarray,
    c: np.ndarray,
    meas_ok: np.ndarray,
    restart: np.ndarray,
    q_start: np.ndarray,
    p_start: np.ndarray,
    started: bool,
    coeffs: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Run the filter over all samples (module docstring).

    t (N,) s; gyr (2, N, 3) rad/s; c (2, N, 3) m/s² joint-centre specific forces
    (:func:`centre_forces`), parent's then child's; meas_ok (N,) bool: the sample's
    measurement may be used; restart (N,) bool: a gap ends at the sample (not integrated
    over; the covariance restarts). ``q_start`` (2, 4) and ``p_start`` (5, 5) are the state
    to start from when ``started``; otherwise the filter starts at the first usable sample,
    levelled by its ``c`` (``q_start``'s headings kept). ``coeffs``: see the C_ slots.

    Returns ``(q, rel, p, first)``: q (2, N, 4) the orientations after each sample (identity
    before the start), rel (N, 4) ``conj(q₁) ⊗ q₂``, p (5, 5) the final covariance, first
    the index of the start (0 when ``started``; N when no sample was usable).
    """
    n = t.shape[0]
    q = np.empty((2, n, 4))
    rel = np.empty((n, 4))
    q1 = q_start[0].copy()
    q2 = q_start[1].copy()
    p = p_start.copy()
    first = 0 if started else n
    h = np.zeros((6, 6))
    y = np.zeros(6)
    r = np.zeros(6)
    ph = np.zeros(5)
    dx = np.zeros(5)
    v1 = np.zeros(3)
    v2 = np.zeros(3)
    g = coeffs[C_GRAVITY]
    restart_pending = False
    for k in range(n):
        if not started:
            if not meas_ok[k]:
                for sensor in range(2):
                    q[sensor, k, 0], q[sensor, k, 1] = 1.0, 0.0
                    q[sensor, k, 2], q[sensor, k, 3] = 0.0, 0.0
                rel[k, 0], rel[k, 1], rel[k, 2], rel[k, 3] = 1.0, 0.0, 0.0, 0.0
                continue
            _level(c[0, k], q1, v1)
            _level(c[1, k], q2, v2)
            _reset_cov(p, coeffs)
            started = True
            first = k
        elif k > 0 and restart[k]:
            # not integrated over the gap: each sensor levelled again by its first usable
            # specific force after it, the headings kept, uncertain again
            restart_pending = True
            _reset_cov(p, coeffs)
        elif k > 0:
            dt = t[k] - t[k - 1]
            w_prev = coeffs[C_GYR_PREV] * dt
            w_now = dt - w_prev
            _times_exp(q1, w_prev * gyr[0, k - 1, 0] + w_now * gyr[0, k, 0],
                       w_prev * gyr[0, k - 1, 1] + w_now * gyr[0, k, 1],
                       w_prev * gyr[0, k - 1, 2] + w_now * gyr[0, k, 2], False,
                       not meas_ok[k])
            _times_exp(q2, w_prev * gyr[1, k - 1, 0] + w_now * gyr[1, k, 0],
                       w_prev * gyr[1, k - 1, 1] + w_now * gyr[1, k, 1],
                       w_prev * gyr[1, k - 1, 2] + w_now * gyr[1, k, 2], False,
                       not meas_ok[k])
            qg = coeffs[C_GYR_VAR] * dt
            for i in range(4):
                p[i, i] += qg
            p[4, 4] += 2.0 * qg
        if meas_ok[k] and restart_pending:
            _level(c[0, k], q1, v1)
            _level(c[1, k], q2, v2)
            restart_pending = False
        if meas_ok[k]:
            _rotate_by(q1, c[0, k], v1)
            _rotate_by(q2, c[1, k], v2)
            _set_rows(v1, v2, h)
            m0 = 0.5 * (v1[0] + v2[0])
            m1 = 0.5 * (v1[1] + v2[1])
            m2 = 0.5 * (v1[2] + v2[2])
            y[0], y[1], y[2] = v2[0] - v1[0], v2[1] - v1[1], v2[2] - v1[2]
            y[3], y[4], y[5] = -m0, -m1, g - m2
            off = np.sqrt(m0 * m0 + m1 * m1 + m2 * m2) - g
            r_incl = coeffs[C_INCL_VAR] + coeffs[C_INCL_GAIN] * off * off
            for i in range(3):
                r[i] = coeffs[C_LINK_VAR]
                r[3 + i] = r_incl
            dx[:] = 0.0
            # each row's non-zero columns: the other two axes of each sensor, on the state
            # (ε₁_z is not a state: its weight is dropped; ε₂_z is ψ, state 4)
            for j in (0, 3):  # axes y, z: ε₁ᵧ, ε₂ᵧ, ψ
                _row(p, dx, ph, y[j], r[j], 1, h[j, 1], 3, h[j, 4], 4, h[j, 5], 0, 0.0)
            for j in (1, 4):  # axes z, x: ε₁ₓ, ε₂ₓ, ψ
                _row(p, dx, ph, y[j], r[j], 0, h[j, 0], 2, h[j, 3], 4, h[j, 5], 0, 0.0)
            # link z: axes x, y, the four inclination components
            _row(p, dx, ph, y[2], r[2], 0, h[2, 0], 1, h[2, 1], 2, h[2, 3], 3, h[2, 4])
            _times_exp(q1, dx[0], dx[1], 0.0, True, True)
            _times_exp(q2, dx[2], dx[3], dx[4], True, True)
        for i in range(4):
            q[0, k, i] = q1[i]
            q[1, k, i] = q2[i]
        # rel = conj(q1) ⊗ q2
        e0, e1, e2, e3 = q1[0], -q1[1], -q1[2], -q1[3]
        rel[k, 0] = e0 * q2[0] - e1 * q2[1] - e2 * q2[2] - e3 * q2[3]
        rel[k, 1] = e0 * q2[1] + e1 * q2[0] + e2 * q2[3] - e3 * q2[2]
        rel[k, 2] = e0 * q2[2] - e1 * q2[3] + e2 * q2[0] + e3 * q2[1]
        rel[k, 3] = e0 * q2[3] + e1 * q2[2] - e2 * q2[1] + e3 * q2[0]
    return q, rel, p, first
