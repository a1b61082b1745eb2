"""Kernel of the factored quaternion algorithm, FQA (002 section II, eqs. 17-46).

The orientation is factored as ``q = q_a ⊗ q_e ⊗ q_r`` (azimuth, elevation, roll; 002
eq. 41), each a rotation about one axis whose half-angle cosine and sine come from the
measured vectors by square roots only: no trigonometric call anywhere. The derivation is
in NED (x north, y east, z down); an ENU output is the fixed frame rotation applied after.
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator.jit import njit
from margtrack.estimator.lowpass import prefilter_sensor
from margtrack.estimator.quat_kernel import mul
from margtrack.estimator.triad_kernel import FASTMATH, OK, ZERO_ACC, level, rotate, unit_pair


@njit(cache=True, inline="always")
def half_angle(c, s):
    """(cos(x/2), sin(x/2)) from (cos x, sin x), x in (-π, π], so cos(x/2) >= 0.

    002 eqs. 23-24 give each half from the full cosine with a square root, the sine's sign
    from ``sign(sin x)`` with ``sign(0) = +1`` (so x = π gives (0, 1), not (0, 0)). Taken
    literally, ``sqrt((1 - cos x) / 2)`` loses half the digits for small x (cos x rounds to
    1; 1e-8 rad comes out as 0) and ``sqrt((1 + cos x) / 2)`` does near x = π. Here only
    the well-conditioned one of the pair is taken from eq. 23 or 24 (the one whose radicand
    is >= 1/2) and the other from ``sin x = 2 sin(x/2) cos(x/2)``: the same half angles,
    still without trigonometric calls, exact to rounding everywhere.
    """
    if c >= 0.0:
        c2 = math.sqrt(0.5 * (1.0 + c))  # (002 eq. 24)
        return c2, s / (2.0 * c2)
    s2 = math.sqrt(0.5 * (1.0 - c))  # (002 eq. 23), sign(0) = +1
    if s < 0.0:
        s2 = -s2
    return s / (2.0 * s2), s2


@njit(cache=True, inline="always")
def fqa_unit(ax, ay, az, mx, my, mz, epsilon, cos_half_alpha, sin_half_alpha):
    """FQA orientation in NED of a checked unit pair: (switched, w, x, y, z).

    â (3) unit specific force in the body frame (points up at rest), m̂ (3) unit field.
    ``switched`` is True when ``cos θ < epsilon``: the vectors are then replaced by those
    of a virtual sensor turned by α about the body y axis (002 eqs. 43-45) and the result
    turned back (eq. 46).
    """
    cos_t = math.sqrt(ay * ay + az * az)  # (002 eq. 22): = sqrt(1 - sin²θ) for a unit â
    switched = cos_t < epsilon
    if switched:
        # (002 eqs. 43-45): v' = q_α v q_α*, q_α = cos(α/2) + sin(α/2) j: v' = R_y(α) v
        ca = cos_half_alpha * cos_half_alpha - sin_half_alpha * sin_half_alpha
        sa = 2.0 * cos_half_alpha * sin_half_alpha
        ax, az = ca * ax + sa * az, -sa * ax + ca * az
        mx, mz = ca * mx + sa * mz, -sa * mx + ca * mz
        cos_t = math.sqrt(ay * ay + az * az)
    # elevation (002 eqs. 21-25)
    sin_t = ax  # (002 eq. 21)
    ce, se = half_angle(cos_t, sin_t)
    # roll (002 eqs. 28-32); with x vertical roll is undefined and taken as 0
    if cos_t > 0.0:
        sin_r, cos_r = -ay / cos_t, -az / cos_t  # (002 eqs. 30-31)
    else:
        sin_r, cos_r = 0.0, 1.0
    cr, sr = half_angle(cos_r, sin_r)
    # azimuth (002 eqs. 33-40): e_m = q_e q_r m q_r* q_e* = R_y(θ) R_x(φ) m (eq. 34)
    ux, uy, uz = mx, cos_r * my - sin_r * mz, sin_r * my + cos_r * mz
    ex, ey = cos_t * ux + sin_t * uz, uy
    h = math.sqrt(ex * ex + ey * ey)  # > 0: unit_pair refused parallel â, m̂
    big_mx, big_my = ex / h, ey / h  # (002 eq. 37)
    # (002 eq. 39) with the normalised horizontal reference N = (1, 0), north in NED (eq. 36)
    cos_a, sin_a = big_mx, -big_my
    ca2, sa2 = half_angle(cos_a, sin_a)
    # q = q_a ⊗ q_e ⊗ q_r (002 eq. 41), q_a = (ca2, 0, 0, sa2), q_e = (ce, 0, se, 0),
    # q_r = (cr, sr, 0, 0), written out
    w, x, y, z = ce * cr, ce * sr, se * cr, -se * sr
    w, x, y, z = ca2 * w - sa2 * z, ca2 * x - sa2 * y, ca2 * y + sa2 * x, ca2 * z + sa2 * w
    if switched:
        # (002 eq. 46): q = q_alt ⊗ q_α
        w, x, y, z = mul(w, x, y, z, cos_half_alpha, 0.0, sin_half_alpha, 0.0)
    return switched, w, x, y, z


@njit(cache=True, fastmath=FASTMATH)
def _fqa_sensor(acc, mag, fw, fx, fy, fz, epsilon, cos_half_alpha, sin_half_alpha,
                quat_state, quat_out, flags, switched_out):
    """FQA over one sensor's (N, 3) series; quat_state (4,) in/out.

    A zero accelerometer holds the previous orientation; a zero or parallel field levels
    it onto the measured gravity (``triad.level``), heading kept.
    """
    # earth up in the output frame: NED's (0, 0, -1) turned by the frame rotation
    ux, uy, uz = rotate(fw, fx, fy, fz, 0.0, 0.0, -1.0)
    pw, px, py, pz = quat_state[0], quat_state[1], quat_state[2], quat_state[3]
    for i in range(acc.shape[0]):
        flag, ax, ay, az, mx, my, mz = unit_pair(
            acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2]
        )
        flags[i] = flag
        switched = False
        if flag == OK:
            switched, w, x, y, z = fqa_unit(
                ax, ay, az, mx, my, mz, epsilon, cos_half_alpha, sin_half_alpha
            )
            w, x, y, z = mul(fw, fx, fy, fz, w, x, y, z)  # NED to the output frame
            inv = math.copysign(1.0, w) / math.sqrt(w * w + x * x + y * y + z * z)
            pw, px, py, pz = w * inv, x * inv, y * inv, z * inv
        elif flag != ZERO_ACC:
            pw, px, py, pz = level(pw, px, py, pz, ax, ay, az, ux, uy, uz)
        switched_out[i] = switched
        quat_out[i, 0], quat_out[i, 1], quat_out[i, 2], quat_out[i, 3] = pw, px, py, pz
    quat_state[0], quat_state[1], quat_state[2], quat_state[3] = pw, px, py, pz


@njit(cache=True)
def fqa_run(
    acc, mag, dt, frame_quat, epsilon, cos_half_alpha, sin_half_alpha,
    acc_cutoff_hz, mag_cutoff_hz, order,
    quat_state, lowpass_history, lowpass_ready, quat_out, flags, switched_out,
):
    """FQA for S sensors and N samples, with the optional low-pass prefilter.

    acc, mag (S, N, 3) any units; dt (N,) s; frame_quat (4,): rotation from NED to the
    output frame applied on the left (identity for NED); epsilon: switch threshold on
    cos θ; cos/sin_half_alpha: half of the virtual sensor's offset angle α;
    acc/mag_cutoff_hz (0 = off), order: prefilter; quat_state (S, 4), lowpass_history
    (S, 2, 4, 3), lowpass_ready (S, 2): state, in/out. Fills quat_out (S, N, 4) with unit
    quaternions, w >= 0; flags (S, N) int8 (see ``unit_pair``); switched_out (S, N) bool.
    A zero accelerometer (the screening's "no measurement") repeats the previous
    orientation; a zero or parallel field levels it (inclination from the accelerometer,
    heading kept).
    """
    fw, fx, fy, fz = frame_quat[0], frame_quat[1], frame_quat[2], frame_quat[3]
    filtering = acc_cutoff_hz > 0.0 or mag_cutoff_hz > 0.0
    n = acc.shape[1] if filtering else 0
    acc_f, mag_f = np.empty((n, 3)), np.empty((n, 3))
    for s in range(acc.shape[0]):
        if filtering:
            prefilter_sensor(acc[s], mag[s], dt, acc_cutoff_hz, mag_cutoff_hz, order,
                             lowpass_history[s], lowpass_ready[s], acc_f, mag_f)
            _fqa_sensor(acc_f, mag_f, fw, fx, fy, fz, epsilon, cos_half_alpha, sin_half_alpha,
                        quat_state[s], quat_out[s], flags[s], switched_out[s])
        else:
            lowpass_ready[s, 0] = lowpass_ready[s, 1] = False
            _fqa_sensor(acc[s], mag[s], fw, fx, fy, fz, epsilon, cos_half_alpha,
                        sin_half_alpha, quat_state[s], quat_out[s], flags[s], switched_out[s])
