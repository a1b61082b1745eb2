"""Kernel of the TRIAD single-frame estimator (002 eqs. 1-8; 003 eqs. 10-13).

Also home of the degenerate-sample policy every single-frame kernel shares
(:func:`unit_pair`, :func:`level` and the flag codes): a zero accelerometer vector (no
measurement) repeats the previous orientation; a zero magnetometer vector, or one (nearly)
parallel to the accelerometer, leaves the heading undetermined, so the previous
orientation is levelled onto the measured gravity (inclination from the accelerometer,
heading kept). The public :func:`triad` keeps the plain rule (every flagged sample
repeats the previous output): the contract and the bias Kalman filter rely on it.
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator.jit import njit
from margtrack.estimator.lowpass import prefilter_sensor
from margtrack.estimator.quat_kernel import cross, from_matrix, mul

#: fast-math flags of the kernels: reciprocals, fused multiply-add, reassociation and
#: signless zeros (results change at rounding level); NaN and inf semantics are kept
FASTMATH = {"nsz", "arcp", "contract", "reassoc"}

# Below this |a × m| / (|a| |m|) the two vectors are treated as parallel: their
# cross product no longer defines a horizontal direction (sin of about 0.06 deg).
PARALLEL_SINE = 1e-3

OK = 0
ZERO_ACC = 1
ZERO_MAG = 2
PARALLEL = 3
#: Gauss-Newton/Newton only: the normal equations were singular
SOLVER_FAILED = 4


@njit(cache=True, inline="always")
def unit_pair(ax, ay, az, mx, my, mz):
    """Check and normalise one accelerometer/magnetometer pair.

    Returns ``(flag, âx, ây, âz, m̂x, m̂y, m̂z)``: flag OK, ZERO_ACC, ZERO_MAG or PARALLEL
    (``|â × m̂| < PARALLEL_SINE``); the unit vectors are meaningful only when flag is OK.
    """
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nm = math.sqrt(mx * mx + my * my + mz * mz)
    if not na > 0.0:
        return ZERO_ACC, ax, ay, az, mx, my, mz
    if not nm > 0.0:
        return ZERO_MAG, ax, ay, az, mx, my, mz
    inv_a, inv_m = 1.0 / na, 1.0 / nm
    ax, ay, az = ax * inv_a, ay * inv_a, az * inv_a
    mx, my, mz = mx * inv_m, my * inv_m, mz * inv_m
    cx, cy, cz = cross(ax, ay, az, mx, my, mz)
    if cx * cx + cy * cy + cz * cz < PARALLEL_SINE * PARALLEL_SINE:
        return PARALLEL, ax, ay, az, mx, my, mz
    return OK, ax, ay, az, mx, my, mz


@njit(cache=True, inline="always")
def rotate(w, x, y, z, vx, vy, vz):
    """``q ⊗ v ⊗ q*`` for a unit quaternion q = (w, x, y, z): body vector v to earth."""
    tx, ty, tz = cross(x, y, z, vx, vy, vz)
    tx, ty, tz = 2.0 * tx, 2.0 * ty, 2.0 * tz
    cx, cy, cz = cross(x, y, z, tx, ty, tz)
    return vx + w * tx + cx, vy + w * ty + cy, vz + w * tz + cz


@njit(cache=True, inline="always")
def level(pw, px, py, pz, ax, ay, az, ux, uy, uz):
    """The orientation p levelled onto the measured gravity, heading kept: ``c ⊗ p``.

    p (unit, body to earth) is the previous orientation; (ax, ay, az) the accelerometer
    (any non-zero length, points up at rest); u the unit earth up. c is the shortest arc
    taking ``v = p ⊗ â ⊗ p*`` (where p puts the measured up) onto u: a rotation about the
    horizontal axis ``v × u``, so it has no component about the vertical and the heading
    (the twist of p about up, as the heading error of the metrics measures it) is
    unchanged, while the new orientation maps â exactly onto up. Used where the field
    cannot give a heading (zero, or parallel to the accelerometer). A zero accelerometer
    returns p. Returns (w, x, y, z) with w >= 0.
    """
    na = math.sqrt(ax * ax + ay * ay + az * az)
    if not na > 0.0:
        return pw, px, py, pz
    vx, vy, vz = rotate(pw, px, py, pz, ax / na, ay / na, az / na)
    nv = math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / nv, vy / nv, vz / nv
    d = vx * ux + vy * uy + vz * uz
    cx, cy, cz = cross(vx, vy, vz, ux, uy, uz)
    if d >= 0.0:
        cw = 1.0 + d  # [1 + v·u, v × u]: accurate while the angle is at most 90 deg
    else:
        # the same rotation scaled by (1 - v·u)/|v × u|: [|v × u|, (1 - v·u) axis], which
        # stays accurate up to a half turn (see quaternion.shortest_arc)
        n = math.sqrt(cx * cx + cy * cy + cz * cz)
        if n > 0.0:
            ex, ey, ez = cx / n, cy / n, cz / n
        else:  # upside down exactly: a half turn about a horizontal axis
            if abs(ux) <= abs(uy) and abs(ux) <= abs(uz):
                ex, ey, ez = cross(ux, uy, uz, 1.0, 0.0, 0.0)
            elif abs(uy) <= abs(uz):
                ex, ey, ez = cross(ux, uy, uz, 0.0, 1.0, 0.0)
            else:
                ex, ey, ez = cross(ux, uy, uz, 0.0, 0.0, 1.0)
            ne = math.sqrt(ex * ex + ey * ey + ez * ez)
            ex, ey, ez = ex / ne, ey / ne, ez / ne
        cw, cx, cy, cz = n, (1.0 - d) * ex, (1.0 - d) * ey, (1.0 - d) * ez
    w, x, y, z = mul(cw, cx, cy, cz, pw, px, py, pz)
    inv = math.copysign(1.0, w) / math.sqrt(w * w + x * x + y * y + z * z)
    return w * inv, x * inv, y * inv, z * inv


@njit(cache=True, inline="always")
def reference_triad(ux, uy, uz, nx, ny, nz):
    """Reference triad s1, s2, s3 (002 eqs. 1-3) from earth up and north, as 9 numbers.

    s1 = up, s2 = up × north / |.|, s3 = s1 × s2 (for a horizontal north, s3 = north).
    """
    s2x, s2y, s2z = cross(ux, uy, uz, nx, ny, nz)
    n = math.sqrt(s2x * s2x + s2y * s2y + s2z * s2z)
    s2x, s2y, s2z = s2x / n, s2y / n, s2z / n
    s3x, s3y, s3z = cross(ux, uy, uz, s2x, s2y, s2z)
    return ux, uy, uz, s2x, s2y, s2z, s3x, s3y, s3z


@njit(cache=True, inline="always")
def triad_unit(ax, ay, az, mx, my, mz, s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z):
    """TRIAD quaternion (w >= 0, body to earth) of a checked unit pair (flag OK).

    Measurement triad (002 eqs. 4-6): r1 = â, r2 = â × m̂ / |.|, r3 = r1 × r2;
    ``R_body_to_earth = M_ref M_mea^T = s1 r1^T + s2 r2^T + s3 r3^T``, the transpose of
    002's A (eq. 8, which maps earth to body; 003 eq. 13 is the same matrix).
    """
    r2x, r2y, r2z = cross(ax, ay, az, mx, my, mz)
    n2 = math.sqrt(r2x * r2x + r2y * r2y + r2z * r2z)
    r2x, r2y, r2z = r2x / n2, r2y / n2, r2z / n2
    r3x, r3y, r3z = cross(ax, ay, az, r2x, r2y, r2z)
    return from_matrix(
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


@njit(cache=True, fastmath=FASTMATH)
def triad(acc, mag, up, north, quat_out, flags):
    """TRIAD orientation (body to earth) for N samples of one sensor, without prefilter.

    acc (N, 3) specific force (points up at rest), mag (N, 3) field, any units;
    up (3,) unit earth-frame up vector; north (3,) unit horizontal earth-frame north.
    quat_out (N, 4) filled with w >= 0; flags (N,) int8: 0 ok, 1 zero acc, 2 zero mag,
    3 acc parallel to mag. A flagged sample repeats the previous output (identity if none).

    With the first triad built on gravity, r1 = â and s1 = up (002 eqs. 1 and 4), so the
    magnetometer only sets the rotation about the vertical (heading).
    """
    s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z = reference_triad(
        up[0], up[1], up[2], north[0], north[1], north[2]
    )
    pw, px, py, pz = 1.0, 0.0, 0.0, 0.0
    for i in range(acc.shape[0]):
        flag, ax, ay, az, mx, my, mz = unit_pair(
            acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2]
        )
        flags[i] = flag
        if flag == OK:
            pw, px, py, pz = triad_unit(
                ax, ay, az, mx, my, mz, s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z
            )
        quat_out[i, 0], quat_out[i, 1], quat_out[i, 2], quat_out[i, 3] = pw, px, py, pz


@njit(cache=True, fastmath=FASTMATH)
def _triad_sensor(acc, mag, s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z, quat_state,
                  quat_out, flags):
    """TRIAD over one sensor's (N, 3) series; quat_state (4,) in/out.

    A zero accelerometer holds the previous orientation; a zero or parallel field levels
    it (:func:`level`; s1 is up).
    """
    pw, px, py, pz = quat_state[0], quat_state[1], quat_state[2], quat_state[3]
    for i in range(acc.shape[0]):
        flag, ax, ay, az, mx, my, mz = unit_pair(
            acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2]
        )
        flags[i] = flag
        if flag == OK:
            pw, px, py, pz = triad_unit(
                ax, ay, az, mx, my, mz, s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z
            )
        elif flag != ZERO_ACC:
            pw, px, py, pz = level(pw, px, py, pz, ax, ay, az, s1x, s1y, s1z)
        quat_out[i, 0], quat_out[i, 1], quat_out[i, 2], quat_out[i, 3] = pw, px, py, pz
    quat_state[0], quat_state[1], quat_state[2], quat_state[3] = pw, px, py, pz


@njit(cache=True)
def triad_run(
    acc, mag, dt, up, north, acc_cutoff_hz, mag_cutoff_hz, order,
    quat_state, lowpass_history, lowpass_ready, quat_out, flags,
):
    """TRIAD for S sensors and N samples, with the optional low-pass prefilter.

    acc, mag (S, N, 3) any units; dt (N,) s; up, north (3,) unit earth vectors;
    acc_cutoff_hz, mag_cutoff_hz: prefilter cut-offs (0 = off), order 1 or 2;
    quat_state (S, 4), lowpass_history (S, 2, 4, 3), lowpass_ready (S, 2): state, in/out;
    quat_out (S, N, 4) filled with w >= 0; flags (S, N) int8 (see :func:`unit_pair`).
    A zero accelerometer repeats the previous orientation (the state's before the first);
    a zero or parallel field levels it onto the measured gravity (:func:`level`). All-zero
    vectors are the input screening's "no measurement"; the prefilter passes them through.
    """
    s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z = reference_triad(
        up[0], up[1], up[2], north[0], north[1], north[2]
    )
    filtering = acc_cutoff_hz > 0.0 or mag_cutoff_hz > 0.0
    n = acc.shape[1] if filtering else 0
    acc_f, mag_f = np.empty((n, 3)), np.empty((n, 3))
    for s in range(acc.shape[0]):
        if filtering:
            prefilter_sensor(acc[s], mag[s], dt, acc_cutoff_hz, mag_cutoff_hz, order,
                             lowpass_history[s], lowpass_ready[s], acc_f, mag_f)
            _triad_sensor(acc_f, mag_f, s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z,
                          quat_state[s], quat_out[s], flags[s])
        else:
            lowpass_ready[s, 0] = lowpass_ready[s, 1] = False
            _triad_sensor(acc[s], mag[s], s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z,
                          quat_state[s], quat_out[s], flags[s])
