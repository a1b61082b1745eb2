# ruff: noqa: F405  (names from robust_layout's star import)
"""Kernel of margtrack's robust filter (``__init__.py``), on ``estimator/skeleton.py``.

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

The row layout, coefficients and outputs are in ``methods/robust/layout.py``; the
interval-dependent gains in ``methods/robust/gains.py``; the step, on a strided row
(one sensor's, or a lane of ``estimator/lockstep.py``' interleaved rows), in
``methods/robust/step.py``.

``_step`` returns the flag bits ``REST`` and ``MAG_DISTURBED``; its extra outputs
(``x_out``, ``N_OUT``) are the 6-D quaternion (4, output frame), the bias (3, rad/s),
its standard deviation (3, rad/s) and the accepted hard-iron offset (3, the field's unit,
body axes; nan until one is accepted: ``methods/robust/hard_iron.py``).
"""

from __future__ import annotations

import math

from margtrack.estimator import skeleton as contract
from margtrack.estimator.jit import njit, select
from margtrack.estimator.quat_kernel import mul
from margtrack.methods.robust import hard_iron
from margtrack.methods.robust.gains import (  # noqa: F401 (butterworth_coefficients: kernel.*)
    butterworth_coefficients,
    gains_ready_at,
)
from margtrack.methods.robust.layout import *  # noqa: F403 (the layout, as this module's)
from margtrack.methods.robust.step import H, outputs_at
from margtrack.methods.robust.step import step_at as _step_at


@njit(cache=True, inline="always")
def _sensor_at(st, o, lanes, coef):
    """What is known of a sensor before its first sample: bias 0 with the initial
    variance, the field reference as given (or none), no hard-iron fit. The row's slot j
    is ``st[o + j * lanes]``."""
    var0 = coef[C_BIAS_SIGMA0] ** 2
    for k in range(3):
        st[o + (R_BIAS + k) * lanes] = 0.0
        st[o + (R_BIAS_VAR + k) * lanes] = var0
        st[o + (R_BIAS_SD + k) * lanes] = math.sqrt(var0)
    st[o + R_MAG_NORM_REF * lanes] = coef[C_MAG_NORM_REF0]
    st[o + R_MAG_DIP_REF * lanes] = coef[C_MAG_DIP_REF0]
    st[o + R_CAND_NORM * lanes] = 0.0
    st[o + R_CAND_DIP * lanes] = math.nan
    st[o + R_CAND_S * lanes] = 0.0
    hard_iron.fresh_at(st, o, lanes)


@njit(cache=True, _nrt=False)
def _window_field_at(st, o, lanes):
    """The field as robust reads it, for a restart's window (``estimator/restart_kernel.py``):
    (offset (3), reference norm, dip rad). With a hard-iron offset accepted, the offset
    and robust's reference for the corrected field; while a field turning with the sensor
    is rejected with none accepted (``R_HI_MOVING``: a carried magnet, still there after a
    gap), norm -1: no field sample agrees and the heading is carried; else no offset and
    the screening's reference (norm 0)."""
    i_off = o + R_HI_OFFSET * lanes
    o0, o1, o2 = st[i_off], st[i_off + lanes], st[i_off + 2 * lanes]
    if st[o + R_HI_MOVING * lanes] != 0.0:
        return 0.0, 0.0, 0.0, -1.0, math.nan
    if (o0 != 0.0 or o1 != 0.0 or o2 != 0.0) and st[o + R_MAG_NORM_REF * lanes] > 0.0:
        return o0, o1, o2, st[o + R_MAG_NORM_REF * lanes], st[o + R_MAG_DIP_REF * lanes]
    return 0.0, 0.0, 0.0, 0.0, math.nan


@njit(cache=True)
def fresh(rows, coefs):
    """Rows (S, N_ROW) of sensors that have seen nothing: the sensor part (``_sensor_at``)."""
    coef = coefs[contract.N_SCOEF :]
    for s in range(rows.shape[0]):
        _sensor_at(rows[s], 0, 1, coef)


@njit(cache=True, inline="always")
def _start_at(st, o, lanes, coef, first, qw, qx, qy, qz):
    """(Re)start at q (output frame): the orientation, low-passes, rest detector and
    start-up afresh; the bias and the field reference only the first time."""
    if first:
        _sensor_at(st, o, lanes, coef)
    if coef[C_NED] > 0.5:
        qw, qx, qy, qz = mul(0.0, H, H, 0.0, qw, qx, qy, qz)  # to ENU
    i_g, i_c = o + R_Q_GYR * lanes, o + R_Q_ACC * lanes
    st[i_g], st[i_g + lanes], st[i_g + 2 * lanes], st[i_g + 3 * lanes] = 1.0, 0.0, 0.0, 0.0
    st[i_c], st[i_c + lanes], st[i_c + 2 * lanes], st[i_c + 3 * lanes] = qw, qx, qy, qz
    st[o + R_HEADING * lanes] = 0.0
    for k in range(3):
        st[o + (R_ACC_LP + k) * lanes] = 0.0
        st[o + (R_GYR_REST + k) * lanes] = 0.0
        st[o + (R_ACC_REST + k) * lanes] = 0.0
    for k in range(6):
        st[o + (R_ACC_LP_BW + k) * lanes] = 0.0
    st[o + R_LP_STAGE * lanes] = LP_EMPTY
    st[o + R_SINCE_START * lanes] = 0.0
    st[o + R_HEADING_N * lanes] = 1.0
    st[o + R_STILL * lanes] = 0.0


@njit(cache=True, inline="always")
def _start(row, coef, first, qw, qx, qy, qz):
    """:func:`_start_at` on one sensor's row."""
    _start_at(row, 0, 1, coef, first, qw, qx, qy, qz)


@njit(cache=True, inline="always")
def _hold_at(st, o, lanes, coef, xa, xo, outs):
    """Extra outputs of the current state (before the first start: the held quaternion).
    The sample counts for the hard-iron fit's solve (no solve here: no sample is used), so
    sensors made together solve at the same samples."""
    i_n = o + R_HI_COUNT * lanes
    st[i_n] = select(st[i_n] + 1.0 >= HI_EVERY, 0.0, st[i_n] + 1.0)
    if st[o + contract.K_STARTS * lanes] == 0.0:
        q = o + contract.K_Q * lanes
        outputs_at(st, o, lanes, False, st[q], st[q + lanes], st[q + 2 * lanes],
                   st[q + 3 * lanes], xa, xo, outs)
        return
    c, g = o + R_Q_ACC * lanes, o + R_Q_GYR * lanes
    q6w, q6x, q6y, q6z = mul(st[c], st[c + lanes], st[c + 2 * lanes], st[c + 3 * lanes],
                             st[g], st[g + lanes], st[g + 2 * lanes], st[g + 3 * lanes])
    outputs_at(st, o, lanes, coef[C_NED] > 0.5, q6w, q6x, q6y, q6z, xa, xo, outs)


@njit(cache=True, inline="always")
def _hold(row, coef, x_out):
    """:func:`_hold_at` on one sensor's row."""
    _hold_at(row, 0, 1, coef, x_out, 0, 1)


@njit(cache=True, _nrt=False)
def _step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """One screened sample of one sensor (``robust_step.step_at``): q_out the 9-D (6-D
    without a field) orientation; returns REST and MAG_DISTURBED bits. Called, not inlined
    (numba's inliner copies an inlined body's variables once per block: the entry points
    compiled in 104 s, then 56 s; same results to the bit, no measurable cost); no
    reference counting: it creates no arrays."""
    return _step_at(row, 0, 1, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, 0,
                   x_out, 0, 1, False)


@njit(cache=True, inline="always")
def _rare_at(st, o, lanes, coef, dt, has_mag, a0, a1, a2, m0, m1, m2):
    """Whether this sample takes one of ``step_at``'s rare branches (no interval, the first
    accelerometer samples since a start, an all-zero accelerometer, gains not cached for
    the interval, no field reference yet, the hard-iron fit's solve due or its origin
    unset at a usable field): those run in ``contract_lanes``' scalar pass."""
    # (& and |, not and/or: no branches, which would make the lockstep pass's stores
    # around this masked stores)
    ready = (
        (dt > 0.0)
        & (st[o + R_LP_STAGE * lanes] == LP_FILTER)
        & ((a0 != 0.0) | (a1 != 0.0) | (a2 != 0.0))
        & gains_ready_at(st, o, lanes, coef, dt)
    )
    field_ready = (st[o + R_MAG_NORM_REF * lanes] > 0.0) & (
        st[o + R_MAG_DIP_REF * lanes] == st[o + R_MAG_DIP_REF * lanes]  # (not nan)
    )
    solve = (coef[C_HI_RATE] > 0.0) & (st[o + R_HI_COUNT * lanes] + 1.0 >= HI_EVERY)
    i_sh = o + R_HI_SHIFT * lanes
    origin = has_mag & ((m0 != 0.0) | (m1 != 0.0) | (m2 != 0.0)) & (st[i_sh] != st[i_sh])
    return (not (ready & (field_ready | (not has_mag)))) | solve | origin


N_X = N_OUT  # what ``run`` writes per sample

run, lanes, start = contract.entry_points(__name__)
