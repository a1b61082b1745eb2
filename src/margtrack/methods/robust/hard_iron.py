# ruff: noqa: F405  (names from robust_layout's star import)
"""The robust filter's online hard-iron estimate: a sphere fit over the rotation seen.

A magnet carried by the sensor adds a constant body-frame offset ``o`` to the field: the
samples ``m = Rᵀ b + o`` lie on a sphere of radius ``|b|`` about ``o`` as the sensor
turns, and the field's norm and dip move with the orientation. The fit is linear least
squares on

    |m|² = 2 m·o + c,        c = r² − |o|²

(the algebraic sphere fit) over exponentially forgotten sums (time constant
``hard_iron_tau_s``) kept in the row, of ``x = m − s`` (``s`` the first usable sample, so
the sums stay well scaled whatever the offset) and ``y = |x|²``. Eliminating ``c`` leaves
the 3x3 system ``2 C o' = cov(x, y)`` (``C`` the scatter of x, ``o' = o − s``); the mean
square algebraic residual is ``var(y) − 4 o'·cov(x, y) + 4 o'ᵀ C o'``.

A fit is accepted only when

- the rotation seen spans every direction: the smallest eigenvalue of ``C`` is at least
  ``COND`` r² (a standard deviation of 0.14 r along the weakest axis, the field direction
  swinging some ±8° about it; a rotation about one axis puts the samples on a circle,
  eigenvalue 0, and a circle lies on a whole family of spheres);
- the samples are on the sphere: the rms radial residual (algebraic residual / 2r) is at
  most half of ``mag_norm_tol`` times r (a field whose norm varies by the tolerance that
  counts as disturbed is no sphere);
- the radius is an earth field: within ``mag_norm_tol`` of ``mag_norm_ref`` when that is
  given, else between ``EARTH_MIN_UT`` and ``EARTH_MAX_UT`` (the geomagnetic field at the
  surface is 22-67 µT; the field is then taken to be in µT).

An offset moves the field's norm over ±|o| as the sensor turns. A fitted offset is taken
on only when it is larger than twice ``mag_norm_tol`` times r: the norm gate would then
reject half of all orientations (those within 60° of the offset's axis or its opposite).
A smaller one changes the norm by about what the filter already accepts as undisturbed,
and is about how far a calibrated sensor's field in a building strays from a sphere
(calibration residue, gradients): no magnet, offset 0. A held offset is dropped (to 0)
when a fit is accepted with one no larger than ``mag_norm_tol`` times r, where the gate
would reject no orientation (the hysteresis keeps a fit near the bound from switching it
on and off, each switch restarting the heading's convergence), or when later fits fail
and the raw field's norm varies less than the corrected one's (the magnet gone).

An accepted offset is subtracted from every field sample before any use. When it moves
by more than half the norm tolerance (a magnet found, moved or gone), the field reference
is the fit's radius, the dip reference the next sample's, and the heading converges
afresh (the start-up mean of ``converge_s``).

While no fit is accepted but the corrected field's norm varies by more than half the
tolerance, an offset explains ``EXPLAINED`` of that variance (a sphere fit regularised, so
a circle is explained too) and the sensor turned (the scatter's middle eigenvalue at
least ``COND`` |m|²: a norm that changes without rotation scatters the samples along one
direction only), the field is rejected (``moving``): the heading is held on the gyro and
flagged ``MAG_DISTURBED``. When not even the regularised fit puts the memory within the
tolerance of a sphere (rms radial residual above half ``mag_norm_tol`` times |m|), the
field changed (a magnet put on or taken off, a disturbed room): the sums start again, so
a new field is not fitted mixed with the old one for several ``hard_iron_tau_s``.

Screened-out samples (all zero: stuck, clipped, non-finite) and samples beyond ``BIG``
never enter the sums. The sums are updated every sample without branches (the lockstep
pass); the solve runs every ``HI_EVERY`` samples, in the scalar pass.
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit, select
from margtrack.estimator.linalg_kernel import sym3_adjugate
from margtrack.methods.robust.layout import *  # noqa: F403 (the layout)

COND = 0.02
EXPLAINED = 0.75
EARTH_MIN_UT = 20.0
EARTH_MAX_UT = 70.0
#: least sum of weights (≈ seconds of data / hard_iron_tau_s) before a fit is solved
MIN_WEIGHT = 0.1
#: |x|² beyond this (a field of 1 T) is no measurement: left out of the sums
BIG = 1e12

_S, _X, _XX, _YX, _Y, _YY = 0, 1, 4, 10, 13, 14  # offsets in R_HI_SUMS


@njit(cache=True, inline="always")
def fresh_at(st, o, lanes):
    """No field seen: no origin, empty sums, no offset accepted, not moving."""
    for k in range(3):
        st[o + (R_HI_SHIFT + k) * lanes] = math.nan
        st[o + (R_HI_OFFSET + k) * lanes] = 0.0
    for k in range(15):
        st[o + (R_HI_SUMS + k) * lanes] = 0.0
    st[o + R_HI_RADIUS * lanes] = 0.0
    st[o + R_HI_MOVING * lanes] = 0.0


@njit(cache=True, inline="always")
def accumulate_at(st, o, lanes, coef, dt, m0, m1, m2, usable, steady):
    """The sums forgotten over ``dt`` and, if ``usable``, the sample (m0, m1, m2) added
    with weight ``dt / hard_iron_tau_s``; ``steady`` (the lockstep pass) without a branch
    (``jit.select``): the origin is set in the scalar pass (``kernel._rare_at``)."""
    w = dt * coef[C_HI_RATE]
    decay = select(w < 1.0, 1.0 - w, 0.0)
    i_sh = o + R_HI_SHIFT * lanes
    if not steady and usable and st[i_sh] != st[i_sh]:  # the first usable sample: origin
        if m0 * m0 + m1 * m1 + m2 * m2 < BIG:
            st[i_sh], st[i_sh + lanes], st[i_sh + 2 * lanes] = m0, m1, m2
    x0, x1, x2 = m0 - st[i_sh], m1 - st[i_sh + lanes], m2 - st[i_sh + 2 * lanes]
    y = x0 * x0 + x1 * x1 + x2 * x2
    ok = usable & (y < BIG)  # (false for nan: no origin yet)
    u = select(ok, w, 0.0)
    x0, x1, x2 = select(ok, x0, 0.0), select(ok, x1, 0.0), select(ok, x2, 0.0)
    y = select(ok, y, 0.0)
    i = o + R_HI_SUMS * lanes
    st[i] = decay * st[i] + u
    ux0, ux1, ux2, uy = u * x0, u * x1, u * x2, u * y
    st[i + _X * lanes] = decay * st[i + _X * lanes] + ux0
    st[i + (_X + 1) * lanes] = decay * st[i + (_X + 1) * lanes] + ux1
    st[i + (_X + 2) * lanes] = decay * st[i + (_X + 2) * lanes] + ux2
    st[i + _XX * lanes] = decay * st[i + _XX * lanes] + ux0 * x0
    st[i + (_XX + 1) * lanes] = decay * st[i + (_XX + 1) * lanes] + ux0 * x1
    st[i + (_XX + 2) * lanes] = decay * st[i + (_XX + 2) * lanes] + ux0 * x2
    st[i + (_XX + 3) * lanes] = decay * st[i + (_XX + 3) * lanes] + ux1 * x1
    st[i + (_XX + 4) * lanes] = decay * st[i + (_XX + 4) * lanes] + ux1 * x2
    st[i + (_XX + 5) * lanes] = decay * st[i + (_XX + 5) * lanes] + ux2 * x2
    st[i + _YX * lanes] = decay * st[i + _YX * lanes] + uy * x0
    st[i + (_YX + 1) * lanes] = decay * st[i + (_YX + 1) * lanes] + uy * x1
    st[i + (_YX + 2) * lanes] = decay * st[i + (_YX + 2) * lanes] + uy * x2
    st[i + _Y * lanes] = decay * st[i + _Y * lanes] + uy
    st[i + _YY * lanes] = decay * st[i + _YY * lanes] + uy * y


@njit(cache=True, inline="always")
def _solve_sym(c00, c01, c02, c11, c12, c22, d0, d1, d2):
    """C⁻¹ d for symmetric C (by its adjugate) and det C; (0, 0, 0) when det C <= 0."""
    a00, a01, a02, a11, a12, a22, det = sym3_adjugate(c00, c01, c02, c11, c12, c22)
    if not det > 0.0:
        return 0.0, 0.0, 0.0, det
    return ((a00 * d0 + a01 * d1 + a02 * d2) / det, (a01 * d0 + a11 * d1 + a12 * d2) / det,
            (a02 * d0 + a12 * d1 + a22 * d2) / det, det)


@njit(cache=True, inline="always")
def eigenvalues(c00, c01, c02, c11, c12, c22):
    """Eigenvalues (smallest, middle, largest) of a symmetric 3x3 matrix (the
    trigonometric closed form)."""
    p1 = c01 * c01 + c02 * c02 + c12 * c12
    q = (c00 + c11 + c22) / 3.0
    p2 = (c00 - q) ** 2 + (c11 - q) ** 2 + (c22 - q) ** 2 + 2.0 * p1
    if not p2 > 0.0:
        return q, q, q
    p = math.sqrt(p2 / 6.0)
    b00, b11, b22 = (c00 - q) / p, (c11 - q) / p, (c22 - q) / p
    b01, b02, b12 = c01 / p, c02 / p, c12 / p
    half_det = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02)
                      + b02 * (b01 * b12 - b11 * b02))
    phi = math.acos(min(1.0, max(-1.0, half_det))) / 3.0
    largest = q + 2.0 * p * math.cos(phi)
    smallest = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return smallest, 3.0 * q - largest - smallest, largest


@njit(cache=True, inline="always")
def _residual2(var_y, c00, c01, c02, c11, c12, c22, d0, d1, d2, o0, o1, o2):
    """Mean square of y − 2 x·o' − c (c at its best) for the origin-relative centre o'."""
    co0 = c00 * o0 + c01 * o1 + c02 * o2
    co1 = c01 * o0 + c11 * o1 + c12 * o2
    co2 = c02 * o0 + c12 * o1 + c22 * o2
    return var_y - 4.0 * (o0 * d0 + o1 * d1 + o2 * d2) + 4.0 * (o0 * co0 + o1 * co1 + o2 * co2)


@njit(cache=True, inline="always")
def _norm2_moments(ey, var_y, e0, e1, e2, c00, c01, c02, c11, c12, c22, d0, d1, d2, t0, t1, t2):
    """Mean and variance of |x + t|² from the moments of x and y = |x|²."""
    ct0 = c00 * t0 + c01 * t1 + c02 * t2
    ct1 = c01 * t0 + c11 * t1 + c12 * t2
    ct2 = c02 * t0 + c12 * t1 + c22 * t2
    mean = ey + 2.0 * (e0 * t0 + e1 * t1 + e2 * t2) + t0 * t0 + t1 * t1 + t2 * t2
    var = var_y + 4.0 * (t0 * d0 + t1 * d1 + t2 * d2) + 4.0 * (t0 * ct0 + t1 * ct1 + t2 * ct2)
    return mean, var


@njit(cache=True, _nrt=False)
def solve_at(st, o, lanes, coef):
    """The fit of the sums so far: accepts it (offset, radius; returns True when the offset
    moved by more than half the norm tolerance) or not (then sets ``moving``)."""
    i = o + R_HI_SUMS * lanes
    weight = st[i]
    if not weight >= MIN_WEIGHT:
        return False
    inv = 1.0 / weight
    e0, e1, e2 = st[i + _X * lanes] * inv, st[i + (_X + 1) * lanes] * inv, \
        st[i + (_X + 2) * lanes] * inv
    ey = st[i + _Y * lanes] * inv
    c00 = st[i + _XX * lanes] * inv - e0 * e0
    c01 = st[i + (_XX + 1) * lanes] * inv - e0 * e1
    c02 = st[i + (_XX + 2) * lanes] * inv - e0 * e2
    c11 = st[i + (_XX + 3) * lanes] * inv - e1 * e1
    c12 = st[i + (_XX + 4) * lanes] * inv - e1 * e2
    c22 = st[i + (_XX + 5) * lanes] * inv - e2 * e2
    d0 = st[i + _YX * lanes] * inv - ey * e0
    d1 = st[i + (_YX + 1) * lanes] * inv - ey * e1
    d2 = st[i + (_YX + 2) * lanes] * inv - ey * e2
    var_y = st[i + _YY * lanes] * inv - ey * ey
    tol = coef[C_MAG_NORM_TOL]
    i_sh, i_off = o + R_HI_SHIFT * lanes, o + R_HI_OFFSET * lanes
    s0, s1, s2 = st[i_sh], st[i_sh + lanes], st[i_sh + 2 * lanes]
    # the exact fit: centre o' relative to the origin, radius r
    p0, p1, p2, _det = _solve_sym(c00, c01, c02, c11, c12, c22, 0.5 * d0, 0.5 * d1, 0.5 * d2)
    r2 = ey - 2.0 * (e0 * p0 + e1 * p1 + e2 * p2) + p0 * p0 + p1 * p1 + p2 * p2
    res2 = _residual2(var_y, c00, c01, c02, c11, c12, c22, d0, d1, d2, p0, p1, p2)
    r = math.sqrt(max(r2, 0.0))
    ref0 = coef[C_MAG_NORM_REF0]
    if ref0 > 0.0:
        plausible = abs(r - ref0) <= tol * ref0
    else:
        plausible = (r >= EARTH_MIN_UT) & (r <= EARTH_MAX_UT)
    lam_min, lam_mid, _ = eigenvalues(c00, c01, c02, c11, c12, c22)
    conditioned = lam_min >= COND * r2
    on_sphere = math.sqrt(max(res2, 0.0)) <= tol * r2  # rms radial <= tol / 2 * r
    if plausible & conditioned & on_sphere & (r2 > 0.0):
        o0, o1, o2 = p0 + s0, p1 + s1, p2 + s2
        held = (st[i_off] != 0.0) | (st[i_off + lanes] != 0.0) | (st[i_off + 2 * lanes] != 0.0)
        least = tol * r if held else 2.0 * tol * r  # (hysteresis: module docstring)
        if o0 * o0 + o1 * o1 + o2 * o2 <= least * least:
            o0, o1, o2 = 0.0, 0.0, 0.0  # no magnet
        moved = math.sqrt((o0 - st[i_off]) ** 2 + (o1 - st[i_off + lanes]) ** 2
                          + (o2 - st[i_off + 2 * lanes]) ** 2) > 0.5 * tol * r
        st[i_off], st[i_off + lanes], st[i_off + 2 * lanes] = o0, o1, o2
        st[o + R_HI_RADIUS * lanes] = r
        st[o + R_HI_MOVING * lanes] = 0.0
        return moved
    # not accepted: does the corrected field's norm move with the orientation?
    h0, h1, h2 = st[i_off], st[i_off + lanes], st[i_off + 2 * lanes]
    mean_z2, var_z2 = _norm2_moments(ey, var_y, e0, e1, e2, c00, c01, c02, c11, c12, c22,
                                     d0, d1, d2, s0 - h0, s1 - h1, s2 - h2)
    moved = False
    if (h0 != 0.0) | (h1 != 0.0) | (h2 != 0.0):
        # the held offset no longer fits (the magnet gone, moved): the raw field's norm
        # varies less than the corrected one's, so the offset is dropped
        mean_m2, var_m2 = _norm2_moments(ey, var_y, e0, e1, e2, c00, c01, c02, c11, c12, c22,
                                         d0, d1, d2, s0, s1, s2)
        if var_m2 * mean_z2 * mean_z2 < var_z2 * mean_m2 * mean_m2:
            st[i_off], st[i_off + lanes], st[i_off + 2 * lanes] = 0.0, 0.0, 0.0
            mean_z2, var_z2, moved = mean_m2, var_m2, True
    spread = math.sqrt(max(var_z2, 0.0)) > tol * mean_z2  # std |z| > tol / 2 |z|
    eps = 1e-3 * (c00 + c11 + c22)  # regularised: a circle's plane fit is explained too
    q0, q1, q2, _ = _solve_sym(c00 + eps, c01, c02, c11 + eps, c12, c22 + eps,
                               0.5 * d0, 0.5 * d1, 0.5 * d2)
    res2_reg = _residual2(var_y, c00, c01, c02, c11, c12, c22, d0, d1, d2, q0, q1, q2)
    explained = res2_reg <= (1.0 - EXPLAINED) * var_z2
    # and the sensor turned: the directions span a plane at least (a norm that changes
    # without rotation scatters the samples along one direction only)
    turned = lam_mid >= COND * mean_z2
    st[o + R_HI_MOVING * lanes] = 1.0 if spread & explained & turned else 0.0
    if not math.sqrt(max(res2_reg, 0.0)) <= tol * mean_z2:
        # no sphere (nor circle) fits the memory: the field changed (a magnet put on or
        # taken off, a disturbed room); the sums start again from the next sample
        for k in range(15):
            st[i + k * lanes] = 0.0
    return moved


@njit(cache=True, inline="always")
def sample_at(st, o, lanes, coef, dt, m0, m1, m2, has_mag, steady):
    """The sample into the hard-iron sums, the fit solved when due (the scalar pass: the
    lockstep pass is never due, ``kernel._rare_at``); returns the field less the accepted
    offset (an all-zero sample stays one) and whether the field moves with the
    orientation unexplained (the module docstring)."""
    usable = has_mag & ((m0 != 0.0) | (m1 != 0.0) | (m2 != 0.0))
    accumulate_at(st, o, lanes, coef, dt, m0, m1, m2, usable, steady)
    i_n = o + R_HI_COUNT * lanes
    count = select(dt > 0.0, st[i_n] + 1.0, st[i_n])
    if not steady and count >= HI_EVERY and coef[C_HI_RATE] > 0.0:
        count = 0.0
        if solve_at(st, o, lanes, coef):
            # a new offset: the corrected field's reference and heading start afresh
            r = st[o + R_HI_RADIUS * lanes]
            st[o + R_MAG_NORM_REF * lanes] = r
            st[o + R_CAND_NORM * lanes] = r
            st[o + R_MAG_DIP_REF * lanes] = math.nan
            st[o + R_CAND_DIP * lanes] = math.nan
            st[o + R_CAND_S * lanes] = 0.0
            st[o + R_HEADING_N * lanes] = 0.0
            st[o + R_SINCE_START * lanes] = 0.0
    st[i_n] = count
    i_off = o + R_HI_OFFSET * lanes
    return (select(usable, m0 - st[i_off], m0), select(usable, m1 - st[i_off + lanes], m1),
            select(usable, m2 - st[i_off + 2 * lanes], m2), st[o + R_HI_MOVING * lanes] > 0.5)


@njit(cache=True, inline="always")
def offset_outputs_at(st, o, lanes):
    """The accepted offset (3), nan until one is accepted."""
    i_off = o + R_HI_OFFSET * lanes
    none = st[o + R_HI_RADIUS * lanes] == 0.0
    return (select(none, math.nan, st[i_off]), select(none, math.nan, st[i_off + lanes]),
            select(none, math.nan, st[i_off + 2 * lanes]))
