"""The per-sample step of Marins' EKF for a state of n = 7 or 10 numbers (001; 003's bias).

The coefficient and row layouts (``C_*``, ``E_*``), the outputs (``X_*``) and the
inline start, step and hold that :mod:`margtrack.methods.ekf.kernel` (7 states) and
:mod:`margtrack.methods.ekf.bias_kernel` (10 states) compile with their n; the model, the
measurements and the layouts are described in :mod:`margtrack.methods.ekf.kernel`.
"""

from __future__ import annotations

import math

from margtrack.estimator import skeleton as contract
from margtrack.estimator.jit import literally, njit
from margtrack.estimator.screen_kernel import ACC_IGNORED, MAG_IGNORED, REF_TAU_S
from margtrack.estimator.triad_kernel import (
    FASTMATH,
    OK,
    SOLVER_FAILED,
    ZERO_ACC,
    ZERO_MAG,
    unit_pair,
)
from margtrack.methods import rest_null_kernel as rest_null
from margtrack.methods.ekf.fit import fit
from margtrack.methods.ekf.model import (
    axis_noise,
    mirror,
    predict_covariance,
    scalar_update,
    transition_terms,
    vector_reading,
)
from margtrack.methods.ekf.noise import disturbance_share, quaternion_update, rotation_covariance
from margtrack.single_frame.davenport_kernel import field_from_dip, measured_dip

#: flag: the innovation variance of a measured component was not positive (or the update
#: would leave a zero or non-finite quaternion): that and the later components were skipped
NOT_PD = 5
#: the gyroscope measurement is limited to this, rad/s per axis (no sensor reaches it)
MAX_RATE_RAD_S = 1e6
#: the interval's constants (a dozen exp/expm1) are kept while the interval stays within
#: this relative distance of the one they were computed for: the intervals of a regular
#: series differ by the rounding of their timestamps (t = i / 285.714 s: up to 1e-10
#: relative at t = 3000 s), which would otherwise recompute them at many samples. The
#: constants' relative error is then below 3e-9 (Var Δφ ∝ h³).
DT_REUSE_REL = 1e-9

# -- coefficients (after the contract's screening coefficients) ---------------------------
C_APPROACH = 0  # 1 or 2
C_TAU = 1  # 3: τ per axis, s
C_RATE_VAR = 4  # 3: driving-noise density², (rad/s)²/Hz
C_GYR_VAR = 7  # 3: gyroscope noise density², (rad/s)²/Hz
C_QUAT_VAR = 10  # 1/Hz
C_ACC_VAR = 11  # (m/s²)²/Hz
C_MAG_VAR = 12  # 1/Hz (relative to the field norm)
C_GRAVITY2 = 13  # g², (m/s²)²
C_MAG_WEIGHT = 14  # ρ
C_GN_TOL = 15
C_GN_MAX_IT = 16
C_UP = 17  # 3: unit earth up
C_NORTH = 20  # 3: unit earth north (horizontal)
C_DIP = 23  # the given dip, rad (NaN: measure each sensor's)
C_FIELD = 24  # 3: the unit field reference of the given dip
C_INIT_RATE_VAR = 27  # (rad/s)²
C_INIT_QUAT_VAR = 28
C_GEN = 29  # generation of these coefficients (keys the row's interval constants)
C_NULL = 30  # rest_null.N_RC: the gyro null's coefficients
C_BIAS_WALK_VAR = C_NULL + rest_null.N_RC  # 3: bias random-walk density², (rad/s)²/s
C_INIT_BIAS_VAR = C_BIAS_WALK_VAR + 3  # (rad/s)²: the bias's initial variance per axis
C_ACC_DIST_S = C_INIT_BIAS_VAR + 1  # s: linear acceleration's correlation time (0: 001's noise)
C_MAG_DIST_S = C_ACC_DIST_S + 1  # s: the field disturbance's correlation time (0: none)
N_COEF = C_MAG_DIST_S + 1

# -- one sensor's row (after the contract's slots; see the module docstring) -------------
E_DIP = contract.N_CONTRACT  # measured dip, rad (NaN: not yet)
E_FIELD = E_DIP + 1  # 3: unit field reference from it (NaN: not known)
E_MAG_NORM = E_FIELD + 3  # the field's reference norm (mag_disturbance_s; 0: none yet)
E_NULL = E_MAG_NORM + 1  # rest_null.N_REST_NULL: the gyro null from the still start
E_DT = E_NULL + rest_null.N_REST_NULL  # interval of the constants below, s (NaN: none)
E_GEN = E_DT + 1  # coefficient generation they were computed with
E_K = E_GEN + 1  # 19: a, c, Var Δω, Cov(Δφ, Δω), Var Δφ, σ_b² h (3 each), field gain
E_X = E_K + 19  # n: [ω (rad/s), q(, b (rad/s))]
N = 7  # this module's state size
E_P = E_X + N  # 49: covariance, row-major
E_PH = E_P + N * N  # 7: scratch of an update
N_ROW = E_PH + N

# -- extra outputs per sample (7-state; out_offsets gives them for any n) -------------------
X_RATE = 0  # 3
X_COV = 3  # 7: the covariance diagonal
X_ITER = 10
X_CODE = 11
X_NULL = 12  # 3
N_OUT = 15


@njit(cache=True, inline="always")
def offsets(n):
    """Row offsets of a state of size n: covariance, scratch, bias of the raw rate, its sd."""
    p = E_X + n
    ph = p + n * n
    return p, ph, ph + n, ph + n + 3


@njit(cache=True, inline="always")
def out_offsets(n):
    """Offsets in ``x_out``: covariance diagonal, iterations, code, null, bias, bias sd."""
    return 3, 3 + n, 4 + n, 5 + n, 8 + n, 11 + n


#: flag bits of each degenerate code (margtrack.estimator.flags): OK 0, ZERO_ACC, ZERO_MAG
#: (the screening's flag stands; the accelerometer was used), PARALLEL, SOLVER_FAILED, NOT_PD
_BOTH = ACC_IGNORED | MAG_IGNORED


@njit(cache=True, inline="always")
def _code_flags(code):
    if code == ZERO_ACC:
        return ACC_IGNORED
    if code == OK or code == ZERO_MAG:
        return 0
    return _BOTH


@njit(cache=True, inline="always")
def _bias_outputs(row, n, nx, ny, nz):
    """The bias of the raw rate (the null plus b) and its sd into the row."""
    p, _, bias, bias_sd = offsets(n)
    null = (nx, ny, nz)
    for k in range(3):
        row[bias + k] = null[k] + row[E_X + 7 + k]
        row[bias_sd + k] = math.sqrt(max(row[p + (n + 1) * (7 + k)], 0.0))


@njit(cache=True, inline="always")
def start_n(row, coef, first, qw, qx, qy, qz, n):
    """(Re)start at q with zero rate and the initial covariance; the first start also
    forgets the dip, the gyro null and the bias (a restart keeps them, and b's covariance
    block)."""
    p = offsets(n)[0]
    for k in range(3):
        row[E_X + k] = 0.0
    row[E_X + 3], row[E_X + 4], row[E_X + 5], row[E_X + 6] = qw, qx, qy, qz
    for i in range(7):
        for j in range(n):
            row[p + i * n + j] = 0.0
            row[p + j * n + i] = 0.0
    for k in range(3):
        row[p + (n + 1) * k] = coef[C_INIT_RATE_VAR]
    for k in range(3, 7):
        row[p + (n + 1) * k] = coef[C_INIT_QUAT_VAR]
    row[E_DT] = math.nan
    if first:
        row[E_DIP] = math.nan
        row[E_FIELD] = row[E_FIELD + 1] = row[E_FIELD + 2] = math.nan
        row[E_MAG_NORM] = 0.0
        rest_null.fresh_one(row, E_NULL)
        for i in range(7, n):
            row[E_X + i] = 0.0
            for j in range(7, n):
                row[p + i * n + j] = coef[C_INIT_BIAS_VAR] if i == j else 0.0
    if n > 7:
        k = E_NULL + rest_null.RN_NULL
        _bias_outputs(row, n, row[k], row[k + 1], row[k + 2])


@njit(cache=True, inline="always")
def _outputs(row, x_out, iterations, code, nx, ny, nz, n):
    p, _, bias, bias_sd = offsets(n)
    o_cov, o_iter, o_code, o_null, o_bias, o_sd = out_offsets(n)
    for k in range(3):
        x_out[k] = row[E_X + k]
    for k in range(n):
        x_out[o_cov + k] = row[p + (n + 1) * k]
    x_out[o_iter] = iterations
    x_out[o_code] = code
    x_out[o_null], x_out[o_null + 1], x_out[o_null + 2] = nx, ny, nz
    if n > 7:
        for k in range(3):
            x_out[o_bias + k] = row[bias + k]
            x_out[o_sd + k] = row[bias_sd + k]


@njit(cache=True, inline="always")
def _constants(row, coef, h):
    """The interval's constants (``E_K``), recomputed when h changes by more than
    ``DT_REUSE_REL`` (relative) from the interval they were computed for, or the
    coefficients change."""
    if not abs(row[E_DT] - h) <= DT_REUSE_REL * h or row[E_GEN] != coef[C_GEN]:
        for k in range(3):
            tau = coef[C_TAU + k]
            row[E_K + k] = math.exp(-h / tau)
            row[E_K + 3 + k] = -tau * math.expm1(-h / tau)
            vw, cpw, vp = axis_noise(h, tau, coef[C_RATE_VAR + k])
            row[E_K + 6 + k], row[E_K + 9 + k], row[E_K + 12 + k] = vw, cpw, vp
            row[E_K + 15 + k] = coef[C_BIAS_WALK_VAR + k] * h
        row[E_K + 18] = -math.expm1(-h / REF_TAU_S)  # the field reference's gain
        row[E_DT] = h
        row[E_GEN] = coef[C_GEN]


@njit(cache=True, inline="always")
def _k3(row, o):
    return row[E_K + o], row[E_K + o + 1], row[E_K + o + 2]


@njit(cache=True, inline="always")
def _update_vector(row, n, zv, jac, meas0, meas1, meas2, var, pw, px, py, pz):
    """The three components of a unit vector reading, linearised at the prediction
    ``q⁻ = (pw, px, py, pz)``; False at the first whose update failed."""
    p, ph, _, _ = offsets(n)
    meas = (meas0, meas1, meas2)
    for i in range(3):
        hr = jac[i]
        nu = meas[i] - zv[i] - (hr[0] * (row[E_X + 3] - pw) + hr[1] * (row[E_X + 4] - px)
                                + hr[2] * (row[E_X + 5] - py) + hr[3] * (row[E_X + 6] - pz))
        if not scalar_update(row, E_X, p, n, ph, -1, -1, hr[0], hr[1], hr[2], hr[3], nu, var):
            return False
    return True


@njit(cache=True, inline="always")
def _unit_update(row, n, k, nu, var):
    """The scalar update of state component k (``h = e_k``) by innovation nu, variance var."""
    p, ph, _, _ = offsets(n)
    return scalar_update(row, E_X, p, n, ph, k, -1, 0.0, 0.0, 0.0, 0.0, nu, var)


@njit(cache=True, inline="always")
def _gyro_update(row, coef, n, rate, k, ih):
    """The gyroscope's axis k: it measures ω_k (or ω_k + b_k with the bias state), the rate
    limited to ±``MAX_RATE_RAD_S``; variance density² / h (ih = 1/h)."""
    p, ph, _, _ = offsets(n)
    rate = min(max(rate, -MAX_RATE_RAD_S), MAX_RATE_RAD_S)
    nu = rate - row[E_X + k]
    kb = -1
    if n > 7:
        nu -= row[E_X + 7 + k]
        kb = 7 + k
    return scalar_update(row, E_X, p, n, ph, k, kb, 0.0, 0.0, 0.0, 0.0, nu,
                         coef[C_GYR_VAR + k] * ih)


@njit(cache=True, inline="always")
def _field_share(row, coef, h, ih, norm):
    """The field's disturbance share against the reference norm ``E_MAG_NORM``, which then
    follows the field slowly (the screening's time constant, ``screen.REF_TAU_S``, its gain
    among the interval's constants); the first usable field sets it."""
    ref = row[E_MAG_NORM]
    if not ref > 0.0:
        row[E_MAG_NORM] = norm
        return 0.0
    row[E_MAG_NORM] = ref + row[E_K + 18] * (norm - ref)  # (_constants: -expm1(-h/τ))
    return disturbance_share(norm, ref, coef[C_MAG_DIST_S], ih)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", _nrt=False)
def step_n(row, coef, h, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out, n):
    """One screened sample: predict over h (0: output the state as it is), update from the
    gyroscope and the accelerometer/magnetometer pair (module docstring); the flag bits.

    Compiled once per state size n (a literal at the call site, ``literally``), not inlined
    into its caller: numba's inliner copies the inlined body's variable table once per
    block, and this body inlines a dozen helpers (16,800 variables in 725 blocks), which
    took 85 s of a 110 s compilation, in every process with an empty cache. Without numba's
    reference counting (``_nrt=False``: the step creates no arrays; the helpers it inlines
    would otherwise count their array arguments, a dozen atomic calls per sample) and with
    numpy's division semantics (no zero checks: every divisor is guarded or positive).
    """
    literally(n)
    p = offsets(n)[0]
    nx, ny, nz = rest_null.step_one(
        row, E_NULL, coef, C_NULL, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, h
    )
    gyr = (g0 - nx, g1 - ny, g2 - nz)
    ux, uy, uz = coef[C_UP], coef[C_UP + 1], coef[C_UP + 2]
    # the field reference: the given dip's, or from the sensor's first valid sample
    if math.isnan(coef[C_DIP]):
        if math.isnan(row[E_DIP]):
            res = unit_pair(a0, a1, a2, m0, m1, m2)
            if res[0] == OK:
                dip = measured_dip(res[1], res[2], res[3], res[4], res[5], res[6])
                row[E_DIP] = dip
                row[E_FIELD], row[E_FIELD + 1], row[E_FIELD + 2] = field_from_dip(
                    math.sin(dip), math.cos(dip), ux, uy, uz,
                    coef[C_NORTH], coef[C_NORTH + 1], coef[C_NORTH + 2],
                )
        hx, hy, hz = row[E_FIELD], row[E_FIELD + 1], row[E_FIELD + 2]
    else:
        hx, hy, hz = coef[C_FIELD], coef[C_FIELD + 1], coef[C_FIELD + 2]
    X = E_X  # the state's offset in the row (no view: a view costs reference counting)
    flag = OK
    iterations = 0
    if h > 0.0:
        # -- prediction: x⁺ = f(x), P = F P Fᵀ + Q ----------------------------------------
        _constants(row, coef, h)
        a, c = _k3(row, 0), _k3(row, 3)
        xn, g, f, _ = transition_terms(row[X], row[X + 1], row[X + 2], row[X + 3], row[X + 4],
                                       row[X + 5], row[X + 6], a[0], a[1], a[2], c[0], c[1],
                                       c[2])
        predict_covariance(row, p, n, a, c, g, f, _k3(row, 6), _k3(row, 9), _k3(row, 12),
                           _k3(row, 15))
        for k in range(7):
            row[X + k] = xn[k]
        pw, px, py, pz = row[X + 3], row[X + 4], row[X + 5], row[X + 6]
        # -- measurement: the gyroscope (ω, or ω + b), then the pair ----------------------
        approach = coef[C_APPROACH]
        res = unit_pair(a0, a1, a2, m0, m1, m2)
        flag = res[0]
        ax, ay, az, mx, my, mz = res[1], res[2], res[3], res[4], res[5], res[6]
        gw, gx, gy, gz = pw, px, py, pz
        ih = 1.0 / h  # the measurement variances are density² / h
        # the evidence-driven noise (kernels.ekf_noise): shares of the disturbances
        s_a = s_m = 0.0
        evidence = coef[C_ACC_DIST_S] > 0.0 or coef[C_MAG_DIST_S] > 0.0
        if evidence:
            s_a = disturbance_share(math.sqrt(a0 ** 2 + a1 ** 2 + a2 ** 2),
                                    math.sqrt(coef[C_GRAVITY2]), coef[C_ACC_DIST_S], ih)
            if coef[C_MAG_DIST_S] > 0.0 and flag == OK:
                s_m = _field_share(row, coef, h, ih, math.sqrt(m0 ** 2 + m1 ** 2 + m2 ** 2))
        if flag == OK and approach == 2.0:  # the Gauss-Newton quaternion, from q⁻ alone
            inq = 1.0 / math.sqrt(pw ** 2 + px ** 2 + py ** 2 + pz ** 2)
            gn_ok, gw, gx, gy, gz, iterations = fit(
                ax, ay, az, mx, my, mz, ux, uy, uz, hx, hy, hz, pw * inq, px * inq,
                py * inq, pz * inq, coef[C_MAG_WEIGHT], coef[C_GN_TOL], int(coef[C_GN_MAX_IT]),
            )
            if not gn_ok:
                flag = SOLVER_FAILED
            elif gw * pw + gx * px + gy * py + gz * pz < 0.0:
                gw, gx, gy, gz = -gw, -gx, -gy, -gz  # sign nearest q⁻
        # one call per component with its index a literal (loops over the index would
        # leave it a variable: masked and scattered row copies, stalls on every update)
        ok = _gyro_update(row, coef, n, gyr[0], 0, ih)
        ok = ok and _gyro_update(row, coef, n, gyr[1], 1, ih)
        ok = ok and _gyro_update(row, coef, n, gyr[2], 2, ih)
        if flag == ZERO_MAG:  # gravity direction alone (module docstring)
            na = math.sqrt(a0 ** 2 + a1 ** 2 + a2 ** 2)
            zv, jac = vector_reading(pw, px, py, pz, ux, uy, uz)
            if approach == 2.0:
                var = 16.0 * coef[C_QUAT_VAR] / h + s_a
            else:
                var = coef[C_ACC_VAR] / h / coef[C_GRAVITY2] + s_a
            if ok:
                ok = _update_vector(row, n, zv, jac, a0 / na, a1 / na, a2 / na, var,
                                    pw, px, py, pz)
        elif flag == OK and approach == 2.0 and evidence:
            okc, c00, c01, c02, c11, c12, c22 = rotation_covariance(
                ax, ay, az, mx, my, mz, coef[C_MAG_WEIGHT], s_a, s_m)
            if not okc:
                c00 = c01 = c02 = c11 = c12 = c22 = 0.0
            ok = ok and quaternion_update(row, X, p, n, offsets(n)[1], gw, gx, gy, gz,
                                          coef[C_QUAT_VAR] * ih, c00, c01, c02, c11, c12, c22)
        elif flag == OK and approach == 2.0:
            var = coef[C_QUAT_VAR] * ih  # H = I on the quaternion: one component each
            ok = ok and _unit_update(row, n, 3, gw - row[X + 3], var)
            ok = ok and _unit_update(row, n, 4, gx - row[X + 4], var)
            ok = ok and _unit_update(row, n, 5, gy - row[X + 5], var)
            ok = ok and _unit_update(row, n, 6, gz - row[X + 6], var)
        elif flag == OK:  # approach 1: the gravity and field readings, linearised at q⁻
            za, ja = vector_reading(pw, px, py, pz, ux, uy, uz)
            zm, jm = vector_reading(pw, px, py, pz, hx, hy, hz)
            if ok:
                ok = _update_vector(row, n, za, ja, ax, ay, az,
                                    coef[C_ACC_VAR] / h / coef[C_GRAVITY2] + s_a,
                                    pw, px, py, pz)
            if ok:
                ok = _update_vector(row, n, zm, jm, mx, my, mz, coef[C_MAG_VAR] / h + s_m,
                                    pw, px, py, pz)
        mirror(row, p, n)
        if not ok:
            flag = NOT_PD
        nq = math.sqrt(row[X + 3] ** 2 + row[X + 4] ** 2 + row[X + 5] ** 2 + row[X + 6] ** 2)
        if not (nq > 0.0 and nq < math.inf):  # undo: keep the predicted attitude
            flag = NOT_PD
            row[X + 3], row[X + 4], row[X + 5], row[X + 6] = pw, px, py, pz
            nq = math.sqrt(pw ** 2 + px ** 2 + py ** 2 + pz ** 2)
        inq = 1.0 / nq
        for k in range(3, 7):  # normalise after the update (001 Fig. 3)
            row[X + k] *= inq
    inq = 1.0 / math.sqrt(row[X + 3] ** 2 + row[X + 4] ** 2 + row[X + 5] ** 2 + row[X + 6] ** 2)
    for k in range(4):
        q_out[k] = row[X + 3 + k] * inq
    if n > 7:
        _bias_outputs(row, n, nx, ny, nz)
    _outputs(row, x_out, iterations, flag, nx, ny, nz, n)
    return _code_flags(flag)


@njit(cache=True, inline="always")
def hold_n(row, coef, x_out, n):
    """Outputs of a held sample (a sensor waiting for a usable sample): the state's."""
    k = E_NULL + rest_null.RN_NULL
    _outputs(row, x_out, 0, OK, row[k], row[k + 1], row[k + 2], n)
