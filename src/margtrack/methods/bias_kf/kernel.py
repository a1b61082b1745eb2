"""Kernel of Ang's bias-augmented quaternion Kalman filter (003 eqs. 20-51), on the contract.

The step is :func:`margtrack.methods.bias_kf.step.filter_step` (state row and
coefficients: :mod:`margtrack.methods.bias_kf.layout`); this module runs it on the
contract (:mod:`margtrack.estimator.skeleton`: clock, screening, starts) and over series of
state arrays (:func:`bias_kf`, :func:`bias_kf_extended`: the all-accelerometer pipeline
and the oracle tests use them), and gathers the names the filter and its tests use.

Extra outputs per sample (``x_out``): the bias (3), the diagonal of ``P`` (7) and the
sample's code (1: OK, ZERO_ACC, ZERO_MAG, PARALLEL or NOT_PD). Flags: PARALLEL is
MAG_IGNORED, NOT_PD is ACC_IGNORED and MAG_IGNORED, a field's norm or dip beyond the
shared tolerances from the reference is MAG_DISTURBED (it is still used, with the noise of
``mag_norm_correlation_s``/``mag_dip_correlation_s``).
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator import skeleton as contract
from margtrack.estimator.jit import njit
from margtrack.estimator.triad_kernel import OK, PARALLEL, ZERO_ACC, ZERO_MAG
from margtrack.methods.bias_kf.layout import (
    BIAS,
    BIAS_SD,  # noqa: F401 (the filter's state layout)
    COV,
    DIP_REF,
    DT,
    FIELD_REF,
    N_COEF,  # noqa: F401 (the estimator's coefficient vector)
    N_ROW,
    Q,
    coefficients,
)
from margtrack.methods.bias_kf.model import (
    _reduced_update,  # noqa: F401 (the partial updates' algebra, known here by its tests)
    _triad,  # noqa: F401 (the TRIAD measurement, known here by its tests and benchmark)
    fill_decoupled_cov,
    fill_phi_q,
    fill_qtilde,
    fill_quat_noise,
    fill_triad_cov,
)
from margtrack.methods.bias_kf.step import NOT_PD, code_flags, filter_step, start_row

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
    "start_row",
]


#: extra outputs per sample: bias (3), diagonal of P (7), degenerate code (1)
N_X = 11


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


run, lanes, start = contract.entry_points(__name__)


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
        row[DIP_REF] = np.nan  # its dip bounds: derived at the first field sample
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
