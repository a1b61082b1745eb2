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

Screened input (``estimator/screening.py``): an all-zero triad means "no measurement". It
passes through as zero (the estimator then skips that vector) and is never filtered in:
a running filter holds its last input over the sample's interval, so the timing stays
right and the output resumes smoothly. ``dt = 0`` integrates nothing. An interval too long
for the cut-off (``f_c dt >= 1/2``, beyond the bilinear transform: dropped samples) leaves
nothing of the history worth keeping, so the filter restarts at the next measurement.
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit

#: coefficients (b0, b1, b2, a1, a2) of the all-pass "filter" used while a filter is off
PASS_THROUGH = (1.0, 0.0, 0.0, 0.0, 0.0)


@njit(cache=True, inline="always")
def coefficients(cutoff_hz, dt_s, order):
    """(b0, b1, b2, a1, a2) of the order-1 or order-2 Butterworth low-pass for one ``dt``.

    ``y[n] = b0 x[n] + b1 x[n-1] + b2 x[n-2] - a1 y[n-1] - a2 y[n-2]``, with
    ``K = tan(π f_c dt)`` (bilinear transform, pre-warped cut-off). The caller guarantees
    ``0 < cutoff_hz < 1 / (2 dt)`` (:func:`filter_series` restarts beyond it). DC gain is
    exactly 1: ``b0 + b1 + b2 = 1 + a1 + a2``.
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
    is not ready starts in steady state at its first measurement; one that is off is marked
    not ready, so turning it on again (``set_params``) restarts it at that sample. dt (N,)
    s before each sample (0: none). An all-zero sample (no measurement) is output as zero
    and a running filter steps over its interval with its last input held; an interval
    with ``cutoff_hz * dt >= 1/2`` restarts the filter at the next measurement.
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
        step_dt = dt[i]
        too_long = cutoff_hz * step_dt >= 0.5
        if x == 0.0 and y == 0.0 and z == 0.0:
            # no measurement: passes through; the filter holds its input over the interval
            out[i, 0], out[i, 1], out[i, 2] = 0.0, 0.0, 0.0
            if ready[channel] and step_dt > 0.0:
                if too_long:
                    ready[channel] = False
                else:
                    if step_dt != last_dt:
                        coef = coefficients(cutoff_hz, step_dt, order)
                        last_dt = step_dt
                    step(history, history[0, 0], history[0, 1], history[0, 2], coef)
            continue
        if not ready[channel] or too_long:
            ready[channel] = True
            x, y, z = start(history, x, y, z)
        elif not step_dt > 0.0:
            # no time has passed since the last filtered sample: its output stands
            x, y, z = history[2, 0], history[2, 1], history[2, 2]
        else:
            if step_dt != last_dt:
                coef = coefficients(cutoff_hz, step_dt, order)
                last_dt = step_dt
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
