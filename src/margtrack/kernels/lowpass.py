"""Kernel of the low-pass prefilter of single-frame estimators (002 Fig. 5).

A first- or second-order Butterworth filter discretised by the bilinear transform with the
cut-off pre-warped, so the digital filter has exactly -3 dB at ``cutoff_hz`` for any sample
time. Coefficients follow each sample's ``dt`` (irregular timestamps are allowed); the
history is kept in direct form I (past inputs and outputs, physical values that stay valid
when the coefficients change), so it can be stored in an estimator's state and a run can be
split anywhere.

History layout per filtered triad: ``(4, 3)`` rows ``[x[n-1], x[n-2], y[n-1], y[n-2]]``.
A filter starts in steady state at its first sample (every row set to that sample), so the
output begins at the input instead of ramping up from zero.
"""

from __future__ import annotations

import math

from numba import njit

#: coefficients (b0, b1, b2, a1, a2) of the all-pass "filter" used while a filter is off
PASS_THROUGH = (1.0, 0.0, 0.0, 0.0, 0.0)


@njit(cache=True, inline="always")
def coefficients(cutoff_hz, dt_s, order):
    """(b0, b1, b2, a1, a2) of the order-1 or order-2 Butterworth low-pass for one ``dt``.

    ``y[n] = b0 x[n] + b1 x[n-1] + b2 x[n-2] - a1 y[n-1] - a2 y[n-2]``, with
    ``K = tan(π f_c dt)`` (bilinear transform, pre-warped cut-off). The caller guarantees
    ``0 < cutoff_hz < 1 / (2 dt)``. DC gain is exactly 1: ``b0 + b1 + b2 = 1 + a1 + a2``.
    """
    k = math.tan(math.pi * cutoff_hz * dt_s)
    if order == 1:
        # H(s) = 1 / (1 + s/ω_c)
        b0 = k / (k + 1.0)
        return b0, b0, 0.0, (k - 1.0) / (k + 1.0), 0.0
    # H(s) = 1 / (1 + √2 s/ω_c + (s/ω_c)²)
    root2 = math.sqrt(2.0)
    norm = 1.0 / (1.0 + root2 * k + k * k)
    b0 = k * k * norm
    return b0, 2.0 * b0, b0, 2.0 * (k * k - 1.0) * norm, (1.0 - root2 * k + k * k) * norm


@njit(cache=True, inline="always")
def start(history, x, y, z):
    """Put a filter in steady state at the sample (x, y, z); return that sample."""
    for row in range(4):
        history[row, 0] = x
        history[row, 1] = y
        history[row, 2] = z
    return x, y, z


@njit(cache=True, inline="always")
def step(history, x, y, z, coef):
    """Filter one sample of a triad with coefficients ``coef``; update ``history`` (4, 3)."""
    b0, b1, b2, a1, a2 = coef
    h = history
    out0 = b0 * x + b1 * h[0, 0] + b2 * h[1, 0] - a1 * h[2, 0] - a2 * h[3, 0]
    out1 = b0 * y + b1 * h[0, 1] + b2 * h[1, 1] - a1 * h[2, 1] - a2 * h[3, 1]
    out2 = b0 * z + b1 * h[0, 2] + b2 * h[1, 2] - a1 * h[2, 2] - a2 * h[3, 2]
    history[1, 0], history[1, 1], history[1, 2] = history[0, 0], history[0, 1], history[0, 2]
    history[0, 0], history[0, 1], history[0, 2] = x, y, z
    history[3, 0], history[3, 1], history[3, 2] = history[2, 0], history[2, 1], history[2, 2]
    history[2, 0], history[2, 1], history[2, 2] = out0, out1, out2
    return out0, out1, out2


@njit(cache=True)
def filter_series(signal, dt, cutoff_hz, order, history, ready, channel, out):
    """Low-pass one triad series (N, 3) into ``out`` (N, 3); ``cutoff_hz`` <= 0: copy.

    history (4, 3) and ready[channel] are that filter's state (updated). A filter that
    is not ready starts in steady state at its first sample; one that is off is marked
    not ready, so turning it on again (``set_params``) restarts it at that sample.
    """
    n = signal.shape[0]
    if not cutoff_hz > 0.0:
        ready[channel] = False
        for i in range(n):
            out[i, 0], out[i, 1], out[i, 2] = signal[i, 0], signal[i, 1], signal[i, 2]
        return
    last_dt = -1.0
    coef = PASS_THROUGH
    for i in range(n):
        x, y, z = signal[i, 0], signal[i, 1], signal[i, 2]
        if not ready[channel]:
            ready[channel] = True
            x, y, z = start(history, x, y, z)
        else:
            if dt[i] != last_dt:
                coef = coefficients(cutoff_hz, dt[i], order)
                last_dt = dt[i]
            x, y, z = step(history, x, y, z, coef)
        out[i, 0], out[i, 1], out[i, 2] = x, y, z


@njit(cache=True)
def prefilter_sensor(acc, mag, dt, acc_cutoff_hz, mag_cutoff_hz, order, history, ready,
                     acc_out, mag_out):
    """The prefilter of one sensor: acc, mag (N, 3) into acc_out, mag_out (N, 3).

    history (2, 4, 3) and ready (2,) are that sensor's filter state (index 0 the
    accelerometer, 1 the magnetometer); a cut-off <= 0 copies that signal.
    """
    filter_series(acc, dt, acc_cutoff_hz, order, history[0], ready, 0, acc_out)
    filter_series(mag, dt, mag_cutoff_hz, order, history[1], ready, 1, mag_out)


@njit(cache=True)
def lowpass(signal, dt, cutoff_hz, order, history, ready, out):
    """Low-pass S triads over N samples (the prefilter on its own, for tests and tools).

    signal (S, N, 3); dt (N,) s; history (S, 4, 3) and ready (S,) bool in/out (a sensor
    that is not ready starts in steady state at its first sample); out (S, N, 3) filled.
    """
    for s in range(signal.shape[0]):
        filter_series(signal[s], dt, cutoff_hz, order, history[s], ready[s:s + 1], 0, out[s])
