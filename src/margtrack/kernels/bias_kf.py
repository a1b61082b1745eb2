"""Kernel of Ang's bias-augmented quaternion Kalman filter (003 eqs. 20-51), on the contract.

State per sensor: ``x = [q (4), b (3)]``, ``q`` body-to-earth ``[w, x, y, z]`` (Hamilton,
output frame), ``b`` the angular-rate bias in rad/s, and the full 7x7 covariance ``P``.
Every sample (:func:`filter_step`): predict with the measured rate minus the bias
(eqs. 25-31, 47-48), then correct with the quaternion of the TRIAD matrix (eqs. 10-13, 38)
weighted by the TRIAD error covariance (eqs. 41-46), Kalman update (eqs. 49-51) in Joseph
form, and normalise ``q``. The matrices, measurements and updates are in
:mod:`margtrack.kernels.bias_kf_model`.

A sample without accelerometer or field (zero vector: the input screening's "no
measurement") corrects what the other still observes, by a reduced update
(``bias_kf_model._reduced_update``): the tilt alone, or the heading alone.

Row layout (one sensor, after the contract's ``N_CONTRACT`` slots):

- ``Q`` (4): the filter's orientation (body to earth, output frame);
- ``BIAS`` (3): the rate bias, rad/s; ``BIAS_SD`` (3): its standard deviation, rad/s
  (square roots of ``P``'s bias diagonal, kept for the accessor);
- ``COV`` (49): ``P``, row-major 7x7, of ``[q (4), b (3)]``;
- ``FIELD_REF`` (2): the norm (data's unit) and the sine of the dip of the first field
  sample, NaN before it (state of the field-noise terms and the disturbance flag);
- ``DT`` (1), ``STAMP`` (1), ``DT_GYR`` (3), ``DT_WALK`` (3), ``DT_ACC`` (1),
  ``DT_ACC_CORR`` (1), ``DT_MAG`` (1): coefficients of the sample interval ``T``
  (``n² T`` per axis, ``n_b² T`` per axis, ``(σ_W²/T + σ_C²)/g²``, ``2τ_a/T``,
  ``mag_var/T``), derived when ``T`` or the coefficient vector (its ``C_STAMP``) changes;
  they depend on nothing else, so they never change a result;
- ``WORK`` (``N_WORK``): scratch of one step (the small matrices of the algebra, ``W_*``;
  written before being read in every step, so not state). Keeping them in the row
  spares the allocations of a step (the series kernel allocated them once per call, the
  contract calls a step per sample); :func:`_mat` views them as matrices without the
  helper call of a ``reshape``.

A (re)start (:func:`start_row`) sets ``q``, the attitude block of ``P`` from
``init_angle_std_rad`` and drops the attitude-bias correlation; the first start also
sets ``b = 0``, the bias block from ``init_bias_std_rad_s`` and no field reference, a
restart after a gap keeps them (what is known of the sensor and the place).

Extra outputs per sample (``x_out``): the bias (3), the diagonal of ``P`` (7) and the
sample's code (1: OK, ZERO_ACC, ZERO_MAG, PARALLEL or NOT_PD). Flags: PARALLEL is
MAG_IGNORED, NOT_PD is ACC_IGNORED and MAG_IGNORED, a field's norm or dip beyond the
shared tolerances from the reference is MAG_DISTURBED (it is still used, with the noise of
``mag_norm_correlation_s``/``mag_dip_correlation_s``).

Coefficients (``C_*``, after the screening's): the squared noise densities per body axis,
the extensions' values (neutral: the filter as printed), the earth-frame up and north,
the initial variances; see :func:`coefficients`. :func:`bias_kf` and
:func:`bias_kf_extended` run the same step over series of state arrays (the
all-accelerometer pipeline and the oracle tests use them).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import as_strided

from margtrack.kernels import contract
from margtrack.kernels._quat import mul, normalized
from margtrack.kernels.bias_kf_model import (
    _acc_variance,
    _decoupled,
    _fill_direction,
    _kalman_update,
    _levelled_heading,
    _mag_variance,
    _normal_axes,
    _predict_covariance,
    _reduced_update,
    _tilt_innovation_d2,
    _tilt_rotation,
    _triad,
    _up_in_body,
    fill_decoupled_cov,
    fill_phi_q,
    fill_qtilde,
    fill_quat_noise,
    fill_triad_cov,
)
from margtrack.kernels.jit import njit
from margtrack.kernels.triad import OK, PARALLEL, ZERO_ACC, ZERO_MAG

#: flag: the innovation covariance was not positive definite, the update was skipped
#: (5, not 4: kernels.triad uses 4 for a failed Gauss-Newton solve)
NOT_PD = 5

__all__ = [
    "NOT_PD",
    "OK",
    "PARALLEL",
    "ZERO_ACC",
    "ZERO_MAG",
    "bias_kf",
    "bias_kf_extended",
    "code_flags",
    "coefficients",
    "fill_decoupled_cov",
    "fill_phi_q",
    "fill_qtilde",
    "fill_quat_noise",
    "fill_triad_cov",
    "filter_step",
]

# -- the row ---------------------------------------------------------------------------------
Q = contract.N_CONTRACT  # 4: orientation, body to earth
BIAS = Q + 4  # 3: rate bias, rad/s
BIAS_SD = BIAS + 3  # 3: its standard deviation, rad/s
COV = BIAS_SD + 3  # 49: P, row-major 7x7
FIELD_REF = COV + 49  # 2: reference field norm, sine of its dip (NaN: none yet)
DT = FIELD_REF + 2  # 1: the interval T the DT_* coefficients hold for, s (0: none)
STAMP = DT + 1  # 1: the C_STAMP of the coefficient vector they came from
DT_GYR = STAMP + 1  # 3: n_k² T, rad² (rate noise as an angle over the period, eq. 31)
DT_WALK = DT_GYR + 3  # 3: n_b,k² T, (rad/s)² (bias walk, eq. 31)
DT_ACC = DT_WALK + 3  # 1: (σ_W²/T + σ_C²)/g² (eqs. 41-43)
DT_ACC_CORR = DT_ACC + 1  # 1: 2 τ_a / T
DT_MAG = DT_ACC_CORR + 1  # 1: mag_var / T (eq. 44)
WORK = DT_MAG + 1  # N_WORK: scratch of one step

# scratch matrices, offsets within WORK (row-major)
W_PHI = 0  # (4, 4) Φ_Q
W_QT = W_PHI + 16  # (4, 3) Q̃
W_G = W_QT + 12  # (4, 7) top block row of Φ: [Φ_Q, Φ_B] (eq. 26)
W_GP = W_G + 28  # (4, 7)
W_XI = W_GP + 28  # (3, 3) an angle covariance (Ξ_Ω, Ξθ)
W_NOISE = W_XI + 9  # (4, 4) its quaternion covariance (W, V)
W_CHOL = W_NOISE + 16  # (4, 4)
W_Y = W_CHOL + 16  # (4, 7)
W_GAIN = W_Y + 28  # (7, 4)
W_ZMAT = W_GAIN + 28  # (7, 7)
W_KV = W_ZMAT + 49  # (7, 4)
W_DX = W_KV + 28  # (7,)
W_INNOV = W_DX + 7  # (4,)
W_TMP = W_INNOV + 4  # (4, 3)
W_PTH = W_TMP + 12  # (3, 3)
W_HQ = W_PTH + 9  # (3, 4)
W_HP = W_HQ + 12  # (3, 7)
W_ZH = W_HP + 21  # (7, 3)
W_VR = W_ZH + 21  # (3, 3)
N_WORK = W_VR + 9
N_ROW = WORK + N_WORK

# -- the coefficients (after the screening's) ------------------------------------------------
C_GYR_VAR = 0  # 3: n_k², (rad/s)²/Hz
C_BIAS_VAR = 3  # 3: n_b,k², (rad/s)²/s
C_ACC_VAR = 6  # σ_W² density, (m/s²)²/Hz
C_ACC_MOTION_VAR = 7  # σ_C², (m/s²)²
C_GRAVITY2 = 8  # g², (m/s²)²
C_G_ABS = 9  # g, m/s²
C_MAG_VAR = 10  # (σ_M/|m₀|)², 1/Hz
C_DECOUPLED = 11  # 1: decoupled tilt/heading measurement
C_GYR_SCALE_VAR = 12  # κ², s
C_ACC_NORM_CORR = 13  # τ_a, s
C_MAG_NORM_CORR = 14  # τ_m, s
C_MAG_DIP_CORR = 15  # τ_δ, s
C_TILT_GATE = 16  # γ (inf: off)
C_TILT_GATE_EXP = 17  # p
C_MAG_NORM_TOL = 18  # relative
C_MAG_DIP_TOL = 19  # rad
C_UP = 20  # 3: unit up, earth frame
C_NORTH = 23  # 3: unit horizontal north, earth frame
C_INIT_ANGLE_VAR = 26  # rad², per body axis
C_INIT_BIAS_VAR = 27  # (rad/s)², per axis
C_STAMP = 28  # identifies this vector (the row's DT_* coefficients are derived from it)
N_COEF = 29

# margtrack.estimator.flags.Flag bits
_ACC_IGNORED = 16
_MAG_IGNORED = 32
_MAG_DISTURBED = 64


@njit(cache=True, inline="always")
def _mat(vec, offset, rows, cols):
    """The (rows, cols) row-major matrix at ``vec[offset:]``: a view, built in place (a
    ``reshape`` costs a helper call, about ten times the arithmetic it would serve)."""
    item = vec.strides[0]
    return as_strided(vec[offset : offset + rows * cols], shape=(rows, cols),
                      strides=(cols * item, item))


@njit(cache=True)
def coefficients(
    gyr_var, bias_var, acc_var, acc_motion_var_m2_s4, gravity2_m2_s4, mag_var, decoupled,
    gyr_scale_var_s, acc_norm_corr_s, mag_norm_corr_s, mag_dip_corr_s, tilt_gate,
    tilt_gate_exponent, mag_norm_tol, mag_dip_tol_rad, up, north, init_angle_var,
    init_bias_var, stamp,
):  # fmt: skip
    """The method's coefficient vector (N_COEF,) (arguments as :func:`bias_kf_extended`).

    init_angle_var rad², init_bias_var (rad/s)²: the initial variances per axis;
    ``stamp`` a number identifying this vector (a new one whenever a value changes).
    """
    c = np.empty(N_COEF)
    for k in range(3):
        c[C_GYR_VAR + k] = gyr_var[k]
        c[C_BIAS_VAR + k] = bias_var[k]
        c[C_UP + k] = up[k]
        c[C_NORTH + k] = north[k]
    c[C_ACC_VAR] = acc_var
    c[C_ACC_MOTION_VAR] = acc_motion_var_m2_s4
    c[C_GRAVITY2] = gravity2_m2_s4
    c[C_G_ABS] = math.sqrt(gravity2_m2_s4)
    c[C_MAG_VAR] = mag_var
    c[C_DECOUPLED] = 1.0 if decoupled else 0.0
    c[C_GYR_SCALE_VAR] = gyr_scale_var_s
    c[C_ACC_NORM_CORR] = acc_norm_corr_s
    c[C_MAG_NORM_CORR] = mag_norm_corr_s
    c[C_MAG_DIP_CORR] = mag_dip_corr_s
    c[C_TILT_GATE] = tilt_gate
    c[C_TILT_GATE_EXP] = tilt_gate_exponent
    c[C_MAG_NORM_TOL] = mag_norm_tol
    c[C_MAG_DIP_TOL] = mag_dip_tol_rad
    c[C_INIT_ANGLE_VAR] = init_angle_var
    c[C_INIT_BIAS_VAR] = init_bias_var
    c[C_STAMP] = stamp
    return c


@njit(cache=True)
def _interval_coefficients(row, coef, h):
    """The row's ``DT_*`` coefficients for the sample interval ``h`` s (> 0)."""
    for k in range(3):
        row[DT_GYR + k] = coef[C_GYR_VAR + k] * h
        row[DT_WALK + k] = coef[C_BIAS_VAR + k] * h
    row[DT_ACC] = (coef[C_ACC_VAR] / h + coef[C_ACC_MOTION_VAR]) / coef[C_GRAVITY2]
    row[DT_ACC_CORR] = 2.0 * coef[C_ACC_NORM_CORR] / h
    row[DT_MAG] = coef[C_MAG_VAR] / h
    row[DT] = h
    row[STAMP] = coef[C_STAMP]


@njit(cache=True)
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
    """
    p = _mat(row, COV, 7, 7)
    wk = row[WORK : WORK + N_WORK]
    qt = _mat(wk, W_QT, 4, 3)
    xi = _mat(wk, W_XI, 3, 3)
    noise = _mat(wk, W_NOISE, 4, 4)
    up = coef[C_UP : C_UP + 3]
    north = coef[C_NORTH : C_NORTH + 3]
    tilt_gate = coef[C_TILT_GATE]
    qw, qx, qy, qz = row[Q], row[Q + 1], row[Q + 2], row[Q + 3]
    bx, by, bz = row[BIAS], row[BIAS + 1], row[BIAS + 2]
    flag = OK
    nm2 = mgx * mgx + mgy * mgy + mgz * mgz
    na2 = acx * acx + acy * acy + acz * acz
    if h > 0.0:
        if h != row[DT] or coef[C_STAMP] != row[STAMP]:
            _interval_coefficients(row, coef, h)
        # -- prediction (eqs. 25-31, 47-48) ----------------------------------------------
        phi = _mat(wk, W_PHI, 4, 4)
        g = _mat(wk, W_G, 4, 7)  # top block row of Φ: [Φ_Q, Φ_B] (eq. 26)
        wx, wy, wz = gx - bx, gy - by, gz - bz  # eq. 17
        fill_phi_q(wx * h, wy * h, wz * h, phi)
        fill_qtilde(qw, qx, qy, qz, qt)
        for r in range(4):
            for c in range(4):
                g[r, c] = phi[r, c]
            for c in range(3):  # Φ_B = -½ T Φ_Q Q̃ (eq. 28 with the period T)
                g[r, 4 + c] = -0.5 * h * (
                    phi[r, 0] * qt[0, c] + phi[r, 1] * qt[1, c]
                    + phi[r, 2] * qt[2, c] + phi[r, 3] * qt[3, c]
                )
        qw, qx, qy, qz = normalized(
            phi[0, 0] * qw + phi[0, 1] * qx + phi[0, 2] * qy + phi[0, 3] * qz,
            phi[1, 0] * qw + phi[1, 1] * qx + phi[1, 2] * qy + phi[1, 3] * qz,
            phi[2, 0] * qw + phi[2, 1] * qx + phi[2, 2] * qy + phi[2, 3] * qz,
            phi[3, 0] * qw + phi[3, 1] * qx + phi[3, 2] * qy + phi[3, 3] * qz,
        )  # eq. 47
        _predict_covariance(p, g, _mat(wk, W_GP, 4, 7))
        # W (eq. 31): rate noise as an angle over the period, Ξ_Ω = n² T per axis
        for k in range(3):
            for c in range(3):
                xi[k, c] = 0.0
            xi[k, k] = row[DT_GYR + k]
        scale_var = coef[C_GYR_SCALE_VAR]
        if scale_var > 0.0:  # rate-proportional part: (κ ω)² T
            xi[0, 0] += scale_var * wx * wx * h
            xi[1, 1] += scale_var * wy * wy * h
            xi[2, 2] += scale_var * wz * wz * h
        fill_quat_noise(qw, qx, qy, qz, xi, qt, noise)
        for r in range(4):
            for c in range(4):
                p[r, c] += noise[r, c]
        for k in range(3):
            p[4 + k, 4 + k] += row[DT_WALK + k]  # Ξ_B: bias random walk
    # predicted up (body frame); the field's norm and dip against its reference
    ux, uy, uz = _up_in_body(qw, qx, qy, qz, up[0], up[1], up[2])
    nm, sin_dip = 0.0, 0.0
    disturbed = False
    if nm2 > 0.0:
        nm = math.sqrt(nm2)
        sin_dip = -(ux * mgx + uy * mgy + uz * mgz) / nm
        if math.isnan(row[FIELD_REF]):
            row[FIELD_REF] = nm
            row[FIELD_REF + 1] = sin_dip
        dip_off = abs(
            math.asin(min(1.0, max(-1.0, sin_dip)))
            - math.asin(min(1.0, max(-1.0, row[FIELD_REF + 1])))
        )
        norm_off = abs(nm / row[FIELD_REF] - 1.0)
        disturbed = norm_off > coef[C_MAG_NORM_TOL] or dip_off > coef[C_MAG_DIP_TOL]
    if h > 0.0 and (na2 > 0.0 or nm2 > 0.0):
        ref_norm, ref_sin_dip = row[FIELD_REF], row[FIELD_REF + 1]
        norm_corr, dip_corr = coef[C_MAG_NORM_CORR], coef[C_MAG_DIP_CORR]
        acc_corr, g_abs = coef[C_ACC_NORM_CORR], coef[C_G_ABS]
        innov = wk[W_INNOV : W_INNOV + 4]
        chol = _mat(wk, W_CHOL, 4, 4)
        y = _mat(wk, W_Y, 4, 7)
        gain = _mat(wk, W_GAIN, 7, 4)
        zmat = _mat(wk, W_ZMAT, 7, 7)
        kv = _mat(wk, W_KV, 7, 4)
        dx = wk[W_DX : W_DX + 7]
        tmp43 = _mat(wk, W_TMP, 4, 3)
        pth = _mat(wk, W_PTH, 3, 3)
        if na2 > 0.0 and nm2 > 0.0:
            # -- measurement: TRIAD quaternion (eqs. 10-13, 38) --------------------------
            res = _triad(acx, acy, acz, mgx, mgy, mgz, up, north)
            flag = res[0]
            mw, mx, my, mz = res[1], res[2], res[3], res[4]
            c2 = 1.0
            decoupled = coef[C_DECOUPLED] > 0.5
            if flag == OK and decoupled:
                dec = _decoupled(res[5], res[6], res[7], res[8], res[9], res[10],
                                 ux, uy, uz, up, north)
                flag = dec[0]
                mw, mx, my, mz, c2 = dec[1], dec[2], dec[3], dec[4], dec[5]
            if flag == OK:
                if mw * qw + mx * qx + my * qy + mz * qz < 0.0:  # sign nearest q⁻
                    mw, mx, my, mz = -mw, -mx, -my, -mz
                # unit-vector noise = normal noise / |E v| (eqs. 41-44)
                var_g = _acc_variance(row[DT_ACC], row[DT_ACC_CORR], acc_corr,
                                      math.sqrt(na2), g_abs)
                var_n = _mag_variance(row[DT_MAG], h, nm, sin_dip, ref_norm, ref_sin_dip,
                                      norm_corr, dip_corr)
                if tilt_gate < math.inf:  # robust tilt gate
                    d2 = _tilt_innovation_d2(p, qw, qx, qy, qz, mw, mx, my, mz,
                                             ux, uy, uz, var_g, qt, tmp43, pth)
                    if d2 > tilt_gate:
                        var_g *= (d2 / tilt_gate) ** coef[C_TILT_GATE_EXP]
                if decoupled:
                    fill_decoupled_cov(ux, uy, uz, var_g, var_n / c2, xi)
                else:
                    fill_triad_cov(res[5], res[6], res[7], res[8], res[9], res[10],
                                   var_g, var_n, xi)  # eq. 45
                fill_quat_noise(qw, qx, qy, qz, xi, qt, noise, 1.0)  # eq. 46
                innov[0], innov[1] = mw - qw, mx - qx
                innov[2], innov[3] = my - qy, mz - qz
                if _kalman_update(p, noise, innov, chol, y, gain, zmat, kv, dx):
                    qw, qx, qy, qz = normalized(qw + dx[0], qx + dx[1], qy + dx[2],
                                                qz + dx[3])
                    bx, by, bz = bx + dx[4], by + dx[5], bz + dx[6]
                else:
                    flag = NOT_PD
        else:
            flag = ZERO_ACC if na2 == 0.0 else ZERO_MAG
        m_rows = 0
        hq = _mat(wk, W_HQ, 3, 4)
        vr = _mat(wk, W_VR, 3, 3)
        if flag == ZERO_MAG or flag == PARALLEL:
            # -- tilt only: m = q⁻ ⊗ r, r taking the measured up to the predicted --------
            na = math.sqrt(na2)
            ex, ey, ez, fx, fy, fz = _normal_axes(ux, uy, uz)
            rw, rx, ry, rz = _tilt_rotation(acx / na, acy / na, acz / na,
                                            ux, uy, uz, ex, ey, ez)
            var_g = _acc_variance(row[DT_ACC], row[DT_ACC_CORR], acc_corr, na, g_abs)
            if tilt_gate < math.inf:
                mw, mx, my, mz = mul(qw, qx, qy, qz, rw, rx, ry, rz)
                d2 = _tilt_innovation_d2(p, qw, qx, qy, qz, mw, mx, my, mz,
                                         ux, uy, uz, var_g, qt, tmp43, pth)
                if d2 > tilt_gate:
                    var_g *= (d2 / tilt_gate) ** coef[C_TILT_GATE_EXP]
            fill_qtilde(qw, qx, qy, qz, qt)
            _fill_direction(qt, ex, ey, ez, hq, 0)
            _fill_direction(qt, fx, fy, fz, hq, 1)
            innov[0] = ex * rx + ey * ry + ez * rz  # δq = ½ Q̃ θ: r's vector part
            innov[1] = fx * rx + fy * ry + fz * rz
            vr[0, 0], vr[1, 1], vr[0, 1], vr[1, 0] = 0.25 * var_g, 0.25 * var_g, 0.0, 0.0
            m_rows = 2
        elif flag == ZERO_ACC and nm2 > 0.0:
            # -- heading only: TRIAD of the predicted up and the field --------------------
            lev = _levelled_heading(mgx / nm, mgy / nm, mgz / nm, ux, uy, uz, up, north)
            if lev[0] == OK:
                var_n = _mag_variance(row[DT_MAG], h, nm, sin_dip, ref_norm, ref_sin_dip,
                                      norm_corr, dip_corr)
                _, ex, ey, ez = mul(qw, -qx, -qy, -qz, lev[1], lev[2], lev[3], lev[4])
                if lev[1] * qw + lev[2] * qx + lev[3] * qy + lev[4] * qz < 0.0:
                    ex, ey, ez = -ex, -ey, -ez  # sign nearest q⁻
                fill_qtilde(qw, qx, qy, qz, qt)
                _fill_direction(qt, ux, uy, uz, hq, 0)
                innov[0] = ux * ex + uy * ey + uz * ez
                vr[0, 0] = 0.25 * var_n / lev[5]
                m_rows = 1
        if m_rows > 0:
            if _reduced_update(p, hq, m_rows, vr, innov, chol, y, gain,
                               _mat(wk, W_HP, 3, 7), zmat,
                               _mat(wk, W_ZH, 7, 3), kv, dx):
                qw, qx, qy, qz = normalized(qw + dx[0], qx + dx[1], qy + dx[2], qz + dx[3])
                bx, by, bz = bx + dx[4], by + dx[5], bz + dx[6]
            else:
                flag = NOT_PD
    row[Q], row[Q + 1], row[Q + 2], row[Q + 3] = qw, qx, qy, qz
    row[BIAS], row[BIAS + 1], row[BIAS + 2] = bx, by, bz
    _bias_sd(row)
    return flag, disturbed


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


@njit(cache=True)
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


@njit(cache=True, inline="always")
def _hold(row, coef, x_out):
    """Extra outputs of the current state: bias (3), diagonal of P (7), code 0."""
    for k in range(3):
        x_out[k] = row[BIAS + k]
    for k in range(7):
        x_out[3 + k] = row[COV + 8 * k]
    x_out[10] = 0.0


@njit(cache=True, inline="always")
def _start(row, coef, first, qw, qx, qy, qz):
    start_row(row, coef, first, qw, qx, qy, qz)


@njit(cache=True, inline="always")
def _step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """:func:`filter_step`, its outputs and flags (the field is required: ``has_mag`` is
    always true; a missing one arrives as the zero sentinel)."""
    code, disturbed = filter_step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2)
    q_out[0], q_out[1], q_out[2], q_out[3] = row[Q], row[Q + 1], row[Q + 2], row[Q + 3]
    _hold(row, coef, x_out)
    x_out[10] = code
    return code_flags(code, disturbed)


@njit(cache=True)
def run(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples (``contract.run_series``)."""
    contract.run_series(_start, _step, _hold, rows, clock, coefs, t, gyr, acc, mag, has,
                        q_out, x_out, flags_out)


@njit(cache=True, parallel=True)
def run_many(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples, shared among threads (``contract.run_series_parallel``)."""
    contract.run_series_parallel(_start, _step, _hold, rows, clock, coefs, t, gyr, acc, mag, has,
                                 q_out, x_out, flags_out)


@njit(cache=True)
def update(rows, clock, coefs, dt, gyr, acc, mag, has, q_out, x_out, flags_out):
    """One sample of S sensors (``contract.update_samples``)."""
    contract.update_samples(_start, _step, _hold, rows, clock, coefs, dt, gyr, acc, mag, has,
                            q_out, x_out, flags_out)


@njit(cache=True)
def update_one(rows, clock, coefs, dt, g, a, m, has, out):
    """One sample of one sensor (``contract.update_one``); returns the flags."""
    return contract.update_one(_start, _step, _hold, rows, clock, coefs, dt, g, a, m, has, out)


@njit(cache=True)
def start(rows, coefs, quat0):
    """Start S sensors at quat0 (S, 4) (``contract.start_rows``)."""
    contract.start_rows(_start, rows, coefs, quat0)


# -- series of state arrays (the all-accelerometer pipeline, oracle tests) -------------------
@njit(cache=True)
def bias_kf(
    quat_state, bias_state, cov_state, gyr, acc, mag, dt, up, north,
    gyr_var, bias_var, acc_var, acc_motion_var_m2_s4, gravity2_m2_s4, mag_var,
    quat_out, bias_out, cov_diag_out, flags,
):  # fmt: skip
    """Run the filter as printed (no extension) for S sensors over N samples, in place.

    quat_state (S, 4), bias_state (S, 3) rad/s, cov_state (S, 7, 7): state before sample 0,
    replaced by the state after the last sample. gyr (S, N, 3) rad/s, acc (S, N, 3) m/s²,
    mag (S, N, 3) any unit; dt (N,) s (dt = 0: output the state as it is). up, north (3,):
    unit earth-frame up and horizontal north. gyr_var (3,) (rad/s)²/Hz and bias_var (3,)
    (rad/s)²/s: squared noise densities per body axis; acc_var (m/s²)²/Hz: squared
    white-noise density; mag_var 1/Hz: the field's squared white-noise density relative
    to the norm of the first field sample ``|m₀|``, ``(σ_M/|m₀|)²`` (eq. 44 becomes
    ``mag_var (|m₀|/|m|)²``: unit-free); acc_motion_var_m2_s4: σ_C² (eq. 43);
    gravity2_m2_s4: g², the squared magnitude of the expected gravity vector (eq. 41).
    Outputs (S, N, 4), (S, N, 3), (S, N, 7) diagonal of P, flags (S, N) int8 (TRIAD flags,
    or NOT_PD): see :func:`filter_step` for what a flagged sample gets.
    :func:`bias_kf_extended` with every extension at its neutral value.
    """
    n_sensors, n = acc.shape[0], acc.shape[1]
    field_ref = np.full((n_sensors, 2), np.nan)
    disturbed = np.empty((n_sensors, n), dtype=np.bool_)
    bias_kf_extended(
        quat_state, bias_state, cov_state, field_ref, gyr, acc, mag, dt, up, north,
        gyr_var, bias_var, acc_var, acc_motion_var_m2_s4, gravity2_m2_s4, mag_var,
        False, 0.0, 0.0, 0.0, 0.0, math.inf, 1.0, math.inf, math.inf,
        quat_out, bias_out, cov_diag_out, flags, disturbed,
    )


@njit(cache=True)
def bias_kf_extended(
    quat_state, bias_state, cov_state, field_ref, gyr, acc, mag, dt, up, north,
    gyr_var, bias_var, acc_var, acc_motion_var_m2_s4, gravity2_m2_s4, mag_var,
    decoupled, gyr_scale_var_s, acc_norm_corr_s, mag_norm_corr_s, mag_dip_corr_s,
    tilt_gate, tilt_gate_exponent, mag_norm_tol, mag_dip_tol_rad,
    quat_out, bias_out, cov_diag_out, flags, mag_disturbed,
):  # fmt: skip
    """:func:`bias_kf` with margtrack's extensions (arguments as there, plus these).

    field_ref (S, 2): the field's reference norm (mag unit) and ``sin`` of its dip (the
    field's component along predicted down over its norm), state; NaN until the first
    sample with a non-zero field sets them from that sample and the orientation then
    (the norm also scales ``mag_var``, see ``bias_kf_model._mag_variance``).
    decoupled: the tilt/heading measurement (``bias_kf_model._decoupled``,
    :func:`fill_decoupled_cov`) instead of TRIAD's. gyr_scale_var_s κ², s: rate noise
    density per axis ``n_k² + κ² ω_k²`` (eq. 31). acc_norm_corr_s, mag_norm_corr_s,
    mag_dip_corr_s τ, s: ``σ_G² += (|a|/g - 1)² 2τ/T`` (eqs. 41-43), ``σ_N² += ((|m|/|m₀|
    - 1)² 2τ_m + (sin δ - sin δ₀)² 2τ_δ)/T`` (eq. 44). tilt_gate γ (inf: off),
    tilt_gate_exponent p: with ``d²`` the normalised tilt innovation, ``σ_G²`` is
    multiplied by ``(d²/γ)^p`` where ``d² > γ``. All neutral (False, 0, 0, 0, 0, inf):
    :func:`bias_kf` exactly. mag_norm_tol (relative) and mag_dip_tol_rad: a field whose
    norm or dip is farther than that from the reference is flagged disturbed
    (``mag_disturbed`` (S, N) bool out).

    The same :func:`filter_step` as the estimator's; the sentinels as there.
    """
    n_sensors, n = acc.shape[0], acc.shape[1]
    coef = coefficients(
        gyr_var, bias_var, acc_var, acc_motion_var_m2_s4, gravity2_m2_s4, mag_var, decoupled,
        gyr_scale_var_s, acc_norm_corr_s, mag_norm_corr_s, mag_dip_corr_s, tilt_gate,
        tilt_gate_exponent, mag_norm_tol, mag_dip_tol_rad, up, north, 0.0, 0.0, 0.0,
    )
    row = np.zeros(N_ROW)
    for s in range(n_sensors):
        for k in range(4):
            row[Q + k] = quat_state[s, k]
        for k in range(3):
            row[BIAS + k] = bias_state[s, k]
        for r in range(7):
            for c in range(7):
                row[COV + 7 * r + c] = cov_state[s, r, c]
        row[FIELD_REF], row[FIELD_REF + 1] = field_ref[s, 0], field_ref[s, 1]
        row[DT] = 0.0
        for i in range(n):
            code, disturbed = filter_step(
                row, coef, dt[i], gyr[s, i, 0], gyr[s, i, 1], gyr[s, i, 2],
                acc[s, i, 0], acc[s, i, 1], acc[s, i, 2], mag[s, i, 0], mag[s, i, 1],
                mag[s, i, 2],
            )
            flags[s, i] = code
            mag_disturbed[s, i] = disturbed
            for k in range(4):
                quat_out[s, i, k] = row[Q + k]
            for k in range(3):
                bias_out[s, i, k] = row[BIAS + k]
            for k in range(7):
                cov_diag_out[s, i, k] = row[COV + 8 * k]
        for k in range(4):
            quat_state[s, k] = row[Q + k]
        for k in range(3):
            bias_state[s, k] = row[BIAS + k]
        for r in range(7):
            for c in range(7):
                cov_state[s, r, c] = row[COV + 7 * r + c]
        field_ref[s, 0], field_ref[s, 1] = row[FIELD_REF], row[FIELD_REF + 1]
