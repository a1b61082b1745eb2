"""The per-sample loop of the joint filter: a multiplicative EKF over two orientations.

State: the two sensors' orientations ``q₁``, ``q₂`` (sensor to earth, ENU, ``[w, x, y, z]``)
and the covariance ``P`` (6, 6) of their errors ``ε = (ε₁, ε₂)``, each a rotation vector
in the earth frame: ``R_true = Exp(ε) R̂`` (a left, earth-frame error, not the body-frame
error of Weygers & Kok 2020's MEKF-acc: see below).

Prediction over ``dt`` (docs/joint.md, eq. 1): ``q ← q ⊗ Exp(ω̄ dt)`` with the trapezoid
rate ``ω̄ = (ω_{k-1} + ω_k) / 2`` for samples that are instantaneous rates, or ``ω̄ = ω_k``
for samples that are the mean rate since the previous one (``gyr_timing``). An earth-frame
error is not moved by the body's own rotation, so the error transition is the identity and,
with isotropic gyroscope noise, ``P ← P + σ_g² dt I``: no 6x6 products.

Update with the joint-centre specific forces ``c₁``, ``c₂`` (sensor frames; eq. 2), in the
earth frame ``v_i = R̂_i c_i``. Both sensors see the same centre, ``v₁ = v₂ = g + a_J``
with ``a_J`` the centre's acceleration: the difference is the link measurement, the mean
the inclination measurement (independent for equal noise on ``v₁`` and ``v₂``)::

    link:  0 = v₁ - v₂,            H = [-[v₁]×,      [v₂]×     ]   (std link_noise)
    incl:  g ẑ = (v₁ + v₂) / 2,    H = [-[v₁]×/2,   -[v₂]×/2   ]   (std incl_noise,
                                                                    grown by |mean| - g)

using ``∂(Exp(ε) R̂ c)/∂ε = -[R̂ c]×``. The six rows are applied one at a time (their noise
is diagonal, so this equals the joint update and needs no matrix inverse), then the
correction is folded into the orientations, ``R̂ ← Exp(δε) R̂``.

The relative heading (rotation about the vertical) is observable only while the joint
centre accelerates horizontally; the global heading never is, and is pinned by giving
the parent's heading a zero initial variance.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["filter_pass"]

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
def _times_exp(q: np.ndarray, vx: float, vy: float, vz: float, left: bool) -> None:
    """q ← q ⊗ Exp(v) (``left`` False) or Exp(v) ⊗ q (``left`` True), renormalised."""
    angle = np.sqrt(vx * vx + vy * vy + vz * vz)
    if angle < 1e-9:
        s = 0.5
        d0 = 1.0
    else:
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
    norm = np.sqrt(w * w + x * x + y * y + z * z)
    q[0], q[1], q[2], q[3] = w / norm, x / norm, y / norm, z / norm


@numba.njit(cache=True)
def _level(c: np.ndarray, q: np.ndarray) -> None:
    """q: the shortest rotation taking the direction of ``c`` (sensor frame) to +z (up)."""
    norm = np.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
    ux, uy, uz = c[0] / norm, c[1] / norm, c[2] / norm
    if uz < -0.999999:  # upside down: half a turn about x
        q[0], q[1], q[2], q[3] = 0.0, 1.0, 0.0, 0.0
        return
    # axis u × ẑ = (uy, -ux, 0), angle acos(uz): q = [1 + uz, uy, -ux, 0] normalised
    w, x, y = 1.0 + uz, uy, -ux
    n = np.sqrt(w * w + x * x + y * y)
    q[0], q[1], q[2], q[3] = w / n, x / n, y / n, 0.0


@numba.njit(cache=True)
def _reset_cov(p: np.ndarray, coeffs: np.ndarray) -> None:
    """P at a (re)start: inclinations uncertain, the parent's heading fixed (the gauge),
    the relative heading uncertain."""
    p[:, :] = 0.0
    for i in (0, 1, 3, 4):
        p[i, i] = coeffs[C_P0_INCL]
    p[2, 2] = 1e-12
    p[5, 5] = coeffs[C_P0_HEADING]


@numba.njit(cache=True)
def _set_rows(v1: np.ndarray, v2: np.ndarray, h: np.ndarray) -> None:
    """The six measurement rows (link, then inclination) at ``v₁``, ``v₂``."""
    h[:, :] = 0.0
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
def filter_pass(
    t: np.ndarray,
    gyr1: np.ndarray,
    gyr2: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    meas_ok: np.ndarray,
    restart: np.ndarray,
    q_start: np.ndarray,
    p_start: np.ndarray,
    started: bool,
    coeffs: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Run the filter over all samples (module docstring).

    t (N,) s; gyr1, gyr2 (N, 3) rad/s; c1, c2 (N, 3) m/s² joint-centre specific forces;
    meas_ok (N,) bool: the sample's measurement may be used; restart (N,) bool: a gap ends
    at the sample (not integrated over; the covariance restarts). ``q_start`` (2, 4) and
    ``p_start`` (6, 6) are the state to start from when ``started``; otherwise the filter
    starts at the first usable sample, levelled by its ``c``. ``coeffs``: see the C_ slots.

    Returns ``(q, p, first)``: q (2, N, 4) the orientations after each sample (identity
    before the start), p (6, 6) the final covariance, first the index of the start (0 when
    ``started``; N when no sample was usable).
    """
    n = t.shape[0]
    q = np.empty((2, n, 4))
    q1 = q_start[0].copy()
    q2 = q_start[1].copy()
    p = p_start.copy()
    first = 0 if started else n
    h = np.zeros((6, 6))
    y = np.zeros(6)
    r = np.zeros(6)
    ph = np.zeros(6)
    dx = np.zeros(6)
    v1 = np.zeros(3)
    v2 = np.zeros(3)
    g = coeffs[C_GRAVITY]
    for k in range(n):
        if not started:
            if not meas_ok[k]:
                q[0, k, 0], q[0, k, 1], q[0, k, 2], q[0, k, 3] = 1.0, 0.0, 0.0, 0.0
                q[1, k, 0], q[1, k, 1], q[1, k, 2], q[1, k, 3] = 1.0, 0.0, 0.0, 0.0
                continue
            _level(c1[k], q1)
            _level(c2[k], q2)
            _reset_cov(p, coeffs)
            started = True
            first = k
        elif k > 0 and restart[k]:
            _reset_cov(p, coeffs)  # held over the gap, uncertain again
        elif k > 0:
            dt = t[k] - t[k - 1]
            a = coeffs[C_GYR_PREV] * dt
            b = dt - a
            _times_exp(q1, a * gyr1[k - 1, 0] + b * gyr1[k, 0],
                       a * gyr1[k - 1, 1] + b * gyr1[k, 1],
                       a * gyr1[k - 1, 2] + b * gyr1[k, 2], False)
            _times_exp(q2, a * gyr2[k - 1, 0] + b * gyr2[k, 0],
                       a * gyr2[k - 1, 1] + b * gyr2[k, 1],
                       a * gyr2[k - 1, 2] + b * gyr2[k, 2], False)
            qg = coeffs[C_GYR_VAR] * dt
            for i in range(6):
                p[i, i] += qg
        if meas_ok[k]:
            _rotate_by(q1, c1[k], v1)
            _rotate_by(q2, c2[k], v2)
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
            for j in range(6):
                innov = y[j]
                s = r[j]
                for a in range(6):
                    acc = 0.0
                    for b in range(6):
                        acc += p[a, b] * h[j, b]
                    ph[a] = acc
                    innov -= h[j, a] * dx[a]
                for a in range(6):
                    s += h[j, a] * ph[a]
                for a in range(6):
                    gain = ph[a] / s
                    dx[a] += gain * innov
                    for b in range(6):
                        p[a, b] -= gain * ph[b]
            _times_exp(q1, dx[0], dx[1], dx[2], True)
            _times_exp(q2, dx[3], dx[4], dx[5], True)
        for i in range(4):
            q[0, k, i] = q1[i]
            q[1, k, i] = q2[i]
    return q, p, first
