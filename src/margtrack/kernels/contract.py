"""The compiled skeleton every method's kernel runs on: clock, screening, (re)starts, holds.

A method provides three inline functions over one sensor's flat state row ``row``
(``N_CONTRACT`` contract slots first, the method's own after them):

- ``start(row, coef, first, qw, qx, qy, qz)``: (re)start at the orientation q (body to
  earth, output frame); ``first`` is True the very first time (then the method also sets
  what it knows of the sensor, like a bias variance); a restart after a gap keeps that;
- ``step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out)``:
  one screened sample (an all-zero acc or mag: no measurement; dt 0: nothing to
  integrate); writes the orientation to ``q_out`` (4,) and its extra outputs to
  ``x_out`` (K,); returns its own flag bits (REST, MAG_DISTURBED, ACC_IGNORED ...);
- ``hold(row, coef, x_out)``: the extra outputs of the current state, for held samples.

and wraps them in ``@njit`` functions of its own: ``series`` (:func:`series` with its
functions as the first arguments: numba compiles, inlines and caches one specialisation
per method, without reference counting) and ``run`` (:func:`run_series` with its
``series``; both ``nogil``, so threads can share the sensors), ``sample`` (:func:`sample`
with its functions, compiled once), ``update`` and ``update_one`` (:func:`update_samples`,
:func:`update_one` with its ``sample``: its step is compiled once for both, not inlined
into each) and ``start`` (:func:`start_rows`). All go through the same :func:`_sample`,
so N updates equal one run.

``contract_lanes`` runs the same samples for blocks of sensors in lockstep, vectorised
across them, with the same results, for a method that also provides its functions in
strided form.

Contract slots of a row: ``K_READY`` (1: started), ``K_STARTS`` (how many starts),
``K_Q`` (4: the last output), ``K_SCREEN`` (the screening state, ``screen.N_SCREEN``).
Screening coefficients ``scoef`` are ``screen``'s plus ``C_NED`` and ``C_MAG_REQUIRED``.
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.kernels import screen
from margtrack.kernels.jit import njit
from margtrack.kernels.triad import level, reference_triad, triad_unit, unit_pair

K_READY = 0
K_STARTS = 1
K_Q = 2
K_SCREEN = 6
N_CONTRACT = K_SCREEN + screen.N_SCREEN

# screening coefficients beyond screen.N_COEF
C_NED = screen.N_COEF  # 1: the output frame is NED (else ENU)
C_MAG_REQUIRED = screen.N_COEF + 1  # 1: a start needs a usable field (else acc suffices)
N_SCOEF = screen.N_COEF + 2

INITIALISING = 256  # margtrack.estimator.flags.Flag.INITIALISING


@njit(cache=True)
def initial(scoef, a0, a1, a2, m0, m1, m2):
    """The orientation measured by one screened sample: (ok, w, x, y, z).

    TRIAD with a usable field (heading from its horizontal part), else, when the method
    does not require the field, the shortest arc taking the acceleration to up (heading
    left as it falls); not ok when neither is possible.
    """
    ned = scoef[C_NED] > 0.5
    uz = -1.0 if ned else 1.0
    flag, ax, ay, az, mx, my, mz = unit_pair(a0, a1, a2, m0, m1, m2)
    if flag == 0:
        nx, ny = (1.0, 0.0) if ned else (0.0, 1.0)
        s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z = reference_triad(0.0, 0.0, uz, nx, ny, 0.0)
        w, x, y, z = triad_unit(ax, ay, az, mx, my, mz, s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z)
        return True, w, x, y, z
    if flag == 1 or scoef[C_MAG_REQUIRED] > 0.5:
        return False, 1.0, 0.0, 0.0, 0.0
    # no usable field: a zero field (flag 2) or one parallel to the acceleration (flag 3)
    if flag == 3 and not (m0 == 0.0 and m1 == 0.0 and m2 == 0.0):
        return False, 1.0, 0.0, 0.0, 0.0
    w, x, y, z = level(1.0, 0.0, 0.0, 0.0, a0, a1, a2, 0.0, 0.0, uz)
    return True, w, x, y, z


@njit(cache=True, inline="always")
def _sample(start, step, hold, row, coef, scoef, dt, k_ref, tflags, g0, g1, g2, a0, a1, a2,
            m0, m1, m2, has_mag, has_gyr, q_out, x_out):
    """One sensor, one sample: screen, (re)start when due, step or hold; returns flags.

    ``k_ref`` is ``screen.ref_gain(dt)``, shared by the sensors of a sample."""
    # (screen_at, not its wrapper screen_one_k: each level of inlining copies the body)
    f, g0, g1, g2, a0, a1, a2, m0, m1, m2 = screen.screen_at(
        scoef, row, K_SCREEN, 1, dt, k_ref, tflags, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag,
        has_gyr,
    )
    if tflags & screen.GAP:
        row[K_READY] = 0.0
    if row[K_READY] == 0.0:
        ok, qw, qx, qy, qz = initial(scoef, a0, a1, a2, m0, m1, m2)
        if not ok:
            for k in range(4):
                q_out[k] = row[K_Q + k]
            hold(row, coef, x_out)
            return f | INITIALISING
        start(row, coef, row[K_STARTS] == 0.0, qw, qx, qy, qz)
        row[K_STARTS] += 1.0
        row[K_READY] = 1.0
        dt = 0.0  # the measured orientation is this sample's: nothing to integrate
    f |= step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out)
    for k in range(4):
        row[K_Q + k] = q_out[k]
    return f


@njit(cache=True, inline="always")
def _clock_series(clock, max_gap, t):
    """The shared clock over timestamps ``t`` (N,): intervals (N,) s, clock flags (N,) and
    the screening's reference gains (N,) (``screen.ref_gain``, once per sample).

    A gain is computed (an ``exp``) only for an interval that differs from the last two
    computed (a steady rate's intervals take 2-3 values in turn, differing in the last
    bits): the same values at a fraction of the cost on one long stream."""
    n = t.shape[0]
    dts = np.empty(n)
    ks = np.empty(n)
    tflags = np.empty(n, dtype=np.int64)
    dt_a, k_a, dt_b, k_b = math.nan, 0.0, math.nan, 0.0  # the last two computed
    for i in range(n):
        dt, tflags[i] = screen.time_one(clock, max_gap, t[i])
        dts[i] = dt
        if dt == dt_a:
            ks[i] = k_a
        elif dt == dt_b:
            ks[i] = k_b
        else:
            dt_b, k_b = dt_a, k_a
            dt_a, k_a = dt, screen.ref_gain(dt)
            ks[i] = k_a
    return dts, ks, tflags


@njit(cache=True, inline="always")
def _sensor_series(start, step, hold, row, coef, scoef, dts, ks, tflags, gyr, acc, mag,
                   has_mag, has_gyr, q_out, x_out, flags_out):
    """One sensor's N samples: gyr, acc, mag (N, 3); q_out (N, 4), x_out (N, K), flags_out
    (N,) filled."""
    for i in range(dts.shape[0]):
        flags_out[i] = _sample(
            start, step, hold, row, coef, scoef, dts[i], ks[i], tflags[i],
            gyr[i, 0], gyr[i, 1], gyr[i, 2], acc[i, 0], acc[i, 1], acc[i, 2],
            mag[i, 0], mag[i, 1], mag[i, 2], has_mag, has_gyr, q_out[i], x_out[i],
        )


@njit(cache=True, inline="always")
def series(start, step, hold, rows, coefs, dts, ks, tflags, gyr, acc, mag, has, q_out, x_out,
           flags_out):
    """S sensors' N samples on a shared clock's values (:func:`_clock_series`): dts, ks,
    tflags (N,).

    rows (S, R) in/out; coefs: the screening coefficients (N_SCOEF) then the method's;
    gyr, acc, mag (S, N, 3); ``has`` bits: 1 a field is given, 2 a rate is given;
    q_out (S, N, 4), x_out (S, N, K), flags_out (S, N) uint16 filled; each sensor runs
    through its samples on its own. The body of a method's ``series``, compiled without
    numba's reference counting (``_nrt=False``): with it, every array a sample passes on
    (the row, the output rows ``q_out[i]``, ``x_out[i]``) is counted in and out, about a
    dozen atomic calls per sample: 3-9 % of a filter's time on one stream, a third of plain
    gyro integration's (``perf``).
    """
    scoef, coef = coefs[:N_SCOEF], coefs[N_SCOEF:]
    has_mag, has_gyr = (has & 1) != 0, (has & 2) != 0
    for s in range(rows.shape[0]):
        _sensor_series(start, step, hold, rows[s], coef, scoef, dts, ks, tflags, gyr[s], acc[s],
                       mag[s], has_mag, has_gyr, q_out[s], x_out[s], flags_out[s])


@njit(cache=True, inline="always")
def run_series(series_kernel, rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out,
               flags_out):
    """S sensors' N samples with common timestamps ``t`` (N,) s; ``clock`` (1,) in/out.

    The clock is shared, so it is read once (:func:`_clock_series`); then
    ``series_kernel`` (a method's ``series``: :func:`series` with its functions) runs the
    sensors; the other arguments as :func:`series` takes them.
    """
    dts, ks, tflags = _clock_series(clock, coefs[screen.C_MAX_GAP], t)
    series_kernel(rows, coefs, dts, ks, tflags, gyr, acc, mag, has, q_out, x_out, flags_out)


@njit(cache=True, inline="always")
def _clock_step(clock, scoef, dt_given):
    """Interval and clock flags of a sample ``dt_given`` s after the last (any, if first)."""
    t = 0.0 if not math.isfinite(clock[0]) else clock[0] + dt_given
    return screen.time_one(clock, scoef[screen.C_MAX_GAP], t)


@njit(cache=True, inline="always")
def sample(start, step, hold, row, coef, scoef, clk, imu, has, q_out, x_out):
    """:func:`_sample` with the clock's values ``clk`` (dt, k_ref, tflags) and the sample
    ``imu`` (g0, g1, g2, a0, a1, a2, m0, m1, m2) packed, and the ``has`` bits: the body of
    a method's compiled ``sample``, the one function its ``update`` and ``update_one``
    call (so the method's step compiles once for both)."""
    dt, k_ref, tflags = clk
    g0, g1, g2, a0, a1, a2, m0, m1, m2 = imu
    return _sample(start, step, hold, row, coef, scoef, dt, k_ref, tflags, g0, g1, g2, a0, a1,
                   a2, m0, m1, m2, (has & 1) != 0, (has & 2) != 0, q_out, x_out)


@njit(cache=True, inline="always")
def update_samples(sample, rows, clock, coefs, dt_given, gyr, acc, mag, has, q_out, x_out,
                   flags_out):
    """One sample of S sensors, ``dt_given`` s after the last: gyr, acc, mag (S, 3);
    q_out (S, 4), x_out (S, K), flags_out (S,) filled; ``sample`` the method's compiled
    one (:func:`sample`)."""
    scoef, coef = coefs[:N_SCOEF], coefs[N_SCOEF:]
    dt, tflags = _clock_step(clock, scoef, dt_given)
    clk = (dt, screen.ref_gain(dt), tflags)
    for s in range(rows.shape[0]):
        flags_out[s] = sample(
            rows[s], coef, scoef, clk, (gyr[s, 0], gyr[s, 1], gyr[s, 2], acc[s, 0], acc[s, 1],
                                        acc[s, 2], mag[s, 0], mag[s, 1], mag[s, 2]),
            has, q_out[s], x_out[s],
        )


@njit(cache=True, inline="always")
def update_one(sample, rows, clock, coefs, dt_given, g, a, m, has, out):
    """One sample of one sensor: g, a, m (3,); out (4 + K,) gets q then the extra outputs.

    Returns the flags. The lean path of ``update`` (few arguments, nothing allocated).
    """
    scoef, coef = coefs[:N_SCOEF], coefs[N_SCOEF:]
    dt, tflags = _clock_step(clock, scoef, dt_given)
    return sample(rows[0], coef, scoef, (dt, screen.ref_gain(dt), tflags),
                  (g[0], g[1], g[2], a[0], a[1], a[2], m[0], m[1], m[2]), has, out[:4], out[4:])


@njit(cache=True, inline="always")
def start_rows(start, rows, coefs, quat0):
    """Start every sensor at a given orientation quat0 (S, 4) (``reset(q0)``)."""
    coef = coefs[N_SCOEF:]
    for s in range(rows.shape[0]):
        row = rows[s]
        start(row, coef, row[K_STARTS] == 0.0, quat0[s, 0], quat0[s, 1], quat0[s, 2], quat0[s, 3])
        row[K_STARTS] += 1.0
        row[K_READY] = 1.0
        for k in range(4):
            row[K_Q + k] = quat0[s, k]
