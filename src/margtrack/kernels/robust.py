# ruff: noqa: F405  (names from robust_layout's star import)
"""Kernel of margtrack's robust filter (``filters/robust.py``), on ``kernels/contract.py``.

Internally everything is computed in ENU; the output is rotated to NED at the end when
asked. Orientation is factored as ``q9 = q_z(heading) ⊗ q_acc ⊗ q_gyr`` (the factoring of
FQA, 002, where heading is kept apart from inclination):

- ``q_gyr``: strapdown integration of the bias-corrected gyro, body to a quasi-inertial
  frame I that drifts only as slowly as the bias error;
- ``q_acc``: I to a level frame, corrected so that the accelerometer, low-pass filtered in
  I (where linear acceleration of a moving person averages out but gravity does not),
  points up;
- ``heading``: rotation about the vertical from the level frame to the earth frame, from
  the horizontal magnetometer direction only (004's vector rejection), skipped while the
  field's norm or dip disagrees with its tracked reference.

Start-up (after the first sample and after every restart): the heading gain is ``1/n``
for its n-th measurement since the start (the initial orientation counting as the first)
while that exceeds the nominal gain and for at most ``converge_s``, as VQF does at
start-up: the heading is the mean of the measurements so far, so a start sample taken
during motion stops dominating it after a second or two instead of after several
``tau_mag`` (20 s). The accelerometer low-pass starts at its first sample, steady (a mean
of the first seconds was tried: it lets a periodic motion's linear acceleration through,
49 deg of tilt on a 1 Hz limb swing, against 2 deg from the start sample).

The row layout, coefficients and outputs are in ``kernels/robust_layout.py``; the
interval-dependent gains in ``kernels/robust_gains.py``.

``_step`` returns the flag bits ``REST`` and ``MAG_DISTURBED``; its extra outputs
(``x_out``, ``N_OUT``) are the 6-D quaternion (4, output frame), the bias (3, rad/s) and
its standard deviation (3, rad/s).
"""

from __future__ import annotations

import math

from margtrack.kernels import contract
from margtrack.kernels._quat import exp_half, mul, normalized
from margtrack.kernels.jit import njit
from margtrack.kernels.robust_gains import (  # noqa: F401 (butterworth_coefficients: kernel.*)
    _bw_hold,
    _bw_step,
    _gains,
    butterworth_coefficients,
)
from margtrack.kernels.robust_layout import *  # noqa: F403 (the layout, as this module's)

_H = math.sqrt(0.5)  # ENU <-> NED: q_ned = (0, h, h, 0) ⊗ q_enu, and back the same way


@njit(cache=True, inline="always")
def _rotate(w, x, y, z, vx, vy, vz):
    """q ⊗ v ⊗ q* for unit q."""
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (
        vx + w * tx + y * tz - z * ty,
        vy + w * ty + z * tx - x * tz,
        vz + w * tz + x * ty - y * tx,
    )


@njit(cache=True, inline="always")
def _wrap(angle):
    """An angle in (-3 pi, 3 pi) wrapped to [-pi, pi] (the differences and sums of two
    wrapped angles here); the same as ``atan2(sin, cos)`` to rounding, at a fraction of
    its cost."""
    if angle > math.pi:
        return angle - 2.0 * math.pi
    if angle < -math.pi:
        return angle + 2.0 * math.pi
    return angle


@njit(cache=True, inline="always")
def _sensor(row, coef):
    """What is known of a sensor before its first sample: bias 0 with the initial
    variance, the field reference as given (or none)."""
    var0 = coef[C_BIAS_SIGMA0] ** 2
    for k in range(3):
        row[R_BIAS + k] = 0.0
        row[R_BIAS_VAR + k] = var0
        row[R_BIAS_SD + k] = math.sqrt(var0)
    row[R_MAG_NORM_REF] = coef[C_MAG_NORM_REF0]
    row[R_MAG_DIP_REF] = coef[C_MAG_DIP_REF0]
    row[R_CAND_NORM] = 0.0
    row[R_CAND_DIP] = math.nan
    row[R_CAND_S] = 0.0


@njit(cache=True)
def fresh(rows, coefs):
    """Rows (S, N_ROW) of sensors that have seen nothing: the sensor part (``_sensor``)."""
    coef = coefs[contract.N_SCOEF :]
    for s in range(rows.shape[0]):
        _sensor(rows[s], coef)


@njit(cache=True, inline="always")
def _start(row, coef, first, qw, qx, qy, qz):
    """(Re)start at q (output frame): the orientation, low-passes, rest detector and
    start-up afresh; the bias and the field reference only the first time."""
    if first:
        _sensor(row, coef)
    if coef[C_NED] > 0.5:
        qw, qx, qy, qz = mul(0.0, _H, _H, 0.0, qw, qx, qy, qz)  # to ENU
    row[R_Q_GYR], row[R_Q_GYR + 1], row[R_Q_GYR + 2], row[R_Q_GYR + 3] = 1.0, 0.0, 0.0, 0.0
    row[R_Q_ACC], row[R_Q_ACC + 1], row[R_Q_ACC + 2], row[R_Q_ACC + 3] = qw, qx, qy, qz
    row[R_HEADING] = 0.0
    for k in range(3):
        row[R_ACC_LP + k] = 0.0
        row[R_GYR_REST + k] = 0.0
        row[R_ACC_REST + k] = 0.0
    for k in range(6):
        row[R_ACC_LP_BW + k] = 0.0
    row[R_LP_STAGE] = LP_EMPTY
    row[R_SINCE_START] = 0.0
    row[R_HEADING_N] = 1.0
    row[R_STILL] = 0.0


@njit(cache=True, inline="always")
def _outputs(row, ned, q6w, q6x, q6y, q6z, x_out):
    """x_out: the 6-D quaternion (ENU in; to NED when ``ned``), bias and its deviation."""
    if ned:
        q6w, q6x, q6y, q6z = mul(0.0, _H, _H, 0.0, q6w, q6x, q6y, q6z)
    x_out[X_QUAT6], x_out[X_QUAT6 + 1] = q6w, q6x
    x_out[X_QUAT6 + 2], x_out[X_QUAT6 + 3] = q6y, q6z
    for k in range(3):
        x_out[X_BIAS + k] = row[R_BIAS + k]
        x_out[X_BIAS_SD + k] = row[R_BIAS_SD + k]


@njit(cache=True, inline="always")
def _hold(row, coef, x_out):
    """Extra outputs of the current state (before the first start: the held quaternion)."""
    if row[contract.K_STARTS] == 0.0:
        q = contract.K_Q
        _outputs(row, False, row[q], row[q + 1], row[q + 2], row[q + 3], x_out)
        return
    c, g = R_Q_ACC, R_Q_GYR
    q6w, q6x, q6y, q6z = mul(row[c], row[c + 1], row[c + 2], row[c + 3],
                             row[g], row[g + 1], row[g + 2], row[g + 3])  # fmt: skip
    _outputs(row, coef[C_NED] > 0.5, q6w, q6x, q6y, q6z, x_out)


@njit(cache=True, inline="always")
def _rest(row, coef, gains, step, g0, g1, g2, a0, a1, a2, acc_ok):
    """Rest detection (small deviation from slow means, small rate) and, at rest, the
    bias update from the gyro's slow mean; returns whether at rest. ``gains``: the offset
    of the interval's gains (:func:`_gains`)."""
    k_rest = row[gains + G_K_REST]
    bias_max = coef[C_BIAS_MAX]
    gr0 = row[R_GYR_REST] + k_rest * (g0 - row[R_GYR_REST])
    gr1 = row[R_GYR_REST + 1] + k_rest * (g1 - row[R_GYR_REST + 1])
    gr2 = row[R_GYR_REST + 2] + k_rest * (g2 - row[R_GYR_REST + 2])
    row[R_GYR_REST], row[R_GYR_REST + 1], row[R_GYR_REST + 2] = gr0, gr1, gr2
    dev_g = (g0 - gr0) ** 2 + (g1 - gr1) ** 2 + (g2 - gr2) ** 2
    still = (
        dev_g < coef[C_REST_GYR] ** 2
        and abs(gr0) < bias_max
        and abs(gr1) < bias_max
        and abs(gr2) < bias_max
    )
    if acc_ok:
        ar0 = row[R_ACC_REST] + k_rest * (a0 - row[R_ACC_REST])
        ar1 = row[R_ACC_REST + 1] + k_rest * (a1 - row[R_ACC_REST + 1])
        ar2 = row[R_ACC_REST + 2] + k_rest * (a2 - row[R_ACC_REST + 2])
        row[R_ACC_REST], row[R_ACC_REST + 1], row[R_ACC_REST + 2] = ar0, ar1, ar2
        dev_a = (a0 - ar0) ** 2 + (a1 - ar1) ** 2 + (a2 - ar2) ** 2
        still = still and dev_a < coef[C_REST_ACC] ** 2
        row[R_STILL] = row[R_STILL] + step if still else 0.0
    elif not still:
        row[R_STILL] = 0.0  # without an accelerometer the gyro alone can end rest
    rest = still and row[R_STILL] >= coef[C_REST_MIN_T]
    if rest:
        # at rest the gyro reads its bias: a Kalman update per axis (Ang's bias states, 003)
        r = coef[C_BIAS_REST_NOISE] ** 2
        for k in range(3):
            p = row[R_BIAS_VAR + k]
            gain = p / (p + r)
            row[R_BIAS + k] += gain * (row[R_GYR_REST + k] - row[R_BIAS + k])
            row[R_BIAS_VAR + k] = (1.0 - gain) * p
    return rest


@njit(cache=True, inline="always")
def _incline(row, coef, gains, step, a0, a1, a2, rest):
    """The low-passed accelerometer in I must point up: q_acc corrected by the shortest
    arc (004); in motion the applied correction rate is a bias measurement."""
    gw, gx, gy, gz = row[R_Q_GYR], row[R_Q_GYR + 1], row[R_Q_GYR + 2], row[R_Q_GYR + 3]
    cw, cx, cy, cz = row[R_Q_ACC], row[R_Q_ACC + 1], row[R_Q_ACC + 2], row[R_Q_ACC + 3]
    bb0, ba1, ba2 = row[gains + G_BW], row[gains + G_BW + 1], row[gains + G_BW + 2]
    bw = R_ACC_LP_BW
    if row[R_LP_STAGE] == LP_FIRST:
        # start the low-pass steady at the first sample
        for k in range(3):
            row[bw + 2 * k], row[bw + 2 * k + 1] = _bw_hold(bb0, ba1, ba2, row[R_ACC_LP + k])
        row[R_LP_STAGE] = LP_FILTER
    ex, ey, ez = _rotate(gw, gx, gy, gz, a0, a1, a2)
    l0, row[bw], row[bw + 1] = _bw_step(bb0, ba1, ba2, row[bw], row[bw + 1], ex)
    l1, row[bw + 2], row[bw + 3] = _bw_step(bb0, ba1, ba2, row[bw + 2], row[bw + 3], ey)
    l2, row[bw + 4], row[bw + 5] = _bw_step(bb0, ba1, ba2, row[bw + 4], row[bw + 5], ez)
    row[R_ACC_LP], row[R_ACC_LP + 1], row[R_ACC_LP + 2] = l0, l1, l2
    lx, ly, lz = _rotate(cw, cx, cy, cz, l0, l1, l2)
    norm = math.sqrt(lx * lx + ly * ly + lz * lz)
    if not norm > 0.0:
        return
    lx, ly, lz = lx / norm, ly / norm, lz / norm
    # shortest arc taking (lx, ly, lz) to up = [0, 0, 1] (004)
    if lz > -0.999999:
        sq = math.sqrt(2.0 * (1.0 + lz))
        rw, rx, ry = 0.5 * sq, ly / sq, -lx / sq
    else:
        rw, rx, ry = 0.0, 1.0, 0.0
    cw, cx, cy, cz = mul(rw, rx, ry, 0.0, cw, cx, cy, cz)
    cw, cx, cy, cz = normalized(cw, cx, cy, cz)
    row[R_Q_ACC], row[R_Q_ACC + 1], row[R_Q_ACC + 2], row[R_Q_ACC + 3] = cw, cx, cy, cz
    if rest:
        return
    # the applied correction rate (level frame), seen in the body, is minus the
    # horizontal bias error: a bias measurement in motion
    q6w, q6x, q6y, q6z = mul(cw, cx, cy, cz, gw, gx, gy, gz)
    ux, uy, uz = _rotate(q6w, -q6x, -q6y, -q6z, 2.0 * rx / step, 2.0 * ry / step, 0.0)
    # only the horizontal components are observed: weight by how much of each body axis
    # lies in the horizontal plane
    vx, vy, vz = _rotate(q6w, -q6x, -q6y, -q6z, 0.0, 0.0, 1.0)
    r = coef[C_BIAS_MOTION_NOISE] ** 2
    for k, u, v in ((0, ux, vx), (1, uy, vy), (2, uz, vz)):
        horizontal = 1.0 - v * v
        if horizontal > 1e-3:
            p = row[R_BIAS_VAR + k]
            gain = p * horizontal / (p * horizontal + r)
            row[R_BIAS + k] -= gain * u
            row[R_BIAS_VAR + k] = (1.0 - gain * horizontal) * p


@njit(cache=True, inline="always")
def _heading(row, coef, gains, step, q6w, q6x, q6y, q6z, m0, m1, m2):
    """Heading from the horizontal field (004's vector rejection), unless the field's norm
    or dip disagrees with the tracked reference; returns whether it did (disturbed).
    ``gains``: the offset of the interval's gains (:func:`_gains`; read only when step > 0)."""
    mx, my, mz = _rotate(q6w, q6x, q6y, q6z, m0, m1, m2)
    m_norm = math.sqrt(mx * mx + my * my + mz * mz)
    horizontal = math.sqrt(mx * mx + my * my)
    # an all-zero sample (no measurement) has m_norm == 0: skipped
    usable = m_norm > 0.0 and horizontal > 1e-6 * m_norm
    disturbed = False
    if usable:
        dip = math.atan2(-mz, horizontal)
        if row[R_MAG_NORM_REF] <= 0.0:
            row[R_MAG_NORM_REF] = m_norm
            row[R_CAND_NORM] = m_norm
        if math.isnan(row[R_MAG_DIP_REF]):
            row[R_MAG_DIP_REF] = dip
            row[R_CAND_DIP] = dip
        ref_n, ref_d = row[R_MAG_NORM_REF], row[R_MAG_DIP_REF]
        disturbed = (
            abs(m_norm - ref_n) > coef[C_MAG_NORM_TOL] * ref_n
            or abs(dip - ref_d) > coef[C_MAG_DIP_TOL]
        )
        if step > 0.0:
            k_ref = row[gains + G_K_REF]
            if not disturbed:
                row[R_MAG_NORM_REF] = ref_n + k_ref * (m_norm - ref_n)
                row[R_MAG_DIP_REF] = ref_d + k_ref * (dip - ref_d)
                row[R_CAND_NORM] = m_norm
                row[R_CAND_DIP] = dip
                row[R_CAND_S] = 0.0
                # a fixed time constant: an adaptive (Kalman) gain that grows after fast
                # turns or rejected disturbances was measured worse on BROAD, re-acquiring
                # still-distorted fields too quickly. Start-up: the mean of the
                # measurements while 1/n is larger
                k = row[gains + G_K_MAG]
                if row[R_SINCE_START] < coef[C_CONVERGE]:
                    row[R_HEADING_N] += 1.0
                    k = max(k, 1.0 / row[R_HEADING_N])
                # angle of the horizontal field from north (+y) towards east (+x)
                field_heading = math.atan2(mx, my)
                head = row[R_HEADING]
                row[R_HEADING] = _wrap(head + k * _wrap(field_heading - head))
            else:
                # a new, steady field: track a candidate and adopt it once it has stayed
                # consistent for long enough (a new environment)
                cand_n, cand_d = row[R_CAND_NORM], row[R_CAND_DIP]
                steady = (
                    abs(m_norm - cand_n) < coef[C_MAG_NORM_TOL] * cand_n
                    and abs(dip - cand_d) < coef[C_MAG_DIP_TOL]
                )
                if steady:
                    row[R_CAND_S] += step
                    row[R_CAND_NORM] = cand_n + k_ref * (m_norm - cand_n)
                    row[R_CAND_DIP] = cand_d + k_ref * (dip - cand_d)
                else:
                    row[R_CAND_S] = 0.0
                    row[R_CAND_NORM] = m_norm
                    row[R_CAND_DIP] = dip
                if row[R_CAND_S] > coef[C_MAG_NEW_REF_T]:
                    row[R_MAG_NORM_REF] = row[R_CAND_NORM]
                    row[R_MAG_DIP_REF] = row[R_CAND_DIP]
                    row[R_CAND_S] = 0.0
    if row[R_SINCE_START] == 0.0 and row[R_HEADING_N] == 1.0 and (disturbed or not usable):
        # a start without an undisturbed field: its heading is no measurement, the first
        # one replaces it
        row[R_HEADING_N] = 0.0
    return disturbed


@njit(cache=True, _nrt=False)
def _step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """One screened sample (an all-zero acc or mag: no measurement; dt 0: nothing to
    integrate): q_out the 9-D (6-D without a field) orientation; returns REST and
    MAG_DISTURBED bits. Called, not inlined (numba's inliner copies an inlined body's
    variables once per block: the entry points compiled in 104 s, now 56 s; same results to
    the bit, no measurable cost); no reference counting: it creates no arrays."""
    acc_ok = a0 != 0.0 or a1 != 0.0 or a2 != 0.0
    if acc_ok and row[R_LP_STAGE] == LP_EMPTY:
        # the first usable sample since the start: it starts both low-passes (q_gyr is
        # the identity at a start, so I is the body frame then)
        g = R_Q_GYR
        row[R_ACC_LP], row[R_ACC_LP + 1], row[R_ACC_LP + 2] = _rotate(
            row[g], row[g + 1], row[g + 2], row[g + 3], a0, a1, a2
        )
        row[R_ACC_REST], row[R_ACC_REST + 1], row[R_ACC_REST + 2] = a0, a1, a2
        row[R_LP_STAGE] = LP_FIRST
        acc_ok = False  # used: not filtered a second time below
    rest = False
    gains = R_GAINS + int(row[R_GAINS_IN_USE])  # the slot in use (read only when dt > 0)
    if dt > 0.0:
        gains = _gains(row, coef, dt)
        row[R_SINCE_START] += dt
        # -- strapdown: q_gyr ⊗ exp((ω - b) dt / 2); the bias walks between measurements
        b = R_BIAS
        dw, dx, dy, dz = exp_half(g0 - row[b], g1 - row[b + 1], g2 - row[b + 2], dt)
        g = R_Q_GYR
        gw, gx, gy, gz = mul(row[g], row[g + 1], row[g + 2], row[g + 3], dw, dx, dy, dz)
        row[g], row[g + 1], row[g + 2], row[g + 3] = normalized(gw, gx, gy, gz)
        walk = coef[C_BIAS_WALK] ** 2 * dt
        for k in range(3):
            row[R_BIAS_VAR + k] += walk
        rest = _rest(row, coef, gains, dt, g0, g1, g2, a0, a1, a2, acc_ok)
        if acc_ok:  # (an all-zero sample is no measurement: nothing reaches the low-pass)
            _incline(row, coef, gains, dt, a0, a1, a2, rest)
        bias_max = coef[C_BIAS_MAX]
        for k in range(3):
            row[R_BIAS + k] = min(max(row[R_BIAS + k], -bias_max), bias_max)
            row[R_BIAS_SD + k] = math.sqrt(row[R_BIAS_VAR + k])
    c, g = R_Q_ACC, R_Q_GYR
    q6w, q6x, q6y, q6z = mul(row[c], row[c + 1], row[c + 2], row[c + 3],
                             row[g], row[g + 1], row[g + 2], row[g + 3])  # fmt: skip
    disturbed = False
    if has_mag:
        disturbed = _heading(row, coef, gains, dt, q6w, q6x, q6y, q6z, m0, m1, m2)
        half = 0.5 * row[R_HEADING]
        ow, ox, oy, oz = mul(math.cos(half), 0.0, 0.0, math.sin(half), q6w, q6x, q6y, q6z)
    else:
        ow, ox, oy, oz = q6w, q6x, q6y, q6z
    ned = coef[C_NED] > 0.5
    if ned:
        ow, ox, oy, oz = mul(0.0, _H, _H, 0.0, ow, ox, oy, oz)
    q_out[0], q_out[1], q_out[2], q_out[3] = ow, ox, oy, oz
    _outputs(row, ned, q6w, q6x, q6y, q6z, x_out)
    return (REST if rest else 0) | (MAG_DISTURBED if disturbed else 0)


@njit(cache=True, nogil=True)
def run(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples (``contract.run_series``)."""
    contract.run_series(
        _start, _step, _hold, rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out
    )


@njit(cache=True)
def sample(row, coef, scoef, clk, imu, has, q_out, x_out):
    """One screened sample of one sensor (``contract.sample``), compiled once for
    :func:`update` and :func:`update_one`."""
    return contract.sample(_start, _step, _hold, row, coef, scoef, clk, imu, has, q_out, x_out)


@njit(cache=True)
def update(rows, clock, coefs, dt, gyr, acc, mag, has, q_out, x_out, flags_out):
    """One sample of S sensors (``contract.update_samples``)."""
    contract.update_samples(sample, rows, clock, coefs, dt, gyr, acc, mag, has, q_out, x_out,
                            flags_out)


@njit(cache=True)
def update_one(rows, clock, coefs, dt, g, a, m, has, out):
    """One sample of one sensor (``contract.update_one``); returns the flags."""
    return contract.update_one(sample, rows, clock, coefs, dt, g, a, m, has, out)


@njit(cache=True)
def start(rows, coefs, quat0):
    """Start S sensors at quat0 (S, 4) (``contract.start_rows``)."""
    contract.start_rows(_start, rows, coefs, quat0)
