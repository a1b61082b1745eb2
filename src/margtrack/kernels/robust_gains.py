"""The robust kernel's interval-dependent gains: first-order low-pass gains and the
second-order Butterworth coefficients, kept per row for the last two intervals.
"""

from __future__ import annotations

import math

from margtrack.kernels.jit import njit
from margtrack.kernels.robust_layout import (
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
def _gains_match(row, g, coef, step):
    """Whether the gains of the slot at ``row[g:]`` were computed for this interval and
    these time constants."""
    return (
        row[g + G_DT] == step
        and row[g + G_TAU_ACC] == coef[C_TAU_ACC]
        and row[g + G_TAU_MAG] == coef[C_TAU_MAG]
        and row[g + G_REST_TAU] == coef[C_REST_TAU]
        and row[g + G_REF_TAU] == coef[C_MAG_REF_TAU]
    )


@njit(cache=True, inline="always")
def _gains(row, coef, step):
    """The offset of the slot holding the gains for interval ``step``; computed (3 ``exp``,
    a ``tan``) only when neither slot has them for this interval and the time constants.

    Timestamps of a steady rate give intervals that differ in the last bits (``t = i /
    rate`` has 2-3 distinct differences in turn; BROAD's clock 21): one slot recomputed
    them at 40-65 % of the samples, two at 0.05 %. The values are those of a fresh
    computation (the same function of the same numbers)."""
    g = R_GAINS + (N_GAINS if row[R_GAINS_IN_USE] == N_GAINS else 0)  # any value: a slot
    if _gains_match(row, g, coef, step):
        return g
    g = 2 * R_GAINS + N_GAINS - g  # the other slot
    row[R_GAINS_IN_USE] = g - R_GAINS
    if not _gains_match(row, g, coef, step):
        row[g + G_DT] = step
        row[g + G_TAU_ACC] = coef[C_TAU_ACC]
        row[g + G_TAU_MAG] = coef[C_TAU_MAG]
        row[g + G_REST_TAU] = coef[C_REST_TAU]
        row[g + G_REF_TAU] = coef[C_MAG_REF_TAU]
        row[g + G_K_REST] = _lowpass_gain(step, coef[C_REST_TAU])
        row[g + G_K_REF] = _lowpass_gain(step, coef[C_MAG_REF_TAU])
        row[g + G_K_MAG] = _lowpass_gain(step, coef[C_TAU_MAG])
        b0, a1, a2 = butterworth_coefficients(step, coef[C_TAU_ACC])
        row[g + G_BW], row[g + G_BW + 1], row[g + G_BW + 2] = b0, a1, a2
    return g
