"""Covariance algebra of Ang's bias filter (003 eqs. 46-51), hand-derived for its structure.

The 7x7 ``P`` of ``x = [q (4), b (3)]`` and the scratch of these helpers live in one flat
float64 ``row`` (the filter's state row): ``P`` row-major at ``row[p0:]``, the scratch at
``row[s0:]`` (``N_SCRATCH`` slots, offsets ``F_*``). Every helper is inlined and indexes
``row`` at offsets the compiler knows, so it keeps the small matrices in registers and sees
that no two of them overlap (views of the row with their own strides hid that, and every
store forced the loads after it to be repeated).

What the structure buys, each an identity of exact arithmetic (the rounding differs):

- prediction (eq. 48): ``Φ = [[Φ_Q, Φ_Q A], [0, I]]`` with ``A = -½ T Q̃(q)`` (eq. 28), so
  ``P⁻_qb = Φ_Q M``, ``P⁻_qq = Φ_Q X Φ_Qᵀ + W`` with ``M = P_qb + A P_bb`` and
  ``X = P_qq + A P_bq + M Aᵀ``; ``P_bb`` only gains the bias walk; 250 multiply-adds
  instead of the 7x7 product's 520;
- ``W = ¼ Q̃ Ξ Q̃ᵀ + w qqᵀ`` (eqs. 31, 46) with ``Ξ`` diagonal: three products per entry;
- ``Q̃ Q̃ᵀ = I - qqᵀ`` (``[q, Q̃]`` is orthogonal for a unit ``q``): the decoupled
  measurement's ``V = ¼ Q̃ (σ_G² (I - ẑẑᵀ) + σ_H² ẑẑᵀ) Q̃ᵀ + qqᵀ`` is
  ``¼σ_G² (I - qqᵀ) + ¼(σ_H² - σ_G²) vvᵀ + qqᵀ`` with ``v = Q̃ ẑ``, and the tilt gate's
  ``½ (tr P_θ - ẑᵀ P_θ ẑ)`` with ``P_θ = 4 Q̃ᵀ P_qq Q̃`` is
  ``2 (tr P_qq - qᵀ P_qq q - vᵀ P_qq v)``; TRIAD's ``V = ¼ Q̃ Ξθ Q̃ᵀ + qqᵀ`` with eq. 45's
  ``Ξθ`` is ``(1 - ¼σ_G²) qqᵀ + ¼σ_G² I + a vvᵀ + b (vuᵀ + uvᵀ)``, ``v = Q̃ ẑ``,
  ``u = Q̃ n̂``: no 4x3 and 3x3 products, no array views;
- update (eqs. 49-51), ``H = [I₄ 0]``: ``S = L D Lᵀ`` and ``W = P_·q L⁻ᵀ`` give
  ``K ν = W D⁻¹ L⁻¹ ν`` and ``P - K S Kᵀ = P - W D⁻¹ Wᵀ``: 150 multiply-adds where the
  gain's two triangular solves per column and the Joseph form's three 7x4 products took
  660, and no square root; one triangle is computed and mirrored, so ``P`` stays exactly
  symmetric.
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit
from margtrack.estimator.quat_kernel import normalized

__all__ = [
    "N_SCRATCH", "body_direction", "decoupled_noise", "kalman_update", "predict", "tilt_d2",
    "tilt_variance", "triad_noise",
]

# scratch offsets (relative to s0)
F_PHI = 0  # 16: Φ_Q, row-major (eq. 27)
F_A = F_PHI + 16  # 12: A = -½ T Q̃(q) (4, 3) (eq. 28)
F_M = F_A + 12  # 12: M = P_qb + A P_bb (4, 3)
F_X = F_M + 12  # 16: X = [I A] P [I A]ᵀ (4, 4)
F_Y = F_X + 16  # 16: Φ_Q X (4, 4)
F_QT = F_Y + 16  # 12: Q̃(q⁻) (4, 3)
F_L = F_QT + 12  # 16: S = P_qq + V = L D Lᵀ: L's strict lower part and D on its diagonal
F_ID = F_L + 16  # 4: D⁻¹
F_Z = F_ID + 4  # 4: L⁻¹ ν
F_W = F_Z + 4  # 28: W = P_·q L⁻ᵀ (7, 4)
F_WD = F_W + 28  # 28: W D⁻¹ (7, 4)
F_DX = F_WD + 28  # 7: the state correction K ν
N_SCRATCH = F_DX + 7


@njit(cache=True, inline="always")
def _component(k, c0, c1, c2, c3):
    """Component k of the 4-vector (c0, c1, c2, c3) (k a loop index over 0-3: unrolled,
    the selection folds away)."""
    return c0 if k == 0 else (c1 if k == 1 else (c2 if k == 2 else c3))


@njit(cache=True, inline="always")
def _half_angle(angle2):
    """``(cos(|Θ|/2), sin(|Θ|/2)/|Θ|)`` of ``|Θ|² = angle2`` rad² (003 eq. 27).

    Below ``|Θ|`` = 0.2 rad (70 rad/s at 286 Hz) by their Taylor series to the 10th power
    of ``|Θ|/2``, whose remainder (< 2e-21) is far below the rounding: no square root and
    no libm call on the usual sample; beyond, by ``math.cos`` and ``math.sin``.
    """
    if angle2 < 0.04:
        x2 = 0.25 * angle2  # (|Θ|/2)²
        c = 1.0 - x2 * (1.0 / 2.0) * (1.0 - x2 * (1.0 / 12.0) * (1.0 - x2 * (1.0 / 30.0) * (
            1.0 - x2 * (1.0 / 56.0) * (1.0 - x2 * (1.0 / 90.0)))))
        s = 0.5 - x2 * (0.5 / 6.0) * (1.0 - x2 * (1.0 / 20.0) * (1.0 - x2 * (1.0 / 42.0) * (
            1.0 - x2 * (1.0 / 72.0) * (1.0 - x2 * (1.0 / 110.0)))))
        return c, s
    angle = math.sqrt(angle2)
    return math.cos(0.5 * angle), math.sin(0.5 * angle) / angle


@njit(cache=True, inline="always")
def predict(row, p0, s0, h, qw, qx, qy, qz, tx, ty, tz, xi0, xi1, xi2, walk0, walk1, walk2):
    """Predict ``q`` and ``P`` over one period (003 eqs. 25-31, 47-48); returns ``q⁻``.

    ``q`` unit, body to earth; ``Θ = (tx, ty, tz) = (Ω - b) T`` rad; ``h`` = T s;
    ``xi*`` the diagonal of ``Ξ_Ω`` rad² and ``walk*`` that of ``Ξ_B`` (rad/s)² over the
    period. ``q⁻ = Φ_Q q`` normalised; ``P⁻ = Φ P Φᵀ + diag(W, Ξ_B)``, ``W = ¼ Q̃ Ξ_Ω Q̃ᵀ +
    w q⁻q⁻ᵀ`` at ``q⁻`` with ``w = ((tr Ξ)² + 2 tr Ξ²)/64`` capped at 1 (see
    ``bias_kf_model.fill_quat_noise``).
    """
    f = s0 + F_PHI
    c, s = _half_angle(tx * tx + ty * ty + tz * tz)
    sx, sy, sz = s * tx, s * ty, s * tz
    row[f + 0], row[f + 1], row[f + 2], row[f + 3] = c, -sx, -sy, -sz  # eq. 27
    row[f + 4], row[f + 5], row[f + 6], row[f + 7] = sx, c, sz, -sy
    row[f + 8], row[f + 9], row[f + 10], row[f + 11] = sy, -sz, c, sx
    row[f + 12], row[f + 13], row[f + 14], row[f + 15] = sz, sy, -sx, c
    a = s0 + F_A
    g = -0.5 * h  # A = -½ T Q̃(q), eq. 28 with the period T
    row[a + 0], row[a + 1], row[a + 2] = -g * qx, -g * qy, -g * qz
    row[a + 3], row[a + 4], row[a + 5] = g * qw, -g * qz, g * qy
    row[a + 6], row[a + 7], row[a + 8] = g * qz, g * qw, -g * qx
    row[a + 9], row[a + 10], row[a + 11] = -g * qy, g * qx, g * qw
    m = s0 + F_M
    for i in range(4):  # M = P_qb + A P_bb
        for j in range(3):
            acc = row[p0 + 7 * i + 4 + j]
            for k in range(3):
                acc += row[a + 3 * i + k] * row[p0 + 7 * (4 + k) + 4 + j]
            row[m + 3 * i + j] = acc
    x = s0 + F_X
    for i in range(4):  # X = P_qq + A P_bq + M Aᵀ (symmetric)
        for j in range(i, 4):
            acc = row[p0 + 7 * i + j]
            for k in range(3):
                acc += (row[a + 3 * i + k] * row[p0 + 7 * j + 4 + k]
                        + row[m + 3 * i + k] * row[a + 3 * j + k])
            row[x + 4 * i + j] = acc
            row[x + 4 * j + i] = acc
    y = s0 + F_Y
    for i in range(4):  # Y = Φ_Q X
        for j in range(4):
            acc = 0.0
            for k in range(4):
                acc += row[f + 4 * i + k] * row[x + 4 * k + j]
            row[y + 4 * i + j] = acc
    qw, qx, qy, qz = normalized(
        c * qw - sx * qx - sy * qy - sz * qz,
        sx * qw + c * qx + sz * qy - sy * qz,
        sy * qw - sz * qx + c * qy + sx * qz,
        sz * qw + sy * qx - sx * qy + c * qz,
    )  # eq. 47
    t = s0 + F_QT  # Q̃(q⁻)
    row[t + 0], row[t + 1], row[t + 2] = -qx, -qy, -qz
    row[t + 3], row[t + 4], row[t + 5] = qw, -qz, qy
    row[t + 6], row[t + 7], row[t + 8] = qz, qw, -qx
    row[t + 9], row[t + 10], row[t + 11] = -qy, qx, qw
    tr = xi0 + xi1 + xi2
    along = min((tr * tr + 2.0 * (xi0 * xi0 + xi1 * xi1 + xi2 * xi2)) / 64.0, 1.0)
    q0, q1, q2, q3 = qw, qx, qy, qz
    for i in range(4):  # P_qq = Φ_Q X Φ_Qᵀ + W
        qi = _component(i, q0, q1, q2, q3)
        for j in range(i, 4):
            qj = _component(j, q0, q1, q2, q3)
            acc = 0.0
            for k in range(4):
                acc += row[y + 4 * i + k] * row[f + 4 * j + k]
            noise = 0.25 * (row[t + 3 * i] * xi0 * row[t + 3 * j]
                            + row[t + 3 * i + 1] * xi1 * row[t + 3 * j + 1]
                            + row[t + 3 * i + 2] * xi2 * row[t + 3 * j + 2])
            acc += noise + along * qi * qj
            row[p0 + 7 * i + j] = acc
            row[p0 + 7 * j + i] = acc
    for i in range(4):  # P_qb = Φ_Q M
        for j in range(3):
            acc = 0.0
            for k in range(4):
                acc += row[f + 4 * i + k] * row[m + 3 * k + j]
            row[p0 + 7 * i + 4 + j] = acc
            row[p0 + 7 * (4 + j) + i] = acc
    row[p0 + 32] += walk0  # Ξ_B: bias random walk
    row[p0 + 40] += walk1
    row[p0 + 48] += walk2
    return qw, qx, qy, qz


@njit(cache=True, inline="always")
def _quadratic(p00, p01, p02, p03, p11, p12, p13, p22, p23, p33, a0, a1, a2, a3):
    """``aᵀ P a`` of a symmetric 4 x 4 ``P`` from its upper triangle."""
    return (p00 * a0 * a0 + p11 * a1 * a1 + p22 * a2 * a2 + p33 * a3 * a3
            + 2.0 * (a0 * (p01 * a1 + p02 * a2 + p03 * a3) + a1 * (p12 * a2 + p13 * a3)
                     + p23 * a2 * a3))


@njit(cache=True, inline="always")
def tilt_variance(row, p0, qw, qx, qy, qz, vw, vx, vy, vz):
    """``½ (tr P_θ - ẑᵀ P_θ ẑ)``, the state's tilt variance per axis normal to ``ẑ``, rad².

    ``P_θ = 4 Q̃ᵀ P_qq Q̃`` the body angle covariance, ``v = Q̃ ẑ`` (``ẑ`` unit body up);
    computed as ``2 (tr P_qq - qᵀ P_qq q - vᵀ P_qq v)`` (``Q̃ Q̃ᵀ = I - qqᵀ``), from
    ``P_qq``'s upper triangle.
    """
    p00, p01, p02, p03 = row[p0], row[p0 + 1], row[p0 + 2], row[p0 + 3]
    p11, p12, p13 = row[p0 + 8], row[p0 + 9], row[p0 + 10]
    p22, p23, p33 = row[p0 + 16], row[p0 + 17], row[p0 + 24]
    qpq = _quadratic(p00, p01, p02, p03, p11, p12, p13, p22, p23, p33, qw, qx, qy, qz)
    vpv = _quadratic(p00, p01, p02, p03, p11, p12, p13, p22, p23, p33, vw, vx, vy, vz)
    return 2.0 * (p00 + p11 + p22 + p33 - qpq - vpv)


@njit(cache=True, inline="always")
def body_direction(qw, qx, qy, qz, ax, ay, az):
    """``Q̃ a = q ⊗ (0, a)``: the quaternion direction of body axis ``a`` (003 eq. 24)."""
    return (
        -qx * ax - qy * ay - qz * az,
        qw * ax - qz * ay + qy * az,
        qz * ax + qw * ay - qx * az,
        -qy * ax + qx * ay + qw * az,
    )


@njit(cache=True, inline="always")
def tilt_d2(row, p0, qw, qx, qy, qz, mw, mx, my, mz, zx, zy, zz, var_g):
    """Squared normalised tilt innovation (2 dof) of the measurement ``m`` against ``q⁻``.

    Innovation angle ``θ = 2 vec(q⁻* ⊗ m)`` (body frame), its part normal to the unit
    predicted up ``ẑ`` against ``½ (tr P_θ - ẑᵀ P_θ ẑ) + σ_G²`` per axis
    (:func:`tilt_variance`); ``var_g`` = σ_G² rad².
    """
    ex = qw * mx - qx * mw - qy * mz + qz * my  # vec(q* ⊗ m)
    ey = qw * my + qx * mz - qy * mw - qz * mx
    ez = qw * mz - qx * my + qy * mx - qz * mw
    tx, ty, tz = 2.0 * ex, 2.0 * ey, 2.0 * ez
    vw, vx, vy, vz = body_direction(qw, qx, qy, qz, zx, zy, zz)
    along = tx * zx + ty * zy + tz * zz
    normal2 = tx * tx + ty * ty + tz * tz - along * along
    return normal2 / (tilt_variance(row, p0, qw, qx, qy, qz, vw, vx, vy, vz) + var_g)


@njit(cache=True, inline="always")
def decoupled_noise(row, v0, qw, qx, qy, qz, vw, vx, vy, vz, var_g, var_h):
    """``V`` (4, 4) row-major at ``row[v0:]`` of the decoupled measurement (eq. 46).

    ``¼ Q̃ Ξθ Q̃ᵀ + qqᵀ`` for ``Ξθ = σ_G² (I - ẑẑᵀ) + σ_H² ẑẑᵀ``
    (``bias_kf_model.fill_decoupled_cov``), i.e. ``¼σ_G² (I - qqᵀ) + ¼(σ_H² - σ_G²) vvᵀ +
    qqᵀ`` with ``v = Q̃ ẑ``; unit variance along ``q`` (``fill_quat_noise``'s measurement
    choice). ``var_g``, ``var_h`` rad².
    """
    cg = 0.25 * var_g
    cv = 0.25 * (var_h - var_g)
    cq = 1.0 - cg
    for i in range(4):
        qi = _component(i, qw, qx, qy, qz)
        vi = _component(i, vw, vx, vy, vz)
        for j in range(i, 4):
            qj = _component(j, qw, qx, qy, qz)
            vj = _component(j, vw, vx, vy, vz)
            value = cq * qi * qj + cv * vi * vj + (cg if i == j else 0.0)
            row[v0 + 4 * i + j] = value
            row[v0 + 4 * j + i] = value


@njit(cache=True, inline="always")
def triad_noise(row, v0, qw, qx, qy, qz, zx, zy, zz, nx, ny, nz, var_g, var_n):
    """``V`` (4, 4) row-major at ``row[v0:]`` of the TRIAD quaternion measurement (eq. 46).

    ``¼ Q̃ Ξθ Q̃ᵀ + qqᵀ`` (unit ``q``; unit variance along it, as ``fill_quat_noise``
    gives the measurement) with eq. 45's angle covariance of the unit body up ``ẑ`` and
    field ``n̂`` (``bias_kf_model.fill_triad_cov``): ``Ξθ = σ_G² I + [(σ_N² - σ_G²) ẑẑᵀ
    + σ_G² (ẑ·n̂)(ẑn̂ᵀ + n̂ẑᵀ)] / |ẑ × n̂|²``. With ``v = Q̃ ẑ``, ``u = Q̃ n̂`` and
    ``Q̃ Q̃ᵀ = I - qqᵀ``: ``V = (1 - ¼σ_G²) qqᵀ + ¼σ_G² I + a vvᵀ + b (vuᵀ + uvᵀ)``,
    ``a = ¼(σ_N² - σ_G²)/|ẑ × n̂|²``, ``b = ¼σ_G² (ẑ·n̂)/|ẑ × n̂|²``. ``var_g``,
    ``var_n`` = σ_G², σ_N² rad².
    """
    cx, cy, cz = zy * nz - zz * ny, zz * nx - zx * nz, zx * ny - zy * nx
    inv = 1.0 / (cx * cx + cy * cy + cz * cz)
    cg = 0.25 * var_g
    ca = 0.25 * (var_n - var_g) * inv
    cb = cg * (zx * nx + zy * ny + zz * nz) * inv
    cq = 1.0 - cg
    vw, vx, vy, vz = body_direction(qw, qx, qy, qz, zx, zy, zz)
    uw, ux, uy, uz = body_direction(qw, qx, qy, qz, nx, ny, nz)
    for i in range(4):
        qi = _component(i, qw, qx, qy, qz)
        vi = _component(i, vw, vx, vy, vz)
        ui = _component(i, uw, ux, uy, uz)
        for j in range(i, 4):
            qj = _component(j, qw, qx, qy, qz)
            vj = _component(j, vw, vx, vy, vz)
            uj = _component(j, uw, ux, uy, uz)
            value = (cq * qi * qj + ca * vi * vj + cb * (vi * uj + ui * vj)
                     + (cg if i == j else 0.0))
            row[v0 + 4 * i + j] = value
            row[v0 + 4 * j + i] = value


@njit(cache=True, inline="always")
def kalman_update(row, p0, s0, v0, n0, n1, n2, n3):
    """Update with ``H = [I₄ 0]`` (003 eqs. 49-51): ``P`` in place, ``K ν`` at ``F_DX``.

    ``V`` (4, 4) row-major at ``row[v0:]`` (symmetric), innovation ``ν = (n0..n3)``.
    With ``S = P_qq + V = L D Lᵀ`` (``L`` unit lower triangular: no square roots on the
    dependency chain) and ``U = P_·q = P Hᵀ`` (7, 4), the gain is ``K = U S⁻¹ = W D⁻¹ L⁻¹``
    with ``W = U L⁻ᵀ`` (eq. 49), so ``dx = K ν = W D⁻¹ (L⁻¹ ν)`` (eq. 50) and
    ``P - K S Kᵀ = P - W D⁻¹ Wᵀ`` (eq. 51; its Joseph form has the same value for this
    gain): one triangle, mirrored, so ``P`` stays exactly symmetric. Returns False (``P``
    unchanged, ``dx`` not written) if ``S`` is not positive definite.
    """
    lo = s0 + F_L
    inv = s0 + F_ID
    for r in range(4):  # S = P_qq + V = L D Lᵀ
        for c in range(r):
            acc = row[p0 + 7 * r + c] + row[v0 + 4 * r + c]
            for k in range(c):
                acc -= row[lo + 4 * r + k] * row[lo + 4 * c + k] * row[lo + 5 * k]
            row[lo + 4 * r + c] = acc * row[inv + c]
        d = row[p0 + 8 * r] + row[v0 + 5 * r]
        for k in range(r):
            d -= row[lo + 4 * r + k] * row[lo + 4 * r + k] * row[lo + 5 * k]
        if not d > 0.0:
            return False
        row[lo + 5 * r] = d  # D on L's diagonal (L's own is 1)
        row[inv + r] = 1.0 / d
    z = s0 + F_Z  # L z = ν (L unit lower)
    for k in range(4):
        acc = _component(k, n0, n1, n2, n3)
        for j in range(k):
            acc -= row[lo + 4 * k + j] * row[z + j]
        row[z + k] = acc
    w = s0 + F_W
    wd = s0 + F_WD
    dx = s0 + F_DX
    for r in range(7):  # row r of W: L w = U_r; dx_r = (W D⁻¹)_r · z
        acc_dx = 0.0
        for k in range(4):
            acc = row[p0 + 7 * r + k]
            for j in range(k):
                acc -= row[lo + 4 * k + j] * row[w + 4 * r + j]
            row[w + 4 * r + k] = acc
            scaled = acc * row[inv + k]
            row[wd + 4 * r + k] = scaled
            acc_dx += scaled * row[z + k]
        row[dx + r] = acc_dx
    for i in range(7):  # P - W D⁻¹ Wᵀ, upper triangle, mirrored
        for j in range(i, 7):
            acc = row[p0 + 7 * i + j]
            for k in range(4):
                acc -= row[wd + 4 * i + k] * row[w + 4 * j + k]
            row[p0 + 7 * i + j] = acc
            row[p0 + 7 * j + i] = acc
    return True
