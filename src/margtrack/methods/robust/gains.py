"""The robust kernel's interval-dependent gains: first-order low-pass gains and the
second-order Butterworth coefficients, kept per row for the last two intervals.
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit, select
from margtrack.methods.robust.layout import (
    C_MAG_REF_TAU,
    C_REST_TAU,
    C_TAU_ACC,
    C_TAU_MAG,
    G_BW,
    G_DT,
    G_K_MAG,
    G_K_REF,
    G_K_REST,
    G_REF_TAU,
    G_REST_TAU,
    G_TAU_ACC,
    G_TAU_MAG,
    N_GAINS,
    R_GAINS,
    R_GAINS_IN_USE,
)


@njit(cache=True, inline="always")
def _lowpass_gain(dt, tau):
    """First-order low-pass gain for a time constant tau (s); 1 when tau <= 0."""
    if tau <= 0.0:
        return 1.0
    return 1.0 - math.exp(-dt / tau)


@njit(cache=True)
def butterworth_coefficients(step, tau):
    """(b0, a1, a2) of the second-order Butterworth low-pass for time constant tau at step.

    Cut-off ``f_c = sqrt(2) / (2 pi tau)`` (so its step response is close to a first-order
    filter's with the same tau), discretised by the bilinear transform with pre-warping;
    ``b1 = 2 b0`` and ``b2 = b0``.
    """
    fc = math.sqrt(2.0) / (2.0 * math.pi * tau)
    c = math.tan(math.pi * fc * step)
    d = c * c + math.sqrt(2.0) * c + 1.0
    return c * c / d, 2.0 * (c * c - 1.0) / d, (1.0 - math.sqrt(2.0) * c + c * c) / d


@njit(cache=True, inline="always")
def _bw_step(b0, a1, a2, s1, s2, x):
    """One sample through the low-pass (transposed direct form II): (y, s1, s2)."""
    y = b0 * x + s1
    return y, 2.0 * b0 * x - a1 * y + s2, b0 * x - a2 * y


@njit(cache=True, inline="always")
def _bw_hold(b0, a1, a2, x):
    """States (s1, s2) of the low-pass in the steady state of a constant input x."""
    s2 = (b0 - a2) * x
    return (2.0 * b0 - a1) * x + s2, s2


@njit(cache=True, inline="always")
def _slot_matches_at(st, o, lanes, g, coef, step):
    """Whether the gains of the slot at row offset ``g`` (the row's slot j at
    ``st[o + j * lanes]``) were computed for this interval and these time constants."""
    i = o + g * lanes
    # (& on the comparisons, not and: every load taken, no branch, so a loop over lanes
    # vectorises it)
    return (
        (st[i + G_DT * lanes] == step)
        & (st[i + G_TAU_ACC * lanes] == coef[C_TAU_ACC])
        & (st[i + G_TAU_MAG * lanes] == coef[C_TAU_MAG])
        & (st[i + G_REST_TAU * lanes] == coef[C_REST_TAU])
        & (st[i + G_REF_TAU * lanes] == coef[C_MAG_REF_TAU])
    )


@njit(cache=True, inline="always")
def gains_at(st, o, lanes, coef, step):
    """The row offset of the slot holding the gains for interval ``step``; computed (3
    ``exp``, a ``tan``) only when neither slot has them for this interval and the time
    constants. The row's slot j is ``st[o + j * lanes]`` (``(row, 0, 1)`` for one row).

    Timestamps of a steady rate give intervals that differ in the last bits (``t = i /
    rate`` has 2-3 distinct differences in turn; BROAD's clock 21): one slot recomputed
    them at 40-65 % of the samples, two at 0.05 %. The values are those of a fresh
    computation (the same function of the same numbers)."""
    i_use = o + R_GAINS_IN_USE * lanes
    g = R_GAINS + (N_GAINS if st[i_use] == N_GAINS else 0)  # any value: a slot
    if _slot_matches_at(st, o, lanes, g, coef, step):
        return g
    g = 2 * R_GAINS + N_GAINS - g  # the other slot
    st[i_use] = g - R_GAINS
    if not _slot_matches_at(st, o, lanes, g, coef, step):
        i = o + g * lanes
        st[i + G_DT * lanes] = step
        st[i + G_TAU_ACC * lanes] = coef[C_TAU_ACC]
        st[i + G_TAU_MAG * lanes] = coef[C_TAU_MAG]
        st[i + G_REST_TAU * lanes] = coef[C_REST_TAU]
        st[i + G_REF_TAU * lanes] = coef[C_MAG_REF_TAU]
        st[i + G_K_REST * lanes] = _lowpass_gain(step, coef[C_REST_TAU])
        st[i + G_K_REF * lanes] = _lowpass_gain(step, coef[C_MAG_REF_TAU])
        st[i + G_K_MAG * lanes] = _lowpass_gain(step, coef[C_TAU_MAG])
        b0, a1, a2 = butterworth_coefficients(step, coef[C_TAU_ACC])
        st[i + G_BW * lanes], st[i + (G_BW + 1) * lanes], st[i + (G_BW + 2) * lanes] = b0, a1, a2
    return g


@njit(cache=True, inline="always")
def gains_ready_at(st, o, lanes, coef, step):
    """Whether one of the two slots has the gains for ``step`` (then :func:`gains_at`
    computes nothing)."""
    return _slot_matches_at(st, o, lanes, R_GAINS, coef, step) | _slot_matches_at(
        st, o, lanes, R_GAINS + N_GAINS, coef, step
    )


@njit(cache=True, inline="always")
def gains_values_at(st, o, lanes, g):
    """(k_rest, k_ref, k_mag, b0, a1, a2) of the slot at row offset ``g``."""
    i = o + g * lanes
    return (st[i + G_K_REST * lanes], st[i + G_K_REF * lanes], st[i + G_K_MAG * lanes],
            st[i + G_BW * lanes], st[i + (G_BW + 1) * lanes], st[i + (G_BW + 2) * lanes])


@njit(cache=True, inline="always")
def gains_steady_at(st, o, lanes, coef, step):
    """:func:`gains_at` and the gains it points to, when :func:`gains_ready_at` holds:
    the same slot, in-use mark and values, chosen by selects between the two slots'
    constant offsets (no row-dependent offset, no branch, no ``exp``), so a loop over lanes
    vectorises."""
    i_use = o + R_GAINS_IN_USE * lanes
    match0 = _slot_matches_at(st, o, lanes, R_GAINS, coef, step)
    match1 = _slot_matches_at(st, o, lanes, R_GAINS + N_GAINS, coef, step)
    second = st[i_use] == N_GAINS
    # kept when it matches, else the other one (which does)
    second = second == ((second & match1) | ((not second) & match0))
    st[i_use] = select(second, N_GAINS, 0.0)
    # both slots loaded, then values selected (a select between two loads becomes a load
    # from a selected address, which the vectoriser cannot bound; jit.select, not a
    # branch: after a few branches each store below became a masked store)
    r0, f0, m0, b00, a10, a20 = gains_values_at(st, o, lanes, R_GAINS)
    r1, f1, m1, b01, a11, a21 = gains_values_at(st, o, lanes, R_GAINS + N_GAINS)
    return (select(second, r1, r0), select(second, f1, f0), select(second, m1, m0),
            select(second, b01, b00), select(second, a11, a10), select(second, a21, a20))
