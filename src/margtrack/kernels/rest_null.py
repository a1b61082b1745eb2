"""Compiled kernel: the gyroscope null point measured while the sensor is still at the start.

000 (Appendix B, step 1; "Sensor Calibration") sets each rate sensor's null point to its
reading averaged over a period in which the sensor is stationary. This kernel does that
online for S sensors: from the first sample after a reset it keeps the running mean of the
gyroscope while the sensor stays still, subtracts it, and freezes it at the first sample of
motion. See :mod:`margtrack.filters._rest_null` for the rules and the state.
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True)
def _angle_cos(ax, ay, az, bx, by, bz):
    """Cosine of the angle between two vectors (1.0 if either is zero)."""
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    if na == 0.0 or nb == 0.0:
        return 1.0
    return (ax * bx + ay * by + az * bz) / (na * nb)


@njit(cache=True)
def subtract_rest_null(
    gyr, acc, mag, dt, total, count, duration, acc_sum, mag_sum, still,
    min_rest_s, gyr_tol_rad_s, acc_cos_min, mag_cos_min, max_rate_rad_s, out, null_out,
):  # fmt: skip
    """Subtract the initial-rest gyro null from S sensors' gyroscope series.

    gyr, acc (S, N, 3) rad/s, m/s²; mag (S, N, 3) or (S, 0, 3) without a magnetometer;
    dt (N,) s. State per sensor, updated in place: total (S, 3) sum of the still samples,
    rad/s; count (S,) their number; duration (S,) their time span, s; acc_sum and mag_sum
    (S, 3) the sums of their acc and mag vectors; still (S,) bool, True while the start is
    still. A sample is still when its rate is within ``gyr_tol_rad_s`` of the mean so far
    and its acc (and mag) direction has cosine >= ``acc_cos_min`` (``mag_cos_min``) with
    the mean so far (a mean, not the first sample: magnetometers can be noisy by
    degrees). The null is the running mean while still, the frozen mean after, and 0 if
    the still start lasted less than ``min_rest_s``. A zero acc or mag vector (a screened
    sample) passes its direction test; a rate beyond ``max_rate_rad_s`` (or non-finite)
    is left out without ending the still start.
    out (S, N, 3): gyr minus null; null_out (S, N, 3): the null used.
    """
    n_sensors, n = gyr.shape[0], gyr.shape[1]
    has_mag = mag.shape[1] == n
    for s in range(n_sensors):
        for i in range(n):
            gx, gy, gz = gyr[s, i, 0], gyr[s, i, 1], gyr[s, i, 2]
            sane = abs(gx) <= max_rate_rad_s and abs(gy) <= max_rate_rad_s
            sane = sane and abs(gz) <= max_rate_rad_s
            if still[s] and sane:
                if count[s] == 0:
                    ok = True
                else:
                    c = count[s]
                    ex = gx - total[s, 0] / c
                    ey = gy - total[s, 1] / c
                    ez = gz - total[s, 2] / c
                    ok = ex * ex + ey * ey + ez * ez <= gyr_tol_rad_s * gyr_tol_rad_s
                    ok = ok and _angle_cos(
                        acc[s, i, 0], acc[s, i, 1], acc[s, i, 2],
                        acc_sum[s, 0], acc_sum[s, 1], acc_sum[s, 2],
                    ) >= acc_cos_min
                    if has_mag:
                        ok = ok and _angle_cos(
                            mag[s, i, 0], mag[s, i, 1], mag[s, i, 2],
                            mag_sum[s, 0], mag_sum[s, 1], mag_sum[s, 2],
                        ) >= mag_cos_min
                if ok:
                    total[s, 0] += gx
                    total[s, 1] += gy
                    total[s, 2] += gz
                    for k in range(3):
                        acc_sum[s, k] += acc[s, i, k]
                        if has_mag:
                            mag_sum[s, k] += mag[s, i, k]
                    count[s] += 1
                    duration[s] += dt[i]
                else:
                    still[s] = False
                    if duration[s] < min_rest_s:  # too short to trust: no null
                        total[s, 0] = total[s, 1] = total[s, 2] = 0.0
            c = count[s]
            for k in range(3):
                null = total[s, k] / c if c > 0 else 0.0
                null_out[s, i, k] = null
                out[s, i, k] = gyr[s, i, k] - null
