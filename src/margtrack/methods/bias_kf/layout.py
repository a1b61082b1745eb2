"""The state row and the coefficient vector of Ang's bias filter (``kernel.py``).

Row layout (one sensor, after the contract's ``N_CONTRACT`` slots):

- ``Q`` (4): the filter's orientation (body to earth, output frame);
- ``BIAS`` (3): the rate bias, rad/s; ``BIAS_SD`` (3): its standard deviation, rad/s
  (square roots of ``P``'s bias diagonal, kept for the accessor);
- ``COV`` (49): ``P``, row-major 7x7, of ``[q (4), b (3)]``;
- ``FIELD_REF`` (2): the norm (data's unit) and the sine of the dip of the first field
  sample, NaN before it (state of the field-noise terms and the disturbance flag);
  ``DIP_REF`` (4): the reference sine and the ``C_STAMP`` the next two hold for, the sines
  of the reference dip minus and plus ``mag_dip_tol`` (a field outside is disturbed);
- ``DT`` (1), ``STAMP`` (1), ``DT_GYR`` (3), ``DT_WALK`` (3), ``DT_ACC`` (1),
  ``DT_ACC_CORR`` (1), ``DT_MAG`` (1): coefficients of the sample interval ``T``
  (``n² T`` per axis, ``n_b² T`` per axis, ``(σ_W²/T + σ_C²)/g²``, ``2τ_a/T``,
  ``mag_var/T``), derived when ``T`` or the coefficient vector (its ``C_STAMP``) changes;
  they depend on nothing else, so they never change a result (nor does ``DIP_REF``);
- ``WORK`` (``N_WORK``): scratch of one step (the small matrices of the algebra, ``W_*``,
  and the scratch of :mod:`margtrack.methods.bias_kf.cov` and
  :mod:`margtrack.methods.bias_kf.partial`; written before being read in every step, so
  not state). Keeping them in the row spares the allocations of a step, and offsets
  known to the compiler let it keep the small matrices in registers.

Coefficients (``C_*``, after the screening's): the squared noise densities per body axis,
the extensions' values (neutral: the filter as printed), the earth-frame up and north and
their reference triad, the initial variances; see :func:`coefficients`.
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator import skeleton as contract
from margtrack.estimator.jit import njit
from margtrack.methods.bias_kf import cov, partial

__all__ = ["N_COEF", "N_ROW", "coefficients"]

# -- the row ---------------------------------------------------------------------------------
Q = contract.N_CONTRACT  # 4: orientation, body to earth
BIAS = Q + 4  # 3: rate bias, rad/s
BIAS_SD = BIAS + 3  # 3: its standard deviation, rad/s
COV = BIAS_SD + 3  # 49: P, row-major 7x7
FIELD_REF = COV + 49  # 2: reference field norm, sine of its dip (NaN: none yet)
DIP_REF = FIELD_REF + 2  # 4: the reference sine and C_STAMP they hold for, sine bounds
DT = DIP_REF + 4  # 1: the interval T the DT_* coefficients hold for, s (0: none)
STAMP = DT + 1  # 1: the C_STAMP of the coefficient vector they came from
DT_GYR = STAMP + 1  # 3: n_k² T, rad² (rate noise as an angle over the period, eq. 31)
DT_WALK = DT_GYR + 3  # 3: n_b,k² T, (rad/s)² (bias walk, eq. 31)
DT_ACC = DT_WALK + 3  # 1: (σ_W²/T + σ_C²)/g² (eqs. 41-43)
DT_ACC_CORR = DT_ACC + 1  # 1: 2 τ_a / T
DT_MAG = DT_ACC_CORR + 1  # 1: mag_var / T (eq. 44)
WORK = DT_MAG + 1  # N_WORK: scratch of one step

# scratch, offsets within WORK (matrices row-major)
W_QT = 0  # (4, 3) Q̃
W_XI = W_QT + 12  # (3, 3) an angle covariance (Ξθ, the initial one)
W_NOISE = W_XI + 9  # (4, 4) its quaternion covariance (the measurement's V)
W_COV = W_NOISE + 16  # bias_kf_cov.N_SCRATCH: the prediction's and the full update's
W_PARTIAL = W_COV + cov.N_SCRATCH  # bias_kf_partial.N_SCRATCH: the partial updates'
N_WORK = W_PARTIAL + partial.N_SCRATCH
NOISE = WORK + W_NOISE  # absolute offsets in the row
SCRATCH = WORK + W_COV
PARTIAL = WORK + W_PARTIAL
DX = SCRATCH + cov.F_DX  # the full update's K ν (7)
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
C_REF_TRIAD = 29  # 9: the reference triad s1, s2, s3 of up and north (triad.reference_triad)
N_COEF = 38



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
    # triad.reference_triad, written out: this function also runs as plain Python
    ux, uy, uz, nx, ny, nz = up[0], up[1], up[2], north[0], north[1], north[2]
    s2x, s2y, s2z = uy * nz - uz * ny, uz * nx - ux * nz, ux * ny - uy * nx
    norm = math.sqrt(s2x * s2x + s2y * s2y + s2z * s2z)
    s2x, s2y, s2z = s2x / norm, s2y / norm, s2z / norm
    ref = (ux, uy, uz, s2x, s2y, s2z, uy * s2z - uz * s2y, uz * s2x - ux * s2z,
           ux * s2y - uy * s2x)
    for k in range(9):
        c[C_REF_TRIAD + k] = ref[k]
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
