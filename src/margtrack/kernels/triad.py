"""Kernel of the TRIAD single-frame estimator (002 eqs. 1-8; 003 eqs. 10-13)."""

from __future__ import annotations

import math

from numba import njit

from margtrack.kernels._quat import cross, from_matrix

# Below this |a × m| / (|a| |m|) the two vectors are treated as parallel: their
# cross product no longer defines a horizontal direction (sin of about 0.06 deg).
PARALLEL_SINE = 1e-3

OK = 0
ZERO_ACC = 1
ZERO_MAG = 2
PARALLEL = 3


@njit(cache=True)
def triad(acc, mag, up, north, quat_out, flags):
    """TRIAD orientation (body to earth) for N samples.

    acc (N, 3) specific force (points up at rest), mag (N, 3) field, any units;
    up (3,) unit earth-frame up vector; north (3,) unit horizontal earth-frame north.
    quat_out (N, 4) filled with w >= 0; flags (N,) int8: 0 ok, 1 zero acc, 2 zero mag,
    3 acc parallel to mag. A flagged sample repeats the previous output (identity if none).

    With the first triad built on gravity, r1 = â and s1 = up (002 eqs. 1 and 4), so the
    magnetometer only sets the rotation about the vertical (heading).
    ``R_body_to_earth = M_ref M_mea^T``, the transpose of 002's A (eq. 8).
    """
    # reference triad (002 eqs. 1-3): s1 = up, s2 = up × north / |.|, s3 = s1 × s2
    s1x, s1y, s1z = up[0], up[1], up[2]
    s2x, s2y, s2z = cross(s1x, s1y, s1z, north[0], north[1], north[2])
    n = math.sqrt(s2x * s2x + s2y * s2y + s2z * s2z)
    s2x, s2y, s2z = s2x / n, s2y / n, s2z / n
    s3x, s3y, s3z = cross(s1x, s1y, s1z, s2x, s2y, s2z)
    pw, px, py, pz = 1.0, 0.0, 0.0, 0.0
    for i in range(acc.shape[0]):
        ax, ay, az = acc[i, 0], acc[i, 1], acc[i, 2]
        mx, my, mz = mag[i, 0], mag[i, 1], mag[i, 2]
        na = math.sqrt(ax * ax + ay * ay + az * az)
        nm = math.sqrt(mx * mx + my * my + mz * mz)
        flag = OK
        if not na > 0.0:
            flag = ZERO_ACC
        elif not nm > 0.0:
            flag = ZERO_MAG
        else:
            ax, ay, az = ax / na, ay / na, az / na
            r2x, r2y, r2z = cross(ax, ay, az, mx / nm, my / nm, mz / nm)
            n2 = math.sqrt(r2x * r2x + r2y * r2y + r2z * r2z)
            if n2 < PARALLEL_SINE:
                flag = PARALLEL
        flags[i] = flag
        if flag == OK:
            r2x, r2y, r2z = r2x / n2, r2y / n2, r2z / n2
            r3x, r3y, r3z = cross(ax, ay, az, r2x, r2y, r2z)
            # R = s1 r1^T + s2 r2^T + s3 r3^T
            pw, px, py, pz = from_matrix(
                s1x * ax + s2x * r2x + s3x * r3x,
                s1x * ay + s2x * r2y + s3x * r3y,
                s1x * az + s2x * r2z + s3x * r3z,
                s1y * ax + s2y * r2x + s3y * r3x,
                s1y * ay + s2y * r2y + s3y * r3y,
                s1y * az + s2y * r2z + s3y * r3z,
                s1z * ax + s2z * r2x + s3z * r3x,
                s1z * ay + s2z * r2y + s3z * r3y,
                s1z * az + s2z * r2z + s3z * r3z,
            )
        quat_out[i, 0] = pw
        quat_out[i, 1] = px
        quat_out[i, 2] = py
        quat_out[i, 3] = pz
