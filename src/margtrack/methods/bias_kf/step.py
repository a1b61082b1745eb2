"""One sample of Ang's bias-augmented quaternion Kalman filter (003 eqs. 10-51), in place.

State per sensor (:mod:`margtrack.methods.bias_kf.layout`): ``x = [q (4), b (3)]``, ``q``
body-to-earth ``[w, x, y, z]`` (Hamilton, output frame), ``b`` the angular-rate bias in
rad/s, and the full 7x7 covariance ``P``. Every sample (:func:`filter_step`): predict with
the measured rate minus the bias (eqs. 25-31, 47-48), then correct with the quaternion of
the TRIAD matrix (eqs. 10-13, 38), or margtrack's decoupled tilt/heading measurement,
weighted by its error covariance (eqs. 41-46), Kalman update (eqs. 49-51), and normalise
``q``. The covariance algebra is :mod:`margtrack.methods.bias_kf.cov`, the measurements
:mod:`margtrack.methods.bias_kf.model`.

A sample without accelerometer or field (zero vector: the input screening's "no
measurement") corrects what the other still observes
(:mod:`margtrack.methods.bias_kf.partial`): the tilt alone, or the heading alone.

A (re)start (:func:`start_row`) sets ``q``, the attitude block of ``P`` from
``init_angle_std_rad`` and drops the attitude-bias correlation; the first start also
sets ``b = 0``, the bias block from ``init_bias_std_rad_s`` and no field reference, a
restart after a gap keeps them (what is known of the sensor and the place).
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator.jit import njit
from margtrack.estimator.quat_kernel import normalized
from margtrack.estimator.triad_kernel import OK, PARALLEL, ZERO_ACC, ZERO_MAG, unit_pair
from margtrack.methods.bias_kf import cov, partial
from margtrack.methods.bias_kf.layout import (
    BIAS,
    BIAS_SD,
    C_ACC_NORM_CORR,
    C_DECOUPLED,
    C_G_ABS,
    C_GYR_SCALE_VAR,
    C_INIT_ANGLE_VAR,
    C_INIT_BIAS_VAR,
    C_MAG_DIP_CORR,
    C_MAG_DIP_TOL,
    C_MAG_NORM_CORR,
    C_MAG_NORM_TOL,
    C_NORTH,
    C_REF_TRIAD,
    C_STAMP,
    C_TILT_GATE,
    C_TILT_GATE_EXP,
    C_UP,
    COV,
    DIP_REF,
    DT,
    DT_ACC,
    DT_ACC_CORR,
    DT_GYR,
    DT_MAG,
    DT_WALK,
    DX,
    FIELD_REF,
    N_WORK,
    NOISE,
    PARTIAL,
    SCRATCH,
    STAMP,
    W_NOISE,
    W_QT,
    W_XI,
    WORK,
    Q,
    _interval_coefficients,
)
from margtrack.methods.bias_kf.model import (
    _acc_variance,
    _decoupled,
    _gate_weight,
    _mag_variance,
    _mat,
    _up_in_body,
    fill_quat_noise,
    triad_at,
)

__all__ = ["NOT_PD", "code_flags", "filter_step", "start_row"]

#: flag: the innovation covariance was not positive definite, the update was skipped
#: (5, not 4: kernels.triad uses 4 for a failed Gauss-Newton solve)
NOT_PD = 5

# margtrack.estimator.flags.Flag bits
_ACC_IGNORED = 16
_MAG_IGNORED = 32
_MAG_DISTURBED = 64


@njit(cache=True, fastmath={"contract"}, _nrt=False)
def filter_step(row, coef, h, gx, gy, gz, acx, acy, acz, mgx, mgy, mgz):
    """One sample of one sensor's filter, in place on its ``row``; returns (code, disturbed).

    ``h`` the interval s (0: integrate and correct nothing); rate rad/s, accelerometer
    m/s², field any unit, body frame; an all-zero accelerometer or field is no
    measurement. ``code``: OK, or what the sample got instead of the full correction:
    ZERO_MAG (or a field parallel to the accelerometer or the predicted up, PARALLEL) the
    tilt only, ZERO_ACC the heading only (the field levelled by the predicted up), each by
    the reduced update; NOT_PD: not corrected. ``disturbed``: the field's norm or dip is
    farther than the tolerances from the reference (the first field sample's; it is still
    used, with the variance of the disturbance terms). Never NaN for finite input.
    Compiled with floating-point contraction only (``a * b + c`` fused): every entry point
    and thread calls this one compiled function, so they agree to the last bit; and without
    reference counting, whichever caller compiles it first (numba's callees otherwise take
    the caller's setting, and the first compilation serves all): the partial updates it
    calls, which make views of the row, are compiled with theirs.
    """
    tilt_gate = coef[C_TILT_GATE]
    qw, qx, qy, qz = row[Q], row[Q + 1], row[Q + 2], row[Q + 3]
    bx, by, bz = row[BIAS], row[BIAS + 1], row[BIAS + 2]
    flag = OK
    nm2 = mgx * mgx + mgy * mgy + mgz * mgz
    na2 = acx * acx + acy * acy + acz * acz
    if h > 0.0:
        if h != row[DT] or coef[C_STAMP] != row[STAMP]:
            _interval_coefficients(row, coef, h)
        # -- prediction (eqs. 25-31, 47-48), Ξ_Ω = n² T per axis (+ (κ ω)² T) ---------------
        wx, wy, wz = gx - bx, gy - by, gz - bz  # eq. 17
        xi0, xi1, xi2 = row[DT_GYR], row[DT_GYR + 1], row[DT_GYR + 2]
        scale_var = coef[C_GYR_SCALE_VAR]
        if scale_var > 0.0:  # rate-proportional part: (κ ω)² T
            xi0 += scale_var * wx * wx * h
            xi1 += scale_var * wy * wy * h
            xi2 += scale_var * wz * wz * h
        qw, qx, qy, qz = cov.predict(
            row, COV, SCRATCH, h, qw, qx, qy, qz, wx * h, wy * h, wz * h, xi0, xi1, xi2,
            row[DT_WALK], row[DT_WALK + 1], row[DT_WALK + 2],
        )
    # predicted up (body frame); the field's norm and dip against its reference
    ux, uy, uz = _up_in_body(qw, qx, qy, qz, coef[C_UP], coef[C_UP + 1], coef[C_UP + 2])
    nm, sin_dip = 0.0, 0.0
    disturbed = False
    if nm2 > 0.0:
        nm = math.sqrt(nm2)
        sin_dip = -(ux * mgx + uy * mgy + uz * mgz) / nm
        if math.isnan(row[FIELD_REF]):
            row[FIELD_REF] = nm
            row[FIELD_REF + 1] = sin_dip
        if row[FIELD_REF + 1] != row[DIP_REF] or coef[C_STAMP] != row[DIP_REF + 1]:
            _dip_bounds(row, coef)
        norm_off = abs(nm / row[FIELD_REF] - 1.0)
        disturbed = (norm_off > coef[C_MAG_NORM_TOL] or sin_dip < row[DIP_REF + 2]
                     or sin_dip > row[DIP_REF + 3])
    if h > 0.0 and (na2 > 0.0 or nm2 > 0.0):
        ref_norm, ref_sin_dip = row[FIELD_REF], row[FIELD_REF + 1]
        norm_corr, dip_corr = coef[C_MAG_NORM_CORR], coef[C_MAG_DIP_CORR]
        acc_corr, g_abs = coef[C_ACC_NORM_CORR], coef[C_G_ABS]
        if na2 > 0.0 and nm2 > 0.0:
            # -- measurement: TRIAD quaternion (eqs. 10-13, 38) --------------------------
            c2 = 1.0
            decoupled = coef[C_DECOUPLED] > 0.5
            if decoupled:  # TRIAD's unit vectors only (eqs. 10-11), then the decoupled q
                flag, ax, ay, az, nx, ny, nz = unit_pair(acx, acy, acz, mgx, mgy, mgz)
                mw, mx, my, mz = 1.0, 0.0, 0.0, 0.0
                if flag == OK:
                    flag, mw, mx, my, mz, c2 = _decoupled(qw, qx, qy, qz, ax, ay, az, nx, ny,
                                                          nz, ux, uy, uz, coef, C_REF_TRIAD)
            else:
                flag, mw, mx, my, mz, ax, ay, az, nx, ny, nz = triad_at(
                    acx, acy, acz, mgx, mgy, mgz, coef[C_UP], coef[C_UP + 1], coef[C_UP + 2],
                    coef[C_NORTH], coef[C_NORTH + 1], coef[C_NORTH + 2],
                )
            if flag == OK:
                if mw * qw + mx * qx + my * qy + mz * qz < 0.0:  # sign nearest q⁻
                    mw, mx, my, mz = -mw, -mx, -my, -mz
                # unit-vector noise = normal noise / |E v| (eqs. 41-44)
                var_g = _acc_variance(row[DT_ACC], row[DT_ACC_CORR], acc_corr,
                                      math.sqrt(na2), g_abs)
                var_n = _mag_variance(row[DT_MAG], h, nm, sin_dip, ref_norm, ref_sin_dip,
                                      norm_corr, dip_corr)
                if tilt_gate < math.inf:  # robust tilt gate
                    d2 = cov.tilt_d2(row, COV, qw, qx, qy, qz, mw, mx, my, mz, ux, uy, uz,
                                     var_g)
                    if d2 > tilt_gate:
                        var_g *= _gate_weight(d2 / tilt_gate, coef[C_TILT_GATE_EXP])
                if decoupled:  # eq. 46 of the decoupled Ξθ, in closed form
                    vw, vx, vy, vz = cov.body_direction(qw, qx, qy, qz, ux, uy, uz)
                    cov.decoupled_noise(row, NOISE, qw, qx, qy, qz, vw, vx, vy, vz, var_g,
                                        var_n / c2)
                else:  # eqs. 45-46 in closed form
                    cov.triad_noise(row, NOISE, qw, qx, qy, qz, ax, ay, az, nx, ny, nz, var_g,
                                    var_n)
                if cov.kalman_update(row, COV, SCRATCH, NOISE, mw - qw, mx - qx, my - qy,
                                     mz - qz):
                    qw, qx, qy, qz = normalized(
                        qw + row[DX], qx + row[DX + 1], qy + row[DX + 2], qz + row[DX + 3]
                    )
                    bx, by, bz = bx + row[DX + 4], by + row[DX + 5], bz + row[DX + 6]
                else:
                    flag = NOT_PD
        else:
            flag = ZERO_ACC if na2 == 0.0 else ZERO_MAG
        ok = True
        if flag == ZERO_MAG or flag == PARALLEL:  # the tilt alone
            na = math.sqrt(na2)
            var_g = _acc_variance(row[DT_ACC], row[DT_ACC_CORR], acc_corr, na, g_abs)
            ok, qw, qx, qy, qz, bx, by, bz = partial.tilt_only(
                row, COV, PARTIAL, qw, qx, qy, qz, bx, by, bz, ux, uy, uz, acx / na, acy / na,
                acz / na, var_g, tilt_gate, coef[C_TILT_GATE_EXP],
            )
        elif flag == ZERO_ACC and nm2 > 0.0:  # the heading alone
            var_n = _mag_variance(row[DT_MAG], h, nm, sin_dip, ref_norm, ref_sin_dip,
                                  norm_corr, dip_corr)
            ok, qw, qx, qy, qz, bx, by, bz = partial.heading_only(
                row, COV, PARTIAL, qw, qx, qy, qz, bx, by, bz, ux, uy, uz, mgx / nm,
                mgy / nm, mgz / nm, var_n, coef, C_REF_TRIAD,
            )
        if not ok:
            flag = NOT_PD
    row[Q], row[Q + 1], row[Q + 2], row[Q + 3] = qw, qx, qy, qz
    row[BIAS], row[BIAS + 1], row[BIAS + 2] = bx, by, bz
    _bias_sd(row)
    return flag, disturbed


@njit(cache=True)
def _dip_bounds(row, coef):
    """The sines of the dips ``δ₀ ∓ tol`` (``δ₀`` the reference's, ``tol`` the tolerance):
    a field is disturbed in dip when ``|asin(sin δ) - δ₀| > tol``, i.e. ``sin δ`` outside
    them (asin is increasing; a bound beyond ±90 deg is ∓inf). Kept in ``DIP_REF`` with
    the reference sine and the coefficient stamp they hold for."""
    dip = math.asin(min(1.0, max(-1.0, row[FIELD_REF + 1])))
    tol = coef[C_MAG_DIP_TOL]
    row[DIP_REF] = row[FIELD_REF + 1]
    row[DIP_REF + 1] = coef[C_STAMP]
    row[DIP_REF + 2] = math.sin(dip - tol) if dip - tol > -0.5 * math.pi else -math.inf
    row[DIP_REF + 3] = math.sin(dip + tol) if dip + tol < 0.5 * math.pi else math.inf


@njit(cache=True, inline="always")
def _bias_sd(row):
    for k in range(3):
        row[BIAS_SD + k] = math.sqrt(max(row[COV + 8 * (4 + k)], 0.0))


@njit(cache=True, inline="always")
def code_flags(code, disturbed):
    """The flag bits of a sample's code and disturbance (the screening sets the rest)."""
    f = 0
    if code == PARALLEL:
        f = _MAG_IGNORED
    elif code == NOT_PD:
        f = _ACC_IGNORED | _MAG_IGNORED
    if disturbed:
        f |= _MAG_DISTURBED
    return f


# _nrt=True: its views of the row (``_mat``) need numba's reference counting, also
# when a kernel compiled without it (a method's ``series``) calls it
@njit(cache=True, _nrt=True)
def start_row(row, coef, first, qw, qx, qy, qz):
    """(Re)start one sensor's filter at q (body to earth).

    The attitude block of ``P`` is ``init_angle_std_rad`` per body axis (as
    :func:`fill_quat_noise` maps it), uncorrelated with the bias (the orientation is
    measured, not propagated). ``first``: also ``b = 0``, the bias block
    ``init_bias_std_rad_s`` per axis and no field reference yet; otherwise they are kept.
    """
    p = _mat(row, COV, 7, 7)
    wk = row[WORK : WORK + N_WORK]
    qt = _mat(wk, W_QT, 4, 3)
    xi = _mat(wk, W_XI, 3, 3)
    noise = _mat(wk, W_NOISE, 4, 4)
    if first:
        for k in range(3):
            row[BIAS + k] = 0.0
            for c in range(3):
                p[4 + k, 4 + c] = 0.0
            p[4 + k, 4 + k] = coef[C_INIT_BIAS_VAR]
        row[FIELD_REF] = np.nan
        row[FIELD_REF + 1] = np.nan
        row[DIP_REF] = np.nan  # its dip bounds: none
    row[Q], row[Q + 1], row[Q + 2], row[Q + 3] = qw, qx, qy, qz
    for k in range(3):
        for c in range(3):
            xi[k, c] = 0.0
        xi[k, k] = coef[C_INIT_ANGLE_VAR]
    fill_quat_noise(qw, qx, qy, qz, xi, qt, noise)
    for r in range(4):
        for c in range(4):
            p[r, c] = noise[r, c]
        for c in range(4, 7):
            p[r, c] = 0.0
            p[c, r] = 0.0
    _bias_sd(row)
