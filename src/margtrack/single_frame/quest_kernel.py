"""Kernel of QUEST, Shuster & Oh's quaternion estimator (as described in 002, eqs. 9-10, 42).

For the two pairs (â ↔ up, m̂ ↔ reference field) with weights a_i, with
``B = Σ a_i r_i b_iᵀ``, ``σ = tr B``, ``S = B + Bᵀ``, ``z = Σ a_i b_i × r_i``,
``κ = tr adj S`` and ``Δ = det S`` (Shuster & Oh 1981):

- λ_max, the largest eigenvalue of Davenport's K, is exact for two observations:
  ``λ² = a1² + a2² + 2 a1 a2 cos(θ_r - θ_b)`` with ``cos(θ_r - θ_b) = (r1·r2)(b1·b2) +
  |r1 × r2| |b1 × b2|`` (no Newton iteration on the characteristic equation is needed);
  the paper's QUEST instead finds λ by Newton-Raphson on the characteristic equation
  ``λ⁴ - (a + b) λ² - c λ + (a b + c σ - d) = 0`` from ``λ₀ = a1 + a2``, with
  ``a = σ² - κ``, ``b = σ² + zᵀz``, ``c = Δ + zᵀ S z``, ``d = zᵀ S² z`` (Shuster & Oh
  1981, eq. 71; 002 cites it for its speed comparison): :func:`newton_eigenvalue`;
- ``α = λ² - σ² + κ``, ``β = λ - σ``, ``γ = (λ + σ) α - Δ``, ``X = (α I + β S + S²) z``;
  the optimal quaternion is ``[γ, X] / |[γ, X]|`` (scalar first; Shuster's ``[X, γ]``).

``[γ, X]`` is the scalar column of ``adj(λ I - K) = f'(λ) q qᵀ`` (f the characteristic
polynomial), so ``γ = f'(λ) q_w²``: near a rotation of 180 deg (q_w → 0, the Gibbs-vector
singularity of 002 eq. 42) it vanishes and the direction of [γ, X] is lost to rounding.
The method of sequential rotations (Shuster & Natanson, cited by 002) then solves the
problem with the reference vectors turned by 180 deg about the earth axis e_i whose
rotated problem has the largest ``γ_i = f'(λ) q_i²``, and turns the answer back:
``q = e_i* ⊗ q'``.
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator.jit import njit
from margtrack.estimator.lowpass import prefilter_sensor
from margtrack.estimator.quat_kernel import cross
from margtrack.estimator.triad_kernel import FASTMATH, OK, ZERO_ACC, level, unit_pair
from margtrack.single_frame.davenport_kernel import reference_field

#: Newton-Raphson on the characteristic equation stops when a step is below this
#: fraction of λ, or after NEWTON_MAX_STEPS steps.
NEWTON_TOLERANCE = 1e-13
NEWTON_MAX_STEPS = 10

#: Sequential rotation when q_w² = γ / f'(λ) falls below this (rotation angle above
#: 168.5 deg): there [γ, X] keeps at least 1/10 of its scale and 15 significant digits.
ROTATION_THRESHOLD = 0.01


@njit(cache=True, inline="always")
def adjugate_column(lam, b11, b12, b13, b21, b22, b23, b31, b32, b33):
    """Shuster & Oh's ``(γ, Xx, Xy, Xz)`` for attitude profile B at eigenvalue λ."""
    sigma = b11 + b22 + b33
    s11, s22, s33 = 2.0 * b11, 2.0 * b22, 2.0 * b33
    s12, s13, s23 = b12 + b21, b13 + b31, b23 + b32
    zx, zy, zz = b32 - b23, b13 - b31, b21 - b12
    # cofactors of S: κ = tr adj S, Δ = det S
    c11 = s22 * s33 - s23 * s23
    c22 = s11 * s33 - s13 * s13
    c33 = s11 * s22 - s12 * s12
    kappa = c11 + c22 + c33
    delta = s11 * c11 - s12 * (s12 * s33 - s13 * s23) + s13 * (s12 * s23 - s13 * s22)
    # S z and S² z
    szx = s11 * zx + s12 * zy + s13 * zz
    szy = s12 * zx + s22 * zy + s23 * zz
    szz = s13 * zx + s23 * zy + s33 * zz
    s2zx = s11 * szx + s12 * szy + s13 * szz
    s2zy = s12 * szx + s22 * szy + s23 * szz
    s2zz = s13 * szx + s23 * szy + s33 * szz
    alpha = lam * lam - sigma * sigma + kappa
    beta = lam - sigma
    gamma = (lam + sigma) * alpha - delta
    xx = alpha * zx + beta * szx + s2zx
    xy = alpha * zy + beta * szy + s2zy
    xz = alpha * zz + beta * szz + s2zz
    return gamma, xx, xy, xz


@njit(cache=True, inline="always")
def newton_eigenvalue(lam0, b11, b12, b13, b21, b22, b23, b31, b32, b33):
    """λ_max of Davenport's K by Newton-Raphson on Shuster & Oh's characteristic
    equation from ``lam0`` (the sum of the weights): ``(λ, f'(λ))``."""
    sigma = b11 + b22 + b33
    s11, s22, s33 = 2.0 * b11, 2.0 * b22, 2.0 * b33
    s12, s13, s23 = b12 + b21, b13 + b31, b23 + b32
    zx, zy, zz = b32 - b23, b13 - b31, b21 - b12
    c11 = s22 * s33 - s23 * s23
    c22 = s11 * s33 - s13 * s13
    c33 = s11 * s22 - s12 * s12
    kappa = c11 + c22 + c33
    delta = s11 * c11 - s12 * (s12 * s33 - s13 * s23) + s13 * (s12 * s23 - s13 * s22)
    szx = s11 * zx + s12 * zy + s13 * zz
    szy = s12 * zx + s22 * zy + s23 * zz
    szz = s13 * zx + s23 * zy + s33 * zz
    a = sigma * sigma - kappa
    b = sigma * sigma + zx * zx + zy * zy + zz * zz
    c = delta + zx * szx + zy * szy + zz * szz
    d = szx * szx + szy * szy + szz * szz
    constant = a * b + c * sigma - d
    lam = lam0
    slope = 0.0
    for _ in range(NEWTON_MAX_STEPS):
        lam2 = lam * lam
        value = (lam2 - a - b) * lam2 - c * lam + constant
        slope = 4.0 * lam2 * lam - 2.0 * (a + b) * lam - c
        if slope == 0.0:
            break
        step = value / slope
        lam -= step
        if abs(step) <= NEWTON_TOLERANCE * lam0:
            break
    return lam, slope


@njit(cache=True, inline="always")
def quest_unit(a1, ux, uy, uz, ax, ay, az, a2, hx, hy, hz, mx, my, mz, ref_cos, ref_sin,
               newton):
    """QUEST quaternion (w >= 0) of two checked unit pairs: (axis, w, x, y, z).

    a1, a2 weights; u (up) and h (field) unit earth references with ``ref_cos = u·h`` and
    ``ref_sin = |u × h|``; â, m̂ unit body vectors; ``newton``: λ_max by Newton-Raphson on
    the characteristic equation (the paper's QUEST) instead of in closed form. ``axis`` is
    0 when no sequential rotation was needed, else 1, 2, 3 for x, y, z.
    """
    # B = a1 u âᵀ + a2 h m̂ᵀ (earth rows, body columns)
    au, ah = a1 * ux, a2 * hx
    b11, b12, b13 = au * ax + ah * mx, au * ay + ah * my, au * az + ah * mz
    au, ah = a1 * uy, a2 * hy
    b21, b22, b23 = au * ax + ah * mx, au * ay + ah * my, au * az + ah * mz
    au, ah = a1 * uz, a2 * hz
    b31, b32, b33 = au * ax + ah * mx, au * ay + ah * my, au * az + ah * mz
    if newton:
        lam, slope = newton_eigenvalue(a1 + a2, b11, b12, b13, b21, b22, b23, b31, b32, b33)
    else:
        # λ_max for two observations (Shuster & Oh)
        dx, dy, dz = cross(ax, ay, az, mx, my, mz)
        sines = ref_sin * math.sqrt(dx * dx + dy * dy + dz * dz)
        cos_diff = ref_cos * (ax * mx + ay * my + az * mz) + sines
        lam = math.sqrt(max(0.0, a1 * a1 + a2 * a2 + 2.0 * a1 * a2 * cos_diff))
        # f'(λ) = Π (λ - λ_j) over the other eigenvalues -λ, ±λ₋ of K, with
        # λ² - λ₋² = 4 a1 a2 |r1 × r2| |b1 × b2| (λ₋: the same formula with θ_r + θ_b)
        slope = 8.0 * lam * a1 * a2 * sines
    g, xx, xy, xz = adjugate_column(lam, b11, b12, b13, b21, b22, b23, b31, b32, b33)
    axis = 0
    if g < ROTATION_THRESHOLD * slope:
        # sequential rotation: references turned by 180 deg about earth axis i negate the
        # other two rows of B; the rotated problem's γ_i = f'(λ) q_i², so pick the largest
        g1, x1, y1, z1 = adjugate_column(lam, b11, b12, b13, -b21, -b22, -b23, -b31, -b32, -b33)
        g2, x2, y2, z2 = adjugate_column(lam, -b11, -b12, -b13, b21, b22, b23, -b31, -b32, -b33)
        g3, x3, y3, z3 = adjugate_column(lam, -b11, -b12, -b13, -b21, -b22, -b23, b31, b32, b33)
        if g1 >= g2 and g1 >= g3:
            axis = 1
            # q = e_x* ⊗ q' = -(i ⊗ q'), sign dropped: i ⊗ (w, x, y, z) = (-x, w, -z, y)
            g, xx, xy, xz = -x1, g1, -z1, y1
        elif g2 >= g3:
            axis = 2
            # j ⊗ (w, x, y, z) = (-y, z, w, -x)
            g, xx, xy, xz = -y2, z2, g2, -x2
        else:
            axis = 3
            # k ⊗ (w, x, y, z) = (-z, -y, x, w)
            g, xx, xy, xz = -z3, -y3, x3, g3
    inv = math.copysign(1.0, g) / math.sqrt(g * g + xx * xx + xy * xy + xz * xz)
    return axis, g * inv, xx * inv, xy * inv, xz * inv


@njit(cache=True, fastmath=FASTMATH)
def _quest_sensor(acc, mag, ux, uy, uz, hx, hy, hz, ref_cos, ref_sin, a1, a2, newton,
                  quat_state, quat_out, flags, rotation_out):
    """QUEST over one sensor's (N, 3) series; quat_state (4,) in/out.

    A zero accelerometer holds the previous orientation; a zero or parallel field levels
    it onto the measured gravity (``triad.level``), heading kept.
    """
    pw, px, py, pz = quat_state[0], quat_state[1], quat_state[2], quat_state[3]
    for i in range(acc.shape[0]):
        flag, ax, ay, az, mx, my, mz = unit_pair(
            acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2]
        )
        flags[i] = flag
        axis = 0
        if flag == OK:
            axis, pw, px, py, pz = quest_unit(
                a1, ux, uy, uz, ax, ay, az, a2, hx, hy, hz, mx, my, mz, ref_cos, ref_sin,
                newton,
            )
        elif flag != ZERO_ACC:
            pw, px, py, pz = level(pw, px, py, pz, ax, ay, az, ux, uy, uz)
        rotation_out[i] = axis
        quat_out[i, 0], quat_out[i, 1], quat_out[i, 2], quat_out[i, 3] = pw, px, py, pz
    quat_state[0], quat_state[1], quat_state[2], quat_state[3] = pw, px, py, pz


@njit(cache=True)
def quest_run(
    acc, mag, dt, up, north, dip_rad, acc_weight, mag_weight, newton_eigenvalue_on,
    acc_cutoff_hz, mag_cutoff_hz, order,
    quat_state, dip_state, lowpass_history, lowpass_ready, quat_out, flags, rotation_out,
):
    """QUEST for S sensors and N samples, with the optional low-pass prefilter.

    acc, mag (S, N, 3) any units; dt (N,) s; up, north (3,) unit earth vectors; dip_rad:
    reference dip (positive down) or NaN to measure it from each sensor's first valid
    sample (kept in dip_state (S,)); acc_weight, mag_weight: a_i; newton_eigenvalue_on:
    λ_max by Newton-Raphson (the paper's QUEST) rather than in closed form; prefilter cut-offs
    (0 = off) and order; quat_state (S, 4), lowpass_history (S, 2, 4, 3), lowpass_ready
    (S, 2): state, in/out. Fills quat_out (S, N, 4) (w >= 0), flags (S, N) int8 (see
    ``unit_pair``) and rotation_out (S, N) int8 (sequential rotation axis, 0 = none).
    A zero accelerometer repeats the previous orientation; a zero or parallel field levels
    it (inclination from the accelerometer, heading kept).
    """
    ux, uy, uz = up[0], up[1], up[2]
    nx, ny, nz = north[0], north[1], north[2]
    filtering = acc_cutoff_hz > 0.0 or mag_cutoff_hz > 0.0
    n = acc.shape[1] if filtering else 0
    acc_f, mag_f = np.empty((n, 3)), np.empty((n, 3))
    for s in range(acc.shape[0]):
        if filtering:
            prefilter_sensor(acc[s], mag[s], dt, acc_cutoff_hz, mag_cutoff_hz, order,
                             lowpass_history[s], lowpass_ready[s], acc_f, mag_f)
            hx, hy, hz, sin_dip, cos_dip = reference_field(
                acc_f, mag_f, dip_rad, dip_state[s:s + 1], ux, uy, uz, nx, ny, nz)
            # u·h = -sin(dip) and |u × h| = cos(dip) for the unit references
            _quest_sensor(acc_f, mag_f, ux, uy, uz, hx, hy, hz, -sin_dip, cos_dip,
                          acc_weight, mag_weight, newton_eigenvalue_on, quat_state[s],
                          quat_out[s], flags[s], rotation_out[s])
        else:
            lowpass_ready[s, 0] = lowpass_ready[s, 1] = False
            hx, hy, hz, sin_dip, cos_dip = reference_field(
                acc[s], mag[s], dip_rad, dip_state[s:s + 1], ux, uy, uz, nx, ny, nz)
            _quest_sensor(acc[s], mag[s], ux, uy, uz, hx, hy, hz, -sin_dip, cos_dip,
                          acc_weight, mag_weight, newton_eigenvalue_on, quat_state[s],
                          quat_out[s], flags[s], rotation_out[s])
