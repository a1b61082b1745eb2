"""Kernel of the Gauss-Newton and Newton quaternion fits (001 section 4.2, eqs. 20-26).

The error is taken in the earth frame (001 eq. 20): with the measured unit vectors
y0 = [ĝ; m̂] (body) and the known references y1 = [u; h] (earth),
``ε(n) = y1 - M(n) y0``, ``M = diag(R, R)`` (eq. 21), R of eq. 6 for the 4-vector n (not
constrained to unit norm: ``R(n) v = n ⊗ v ⊗ n*``, which is |n|² times a rotation), and
the criterion ``Q = εᵀε`` (eq. 20). The magnetic rows are multiplied by the weight ρ
(000 eq. 17), so ``Q = |ε_g|² + ρ² |ε_m|²``; for unit vectors its minimum, normalised, is
Wahba's solution with weights (1, ρ²), i.e. Davenport's.

- Gauss-Newton (eq. 22): ``n ← n - (JᵀJ)⁻¹ Jᵀ ε`` with ``J = -∂(M y0)/∂n`` (eq. 23).
  Since ``∂(n ⊗ v ⊗ n*)/∂n_k = 2 vec(e_k ⊗ v ⊗ n*)``, J's columns come from one product
  ``p = v ⊗ n*`` per vector.
- Newton (eq. 24): ``n ← n - H⁻¹ ∇Q`` with ``∇Q = 2 Jᵀ ε`` (eq. 25) and the Hessian
  ``H = 2 (JᵀJ - Σ_j ε_j ∂²(M y0)_j/∂n²) = 2 (JᵀJ - 2 K(y0, ε))``, where K(y0, ε) is
  Davenport's matrix of the pairs (y0_i, ε_i) (the quadratic form ``⟨ε, n ⊗ v ⊗ n*⟩ =
  nᵀ K n`` has Hessian 2K). 001's eq. 26 as printed reads ``[∂²M y0] ε - (∂M y0)ᵀ(∂M y0)``,
  which is ``-H/2``: used literally in eq. 24 it would step uphill with twice the length
  (a sign and factor slip; tests/estimators check H against finite differences).

:func:`gauss_newton_solve`, :func:`newton_solve` and :func:`gauss_newton_step` are plain
numba functions over scalars, callable from other kernels (the EKF of 001 uses the
Gauss-Newton quaternion as its measurement).
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator.jit import njit
from margtrack.estimator.lowpass import prefilter_sensor
from margtrack.estimator.quat_kernel import mul
from margtrack.estimator.triad_kernel import (
    FASTMATH,
    OK,
    SOLVER_FAILED,
    ZERO_ACC,
    level,
    reference_triad,
    triad_unit,
    unit_pair,
)
from margtrack.single_frame.davenport_kernel import profile, reference_field

#: When tracking, the previous estimate is the initial guess only if it lies within this
#: angle of the sample's TRIAD orientation (cos of half of 30 deg); otherwise TRIAD is:
#: far from the minimum the iterations are slow (Gauss-Newton) or can stop at a saddle
#: point of Q (Newton), e.g. after a jump in heading.
RESTART_COS_HALF_ANGLE = 0.9659258262890683

#: Rounding level of Q relative to sqrt(Q) (Q sums squares of residuals that carry
#: absolute rounding errors of a few 1e-16): a change below it is no progress, so a
#: tolerance below rounding cannot spin to the iteration cap.
PROGRESS_FLOOR = 1e-14

#: Halvings of an update that would increase the criterion before giving up on it
MAX_HALVINGS = 8

#: The 4 x 4 normal equations count as singular (the iteration stops and the sample is
#: flagged) when the product of their two smallest eigenvalues is below this fraction of
#: the largest's square (Gauss-Newton, :func:`_gauss_newton_delta`), or a pivot of their
#: LDLᵀ below this fraction of their largest diagonal entry (Newton,
#: :func:`_solve_symmetric`).
PIVOT_TOLERANCE = 1e-12


@njit(cache=True, inline="always")
def _pair_terms(vx, vy, vz, rx, ry, rz, w, x, y, z):
    """Residual ε = r - R(n) v and p = v ⊗ n* (J's columns are -2 vec(e_k ⊗ p))."""
    p0, p1, p2, p3 = mul(0.0, vx, vy, vz, w, -x, -y, -z)
    _, fx, fy, fz = mul(w, x, y, z, p0, p1, p2, p3)
    return rx - fx, ry - fy, rz - fz, p0, p1, p2, p3


@njit(cache=True, inline="always")
def _normal_terms(weight, ex, ey, ez, p0, p1, p2, p3):
    """weight·(JᵀJ, Jᵀε) of one vector pair: 10 upper-triangle entries of JᵀJ, then Jᵀε."""
    # columns of J = -∂f/∂n (001 eq. 23): -2 vec(e_k ⊗ p) for k = w, x, y, z
    jw0, jw1, jw2 = -2.0 * p1, -2.0 * p2, -2.0 * p3
    jx0, jx1, jx2 = -2.0 * p0, 2.0 * p3, -2.0 * p2
    jy0, jy1, jy2 = -2.0 * p3, -2.0 * p0, 2.0 * p1
    jz0, jz1, jz2 = 2.0 * p2, -2.0 * p1, -2.0 * p0
    return (
        weight * (jw0 * jw0 + jw1 * jw1 + jw2 * jw2),
        weight * (jw0 * jx0 + jw1 * jx1 + jw2 * jx2),
        weight * (jw0 * jy0 + jw1 * jy1 + jw2 * jy2),
        weight * (jw0 * jz0 + jw1 * jz1 + jw2 * jz2),
        weight * (jx0 * jx0 + jx1 * jx1 + jx2 * jx2),
        weight * (jx0 * jy0 + jx1 * jy1 + jx2 * jy2),
        weight * (jx0 * jz0 + jx1 * jz1 + jx2 * jz2),
        weight * (jy0 * jy0 + jy1 * jy1 + jy2 * jy2),
        weight * (jy0 * jz0 + jy1 * jz1 + jy2 * jz2),
        weight * (jz0 * jz0 + jz1 * jz1 + jz2 * jz2),
        weight * (jw0 * ex + jw1 * ey + jw2 * ez),
        weight * (jx0 * ex + jx1 * ey + jx2 * ez),
        weight * (jy0 * ex + jy1 * ey + jy2 * ez),
        weight * (jz0 * ex + jz1 * ey + jz2 * ez),
    )


@njit(cache=True, inline="always")
def _gauss_newton_delta(rho2, eg, em):
    """The Gauss-Newton update ``Δ = -(JᵀJ)⁻¹ Jᵀε`` (001 eq. 22) from the two pairs'
    :func:`_pair_terms` ``eg``, ``em`` (ρ² the field's weight): (ok, Δw, Δx, Δy, Δz).

    The normal equations have a structure that is solved in closed form, without forming
    them. With ``p = v ⊗ n*`` of a pair, J's columns are ``-2 vec(e_k ⊗ p)``; the full
    products ``e_k ⊗ p`` are the columns of |p| times an orthogonal matrix, so dropping
    their scalar parts ``u = (p₀, -p₁, -p₂, -p₃)`` leaves ``JᵀJ = 4 (|p|² I - u uᵀ)``; and
    ``Jᵀε = -2 ((0, ε) ⊗ p*)``. Summed over the pairs (u for gravity, v for the field):
    ``JᵀJ = 4 (c I - U Uᵀ)`` with ``U = [u, ρ v]``, ``c = |u|² + ρ²|v|²``, and
    ``Δ = ½ (c I - U Uᵀ)⁻¹ s`` with ``s = (0, ε_g) ⊗ p_g* + ρ² (0, ε_m) ⊗ p_m*``, which
    Woodbury's identity gives as ``(s + U (c I₂ - UᵀU)⁻¹ Uᵀ s) / (2c)``; the 2 x 2 matrix
    has the determinant ``ρ² D``, ``D = |u|²|v|² - (u·v)²`` (Lagrange's identity, without
    cancellation). About 90 operations and two divisions where forming and factoring
    the equations took 200 and four; the same update to rounding (tests compare them).
    The equations' eigenvalues are 4c (twice) and 4λ with ``λ₁ + λ₂ = c``,
    ``λ₁ λ₂ = ρ² D``: singular (``ok`` False) when ``ρ² D <= PIVOT_TOLERANCE c²`` (the
    smallest eigenvalue then at most twice that fraction of the largest): the two body
    vectors parallel, or ρ = 0.
    """
    _, _, _, u0, p1, p2, p3 = eg
    u1, u2, u3 = -p1, -p2, -p3
    _, _, _, v0, r1, r2, r3 = em
    v1, v2, v3 = -r1, -r2, -r3
    a = mul(0.0, eg[0], eg[1], eg[2], u0, u1, u2, u3)
    b = mul(0.0, em[0], em[1], em[2], v0, v1, v2, v3)
    s0, s1 = a[0] + rho2 * b[0], a[1] + rho2 * b[1]
    s2, s3 = a[2] + rho2 * b[2], a[3] + rho2 * b[3]
    uu = u0 * u0 + u1 * u1 + u2 * u2 + u3 * u3
    vv = v0 * v0 + v1 * v1 + v2 * v2 + v3 * v3
    uv = u0 * v0 + u1 * v1 + u2 * v2 + u3 * v3
    c = uu + rho2 * vv
    e01, e02, e03 = u0 * v1 - u1 * v0, u0 * v2 - u2 * v0, u0 * v3 - u3 * v0
    e12, e13, e23 = u1 * v2 - u2 * v1, u1 * v3 - u3 * v1, u2 * v3 - u3 * v2
    d = e01 * e01 + e02 * e02 + e03 * e03 + e12 * e12 + e13 * e13 + e23 * e23
    if not (rho2 * d > PIVOT_TOLERANCE * c * c):
        return False, 0.0, 0.0, 0.0, 0.0
    tu = u0 * s0 + u1 * s1 + u2 * s2 + u3 * s3
    tv = v0 * s0 + v1 * s1 + v2 * s2 + v3 * s3
    inv = 1.0 / (rho2 * d)
    zu = (uu * tu + rho2 * uv * tv) * inv
    zv = (rho2 * vv * tv + uv * tu) * (rho2 * inv)
    k = 0.5 / c
    return (True, k * (s0 + u0 * zu + v0 * zv), k * (s1 + u1 * zu + v1 * zv),
            k * (s2 + u2 * zu + v2 * zv), k * (s3 + u3 * zu + v3 * zv))


@njit(cache=True, inline="always")
def _solve_symmetric(a00, a01, a02, a03, a11, a12, a13, a22, a23, a33, b0, b1, b2, b3):
    """Solve the symmetric 4 x 4 system A x = b by LDLᵀ (no pivoting): (ok, x0..x3).

    ``ok`` is False when a pivot is below PIVOT_TOLERANCE times the largest |a_ii|.
    """
    scale = max(max(abs(a00), abs(a11)), max(abs(a22), abs(a33)))
    tiny = PIVOT_TOLERANCE * scale
    d0 = a00
    if not abs(d0) > tiny:
        return False, 0.0, 0.0, 0.0, 0.0
    r0 = 1.0 / d0  # each pivot's reciprocal: 4 divisions, not 10
    l10, l20, l30 = a01 * r0, a02 * r0, a03 * r0
    d1 = a11 - l10 * l10 * d0
    if not abs(d1) > tiny:
        return False, 0.0, 0.0, 0.0, 0.0
    r1 = 1.0 / d1
    l21 = (a12 - l20 * l10 * d0) * r1
    l31 = (a13 - l30 * l10 * d0) * r1
    d2 = a22 - l20 * l20 * d0 - l21 * l21 * d1
    if not abs(d2) > tiny:
        return False, 0.0, 0.0, 0.0, 0.0
    r2 = 1.0 / d2
    l32 = (a23 - l30 * l20 * d0 - l31 * l21 * d1) * r2
    d3 = a33 - l30 * l30 * d0 - l31 * l31 * d1 - l32 * l32 * d2
    if not abs(d3) > tiny:
        return False, 0.0, 0.0, 0.0, 0.0
    y0 = b0
    y1 = b1 - l10 * y0
    y2 = b2 - l20 * y0 - l21 * y1
    y3 = b3 - l30 * y0 - l31 * y1 - l32 * y2
    x3 = y3 / d3
    x2 = y2 * r2 - l32 * x3
    x1 = y1 * r1 - l21 * x2 - l31 * x3
    x0 = y0 * r0 - l10 * x1 - l20 * x2 - l30 * x3
    return True, x0, x1, x2, x3


@njit(cache=True)
def criterion(gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, mag_weight):
    """The criterion Q = |ε_g|² + ρ²|ε_m|² (001 eq. 20) at n = (w, x, y, z); for kernels."""
    egx, egy, egz, _, _, _, _ = _pair_terms(gx, gy, gz, ux, uy, uz, w, x, y, z)
    emx, emy, emz, _, _, _, _ = _pair_terms(mx, my, mz, hx, hy, hz, w, x, y, z)
    rho2 = mag_weight * mag_weight
    return egx * egx + egy * egy + egz * egz + rho2 * (emx * emx + emy * emy + emz * emz)


@njit(cache=True, fastmath=FASTMATH)
def _step(newton, gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, rho):
    """One Gauss-Newton (001 eq. 22) or Newton (eq. 24) update of n = (w, x, y, z).

    Returns ``(ok, w, x, y, z, Q)`` with Q = εᵀε at the input n (001 eq. 20).
    """
    rho2 = rho * rho
    egx, egy, egz, p0, p1, p2, p3 = _pair_terms(gx, gy, gz, ux, uy, uz, w, x, y, z)
    emx, emy, emz, r0, r1, r2, r3 = _pair_terms(mx, my, mz, hx, hy, hz, w, x, y, z)
    q = egx * egx + egy * egy + egz * egz + rho2 * (emx * emx + emy * emy + emz * emz)
    if not newton:
        ok, d0, d1, d2, d3 = _gauss_newton_delta(rho2, (egx, egy, egz, p0, p1, p2, p3),
                                                 (emx, emy, emz, r0, r1, r2, r3))
        return ok, w + d0, x + d1, y + d2, z + d3, q
    g = _normal_terms(1.0, egx, egy, egz, p0, p1, p2, p3)
    h = _normal_terms(rho2, emx, emy, emz, r0, r1, r2, r3)
    # H/2 = JᵀJ - 2 K(y0, ε): K of the pairs (ε_i earth-side, y0_i body-side)
    k00, k01, k02, k03, k11, k12, k13, k22, k23, k33 = profile(
        1.0, egx, egy, egz, gx, gy, gz, rho2, emx, emy, emz, mx, my, mz
    )
    ok, d0, d1, d2, d3 = _solve_symmetric(
        g[0] + h[0] - 2.0 * k00, g[1] + h[1] - 2.0 * k01, g[2] + h[2] - 2.0 * k02,
        g[3] + h[3] - 2.0 * k03, g[4] + h[4] - 2.0 * k11, g[5] + h[5] - 2.0 * k12,
        g[6] + h[6] - 2.0 * k13, g[7] + h[7] - 2.0 * k22, g[8] + h[8] - 2.0 * k23,
        g[9] + h[9] - 2.0 * k33,
        -(g[10] + h[10]), -(g[11] + h[11]), -(g[12] + h[12]), -(g[13] + h[13]),
    )
    return ok, w + d0, x + d1, y + d2, z + d3, q


@njit(cache=True)
def gauss_newton_step(gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, mag_weight):
    """One Gauss-Newton update ``n ← n - (JᵀJ)⁻¹ Jᵀ ε`` (001 eq. 22), callable from kernels.

    Parameters: unit body accelerometer ĝ and magnetometer m̂ (6 floats), unit earth up u
    and field reference h (6), the current 4-vector n = (w, x, y, z) (any non-zero norm),
    and the magnetometer weight ρ. Returns ``(ok, w, x, y, z, Q)``: the updated
    (unnormalised) n and the criterion Q = |ε_g|² + ρ²|ε_m|² at the *input* n; ok is False
    when the normal equations are singular (n is then returned unchanged).
    """
    ok, w2, x2, y2, z2, q = _step(
        False, gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, mag_weight
    )
    if not ok:
        return False, w, x, y, z, q
    return True, w2, x2, y2, z2, q


@njit(cache=True, fastmath=FASTMATH)
def _solve(newton, gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, rho,
           tolerance, max_iterations):
    """Iterate updates from n until Q <= tolerance, |ΔQ| <= tolerance or the cap.

    Safeguard beyond 001: an update that would increase Q is halved (up to MAX_HALVINGS
    times) before it is taken. Where the full step decreases Q, which is always the case
    near the minimum, this is 001's iteration unchanged; it keeps ill-conditioned samples
    (acceleration nearly parallel to the field, inconsistent references) from diverging.
    """
    iterations = 0
    ok = True
    ok_step, nw, nx, ny, nz, q = _step(
        newton, gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, rho
    )
    if not math.isfinite(q):
        ok = False
    while ok and q > tolerance and iterations < max_iterations:
        if not ok_step:
            ok = False
            break
        floor = PROGRESS_FLOOR * math.sqrt(q)
        tw, tx, ty, tz = nw, nx, ny, nz
        accepted = False
        for _ in range(MAX_HALVINGS + 1):
            ok_t, pw, px, py, pz, qt = _step(
                newton, gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, tw, tx, ty, tz, rho
            )
            if math.isfinite(qt) and qt <= q + floor:
                accepted = True
                break
            tw, tx, ty, tz = 0.5 * (w + tw), 0.5 * (x + tx), 0.5 * (y + ty), 0.5 * (z + tz)
        if not accepted:
            break
        stalled = q - qt <= tolerance + floor
        w, x, y, z, q = tw, tx, ty, tz, qt
        ok_step, nw, nx, ny, nz = ok_t, pw, px, py, pz
        iterations += 1
        if stalled:
            break
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if not (ok and norm > 0.0):
        return False, w, x, y, z, iterations, q
    inv = math.copysign(1.0, w) / norm
    return True, w * inv, x * inv, y * inv, z * inv, iterations, q


@njit(cache=True)
def gauss_newton_solve(
    gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, mag_weight, tolerance,
    max_iterations,
):
    """Gauss-Newton quaternion fit (001 eqs. 20-23) from an initial guess; for other kernels.

    Parameters
    ----------
    gx, gy, gz, mx, my, mz : unit accelerometer (specific force, points up at rest) and
        unit magnetometer vectors in the body frame (check them with ``triad.unit_pair``).
    ux, uy, uz, hx, hy, hz : unit earth-frame up and reference field.
    w, x, y, z : initial guess (any non-zero norm; the previous estimate when tracking).
    mag_weight : ρ, multiplies the magnetic residual (000 eq. 17).
    tolerance : stop when the criterion Q, or its change over the last update, is at most
        this (dimensionless: unit vectors); a change at rounding level also stops.
    max_iterations : cap on the number of updates (0 evaluates Q at the guess only).

    Returns
    -------
    ``(ok, w, x, y, z, iterations, Q)``: the unit quaternion (w >= 0) of the last iterate,
    the number of updates applied, and the criterion Q = |ε_g|² + ρ²|ε_m|² at the last
    (unnormalised) iterate. ``ok`` is False if the normal equations became singular or
    the iterate non-finite; (w, x, y, z) is then the last iterate, unnormalised.
    """
    return _solve(False, gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z,
                  mag_weight, tolerance, max_iterations)


@njit(cache=True)
def newton_solve(
    gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, mag_weight, tolerance,
    max_iterations,
):
    """Newton quaternion fit (001 eqs. 24-26, Hessian corrected); same contract as
    :func:`gauss_newton_solve`. Newton follows the Hessian, which is indefinite far from
    the minimum, so from a poor guess it can stop at a saddle point of Q (another
    eigenvector of K); Gauss-Newton cannot (JᵀJ is positive definite)."""
    return _solve(True, gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z,
                  mag_weight, tolerance, max_iterations)


@njit(cache=True, fastmath=FASTMATH)
def _fit_sensor(acc, mag, ux, uy, uz, hx, hy, hz, triad_axes, mag_weight, tolerance,
                max_iterations, newton, quat_state, has_estimate, quat_out, flags,
                iterations_out, criterion_out):
    """Fits over one sensor's (N, 3) series; quat_state (4,), has_estimate (1,) in/out.

    A zero accelerometer holds the previous orientation; a zero or parallel field, or a
    failed fit, levels it onto the measured gravity (``triad.level``), heading kept.
    """
    s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z = triad_axes
    pw, px, py, pz = quat_state[0], quat_state[1], quat_state[2], quat_state[3]
    for i in range(acc.shape[0]):
        flag, ax, ay, az, mx, my, mz = unit_pair(
            acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2]
        )
        iterations = 0
        crit = math.nan
        if flag == OK:
            gw, gx, gy, gz = triad_unit(
                ax, ay, az, mx, my, mz, s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z
            )
            if has_estimate[0] and (
                abs(gw * pw + gx * px + gy * py + gz * pz) >= RESTART_COS_HALF_ANGLE
            ):
                gw, gx, gy, gz = pw, px, py, pz
            ok, w, x, y, z, iterations, crit = _solve(
                newton, ax, ay, az, mx, my, mz, ux, uy, uz, hx, hy, hz, gw, gx, gy, gz,
                mag_weight, tolerance, max_iterations,
            )
            if ok:
                pw, px, py, pz = w, x, y, z
                has_estimate[0] = True
            else:
                # the fit failed: as for a field without heading, keep the heading
                flag = SOLVER_FAILED
                pw, px, py, pz = level(pw, px, py, pz, ax, ay, az, ux, uy, uz)
        elif flag != ZERO_ACC:
            pw, px, py, pz = level(pw, px, py, pz, ax, ay, az, ux, uy, uz)
        flags[i] = flag
        iterations_out[i] = iterations
        criterion_out[i] = crit
        quat_out[i, 0], quat_out[i, 1], quat_out[i, 2], quat_out[i, 3] = pw, px, py, pz
    quat_state[0], quat_state[1], quat_state[2], quat_state[3] = pw, px, py, pz


@njit(cache=True)
def gauss_newton_run(
    acc, mag, dt, up, north, dip_rad, mag_weight, tolerance, max_iterations, newton,
    acc_cutoff_hz, mag_cutoff_hz, order,
    quat_state, has_estimate, dip_state, lowpass_history, lowpass_ready,
    quat_out, flags, iterations_out, criterion_out,
):
    """Gauss-Newton (``newton`` False) or Newton fits for S sensors and N samples.

    acc, mag (S, N, 3) any units; dt (N,) s; up, north (3,) unit earth vectors; dip_rad:
    reference dip or NaN to measure it from each sensor's first valid sample (kept in
    dip_state (S,)); mag_weight ρ, tolerance, max_iterations: see
    :func:`gauss_newton_solve`; prefilter cut-offs (0 = off) and order. Each sample starts
    from the previous estimate (quat_state), or from TRIAD of the sample where
    has_estimate (S,) is False or the previous estimate is more than 30 deg from TRIAD.
    State arrays are updated in place. Fills quat_out (S, N, 4) (w >= 0), flags (S, N)
    int8 (``unit_pair`` codes, 4 = singular equations), iterations_out (S, N) int32 and
    criterion_out (S, N) (NaN where flagged 1-3). A zero accelerometer repeats the
    previous orientation; a zero or parallel field, or singular equations, level it
    (inclination from the accelerometer, heading kept).
    """
    ux, uy, uz = up[0], up[1], up[2]
    nx, ny, nz = north[0], north[1], north[2]
    axes = reference_triad(ux, uy, uz, nx, ny, nz)
    filtering = acc_cutoff_hz > 0.0 or mag_cutoff_hz > 0.0
    n = acc.shape[1] if filtering else 0
    acc_f, mag_f = np.empty((n, 3)), np.empty((n, 3))
    for s in range(acc.shape[0]):
        if filtering:
            prefilter_sensor(acc[s], mag[s], dt, acc_cutoff_hz, mag_cutoff_hz, order,
                             lowpass_history[s], lowpass_ready[s], acc_f, mag_f)
            hx, hy, hz, _, _ = reference_field(acc_f, mag_f, dip_rad, dip_state[s:s + 1],
                                               ux, uy, uz, nx, ny, nz)
            _fit_sensor(acc_f, mag_f, ux, uy, uz, hx, hy, hz, axes, mag_weight, tolerance,
                        max_iterations, newton, quat_state[s], has_estimate[s:s + 1],
                        quat_out[s], flags[s], iterations_out[s], criterion_out[s])
        else:
            lowpass_ready[s, 0] = lowpass_ready[s, 1] = False
            hx, hy, hz, _, _ = reference_field(acc[s], mag[s], dip_rad, dip_state[s:s + 1],
                                               ux, uy, uz, nx, ny, nz)
            _fit_sensor(acc[s], mag[s], ux, uy, uz, hx, hy, hz, axes, mag_weight, tolerance,
                        max_iterations, newton, quat_state[s], has_estimate[s:s + 1],
                        quat_out[s], flags[s], iterations_out[s], criterion_out[s])
