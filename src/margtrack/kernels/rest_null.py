"""Compiled kernel: the gyroscope null point measured while the sensor is still at the start.

000 (Appendix B, step 1; "Sensor Calibration") sets each rate sensor's null point to its
reading averaged over a period in which the sensor is stationary. This kernel does that
online for S sensors: from the first sample after a reset it keeps the running mean of the
gyroscope while the sensor stays still, subtracts it, and freezes it at the first sample of
motion. See :mod:`margtrack.filters._rest_null` for the rules.

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

from margtrack.kernels.jit import njit

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
def fresh_one(r, o):
    """A null block at ``r[o:o + N_REST_NULL]`` that has seen nothing (still, no null)."""
    for k in range(N_REST_NULL):
        r[o + k] = 0.0
    r[o + RN_STILL] = 1.0


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
    min_rest_s = c[co + RC_MIN_REST]
    if not min_rest_s > 0.0:
        return 0.0, 0.0, 0.0
    max_rate = c[co + RC_MAX_RATE]
    sane = abs(gx) <= max_rate and abs(gy) <= max_rate
    sane = sane and abs(gz) <= max_rate
    if r[o + RN_STILL] != 0.0 and sane:
        count = r[o + RN_COUNT]
        if count == 0.0:
            ok = True
        else:
            tol = c[co + RC_GYR_TOL]
            ex = gx - r[o + RN_TOTAL] / count
            ey = gy - r[o + RN_TOTAL + 1] / count
            ez = gz - r[o + RN_TOTAL + 2] / count
            ok = ex * ex + ey * ey + ez * ez <= tol * tol
            ok = ok and _angle_cos(
                ax, ay, az, r[o + RN_ACC_SUM], r[o + RN_ACC_SUM + 1], r[o + RN_ACC_SUM + 2]
            ) >= c[co + RC_ACC_COS]
            if has_mag:
                ok = ok and _angle_cos(
                    mx, my, mz, r[o + RN_MAG_SUM], r[o + RN_MAG_SUM + 1], r[o + RN_MAG_SUM + 2]
                ) >= c[co + RC_MAG_COS]
        if ok:
            r[o + RN_TOTAL] += gx
            r[o + RN_TOTAL + 1] += gy
            r[o + RN_TOTAL + 2] += gz
            r[o + RN_ACC_SUM] += ax
            r[o + RN_ACC_SUM + 1] += ay
            r[o + RN_ACC_SUM + 2] += az
            if has_mag:
                r[o + RN_MAG_SUM] += mx
                r[o + RN_MAG_SUM + 1] += my
                r[o + RN_MAG_SUM + 2] += mz
            r[o + RN_COUNT] = count + 1.0
            r[o + RN_DURATION] += dt
        else:
            r[o + RN_STILL] = 0.0
            if r[o + RN_DURATION] < min_rest_s:  # too short to trust: no null
                r[o + RN_TOTAL] = r[o + RN_TOTAL + 1] = r[o + RN_TOTAL + 2] = 0.0
        count = r[o + RN_COUNT]
        for k in range(3):
            r[o + RN_NULL + k] = r[o + RN_TOTAL + k] / count if count > 0.0 else 0.0
    return r[o + RN_NULL], r[o + RN_NULL + 1], r[o + RN_NULL + 2]


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
