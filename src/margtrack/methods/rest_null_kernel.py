"""Compiled kernel: the gyroscope null point measured while the sensor is still at the start.

000 (Appendix B, step 1; "Sensor Calibration") sets each rate sensor's null point to its
reading averaged over a period in which the sensor is stationary. This kernel does that
online for S sensors: from the first sample after a reset it keeps the running mean of the
gyroscope while the sensor stays still, subtracts it, and freezes it at the first sample of
motion. See :mod:`margtrack.methods.rest_null` for the rules.

One sensor's null is a block of ``N_REST_NULL`` numbers inside a flat row (the filters'
kernels keep it in theirs, at some offset ``o``): ``RN_TOTAL`` (3) sum of the still gyro
samples, rad/s; ``RN_COUNT`` their number; ``RN_DURATION`` their time span, s;
``RN_ACC_SUM`` and ``RN_MAG_SUM`` (3 each) the sums of their accelerometer and
magnetometer vectors; ``RN_STILL`` 1 while the start is still; ``RN_NULL`` (3) the null in
use, rad/s. :func:`step_one` advances it by one sample (inline, for the filters' per-sample
steps); :func:`subtract_rest_null` runs it over series of S sensors.

Coefficients (``N_RC``, at some offset of a coefficient vector): ``RC_MIN_REST`` the
shortest still start that gives a null, s (<= 0: no null, the block is not advanced);
``RC_GYR_TOL`` rad/s; ``RC_ACC_COS`` and ``RC_MAG_COS`` the smallest cosines of the
direction changes; ``RC_MAX_RATE`` rad/s.
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit

RN_TOTAL = 0
RN_COUNT = 3
RN_DURATION = 4
RN_ACC_SUM = 5
RN_MAG_SUM = 8
RN_STILL = 11
RN_NULL = 12
N_REST_NULL = 15

RC_MIN_REST = 0
RC_GYR_TOL = 1
RC_ACC_COS = 2
RC_MAG_COS = 3
RC_MAX_RATE = 4
N_RC = 5


@njit(cache=True, inline="always")
def _angle_cos(ax, ay, az, bx, by, bz):
    """Cosine of the angle between two vectors (1.0 if either is zero)."""
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    if na == 0.0 or nb == 0.0:
        return 1.0
    return (ax * bx + ay * by + az * bz) / (na * nb)


@njit(cache=True, inline="always")
def fresh_one(r, o, lanes=1):
    """A null block at ``r[o + j * lanes]``, j < N_REST_NULL, that has seen nothing (still,
    no null)."""
    for k in range(N_REST_NULL):
        r[o + k * lanes] = 0.0
    r[o + RN_STILL * lanes] = 1.0


@njit(cache=True, inline="always")
def step_one(r, o, c, co, gx, gy, gz, ax, ay, az, mx, my, mz, has_mag, dt):
    """One sample through the null block ``r[o:]`` (coefficients ``c[co:]``); the null to
    subtract from it, rad/s (3 floats).

    A sample is still when its rate is within the tolerance of the mean so far and its acc
    (and, ``has_mag``, mag) direction has at least the minimum cosine with the mean so far
    (a mean, not the first sample: magnetometers can be noisy by degrees). The null is the
    running mean while still, the frozen mean after, and 0 if the still start lasted less
    than the minimum. A zero acc or mag vector (a screened sample) passes its direction
    test; a rate beyond the maximum (or non-finite) is left out without ending the still
    start. With a minimum <= 0 the block is left alone and the null is 0.
    """
    return step_at(r, o, 1, c, co, gx, gy, gz, ax, ay, az, mx, my, mz, has_mag, dt)


@njit(cache=True, inline="always")
def step_at(r, o, lanes, c, co, gx, gy, gz, ax, ay, az, mx, my, mz, has_mag, dt):
    """:func:`step_one` with the block's slot j at ``r[o + j * lanes]`` (a lane of
    interleaved rows, ``contract_lanes``)."""
    min_rest_s = c[co + RC_MIN_REST]
    if not min_rest_s > 0.0:
        return 0.0, 0.0, 0.0
    i_total, i_acc, i_mag = o + RN_TOTAL * lanes, o + RN_ACC_SUM * lanes, o + RN_MAG_SUM * lanes
    i_count, i_still, i_null = o + RN_COUNT * lanes, o + RN_STILL * lanes, o + RN_NULL * lanes
    max_rate = c[co + RC_MAX_RATE]
    sane = abs(gx) <= max_rate and abs(gy) <= max_rate
    sane = sane and abs(gz) <= max_rate
    if r[i_still] != 0.0 and sane:
        count = r[i_count]
        if count == 0.0:
            ok = True
        else:
            tol = c[co + RC_GYR_TOL]
            ex = gx - r[i_total] / count
            ey = gy - r[i_total + lanes] / count
            ez = gz - r[i_total + 2 * lanes] / count
            ok = ex * ex + ey * ey + ez * ez <= tol * tol
            ok = ok and _angle_cos(
                ax, ay, az, r[i_acc], r[i_acc + lanes], r[i_acc + 2 * lanes]
            ) >= c[co + RC_ACC_COS]
            if has_mag:
                ok = ok and _angle_cos(
                    mx, my, mz, r[i_mag], r[i_mag + lanes], r[i_mag + 2 * lanes]
                ) >= c[co + RC_MAG_COS]
        if ok:
            r[i_total] += gx
            r[i_total + lanes] += gy
            r[i_total + 2 * lanes] += gz
            r[i_acc] += ax
            r[i_acc + lanes] += ay
            r[i_acc + 2 * lanes] += az
            if has_mag:
                r[i_mag] += mx
                r[i_mag + lanes] += my
                r[i_mag + 2 * lanes] += mz
            r[i_count] = count + 1.0
            r[o + RN_DURATION * lanes] += dt
        else:
            r[i_still] = 0.0
            if r[o + RN_DURATION * lanes] < min_rest_s:  # too short to trust: no null
                r[i_total] = r[i_total + lanes] = r[i_total + 2 * lanes] = 0.0
        count = r[i_count]
        # written out: a loop inside a branch stops the vectoriser
        r[i_null] = r[i_total] / count if count > 0.0 else 0.0
        r[i_null + lanes] = r[i_total + lanes] / count if count > 0.0 else 0.0
        r[i_null + 2 * lanes] = r[i_total + 2 * lanes] / count if count > 0.0 else 0.0
    return r[i_null], r[i_null + lanes], r[i_null + 2 * lanes]


@njit(cache=True)
def subtract_rest_null(gyr, acc, mag, dt, blocks, coef, out, null_out):
    """Subtract the initial-rest gyro null from S sensors' gyroscope series.

    gyr, acc (S, N, 3) rad/s, m/s²; mag (S, N, 3) or (S, 0, 3) without a magnetometer;
    dt (N,) s; blocks (S, N_REST_NULL) each sensor's null block, in/out; coef (N_RC,).
    out (S, N, 3): gyr minus null; null_out (S, N, 3): the null used (:func:`step_one`).
    """
    n_sensors, n = gyr.shape[0], gyr.shape[1]
    has_mag = mag.shape[1] == n
    for s in range(n_sensors):
        r = blocks[s]
        for i in range(n):
            mx = my = mz = 0.0
            if has_mag:
                mx, my, mz = mag[s, i, 0], mag[s, i, 1], mag[s, i, 2]
            nx, ny, nz = step_one(
                r, 0, coef, 0, gyr[s, i, 0], gyr[s, i, 1], gyr[s, i, 2],
                acc[s, i, 0], acc[s, i, 1], acc[s, i, 2], mx, my, mz, has_mag, dt[i],
            )
            null_out[s, i, 0], null_out[s, i, 1], null_out[s, i, 2] = nx, ny, nz
            out[s, i, 0] = gyr[s, i, 0] - nx
            out[s, i, 1] = gyr[s, i, 1] - ny
            out[s, i, 2] = gyr[s, i, 2] - nz
