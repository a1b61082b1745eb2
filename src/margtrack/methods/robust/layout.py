"""Layout of the robust kernel's rows, coefficients and outputs (``methods/robust/kernel.py``).

One sensor's state is a flat row: the contract's slots, then these (offsets from
``contract.N_CONTRACT``; the Python names are ``Robust.state_layout``'s):

=================  =====  ==============================================================
``R_Q_GYR``        4      q_gyr: body to the strapdown frame I (identity at a start)
``R_Q_ACC``        4      q_acc: I to the level frame (the whole orientation at a start)
``R_HEADING``      1      heading about up from the level frame to ENU, rad
``R_BIAS``         3      gyro bias estimate, rad/s, body axes (kept on restart)
``R_BIAS_VAR``     3      its variance per axis, (rad/s)² (kept on restart)
``R_BIAS_SD``      3      its standard deviation, rad/s (kept; ``sqrt`` of the variance)
``R_ACC_LP``       3      accelerometer low-passed in I, m/s²
``R_ACC_LP_BW``    6      Butterworth states (s1, s2) of x, y, z in turn, m/s²
``R_LP_STAGE``     1      ``LP_EMPTY``, ``LP_FIRST`` or ``LP_FILTER`` (below)
``R_SINCE_START``  1      time since the start (first sample or restart), s
``R_HEADING_N``    1      heading measurements averaged since the start
``R_GYR_REST``     3      gyro low-passed with ``rest_tau_s``, rad/s (rest detector)
``R_ACC_REST``     3      accelerometer low-passed with ``rest_tau_s``, m/s²
``R_STILL``        1      how long the sensor has been still, s
``R_MAG_NORM_REF`` 1      field norm taken as undisturbed (0: from the next sample); kept
``R_MAG_DIP_REF``  1      dip taken as undisturbed, rad, down positive (nan: next); kept
``R_CAND_NORM``    1      a new steady field's norm, candidate reference; kept
``R_CAND_DIP``     1      its dip, rad; kept
``R_CAND_S``       1      how long the candidate has been steady, s; kept
``R_HI_SHIFT``     3      origin of the hard-iron sums: the first usable field (nan: none
                          yet); kept (``methods/robust/hard_iron.py``)
``R_HI_SUMS``      15     the sphere fit's forgotten sums of the field less the origin x
                          and of y = |x|²: weight, x (3), x x^T (xx, xy, xz, yy, yz, zz),
                          y x (3), y, y²; kept
``R_HI_OFFSET``    3      the accepted hard-iron offset, body axes, the field's unit (0:
                          none); subtracted from every field sample; kept
``R_HI_RADIUS``    1      the accepted fit's radius (0: none accepted yet); kept
``R_HI_MOVING``    1      1: the field's norm moves with the orientation and no offset
                          explains it (the field is rejected); kept
``R_HI_COUNT``     1      samples with an interval since the row was made, modulo
                          ``HI_EVERY`` (the fit is solved when it wraps); kept
``R_GAINS``        23     derived, not state: two slots of 11, each the interval (s)
                          and the four time constants its gains were computed for, then
                          k_rest, k_ref, k_mag and the Butterworth (b0, a1, a2); then
                          the offset of the slot in use. An interval found in neither
                          slot is computed into the other one (see :func:`_gains`)
=================  =====  ==============================================================
"""

from __future__ import annotations

from margtrack.estimator import skeleton as contract

__all__ = [  # every constant: methods/robust/kernel.py takes them all
    "C_BIAS_MAX",
    "C_BIAS_MOTION_NOISE",
    "C_BIAS_REST_NOISE",
    "C_BIAS_SIGMA0",
    "C_BIAS_WALK",
    "C_CONVERGE",
    "C_HI_RATE",
    "C_MAG_DIP_REF0",
    "C_MAG_DIP_TOL",
    "C_MAG_NEW_REF_T",
    "C_MAG_NORM_REF0",
    "C_MAG_NORM_TOL",
    "C_MAG_REF_TAU",
    "C_NED",
    "C_REST_ACC",
    "C_REST_GYR",
    "C_REST_MIN_T",
    "C_REST_TAU",
    "C_TAU_ACC",
    "C_TAU_MAG",
    "G_BW",
    "G_DT",
    "G_K_MAG",
    "G_K_REF",
    "G_K_REST",
    "G_REF_TAU",
    "G_REST_TAU",
    "G_TAU_ACC",
    "G_TAU_MAG",
    "HI_EVERY",
    "LP_EMPTY",
    "LP_FILTER",
    "LP_FIRST",
    "MAG_DISTURBED",
    "N_COEF",
    "N_GAINS",
    "N_OUT",
    "N_ROW",
    "REST",
    "R_ACC_LP",
    "R_ACC_LP_BW",
    "R_ACC_REST",
    "R_BIAS",
    "R_BIAS_SD",
    "R_BIAS_VAR",
    "R_CAND_DIP",
    "R_CAND_NORM",
    "R_CAND_S",
    "R_GAINS",
    "R_GAINS_IN_USE",
    "R_GYR_REST",
    "R_HEADING",
    "R_HEADING_N",
    "R_HI_COUNT",
    "R_HI_MOVING",
    "R_HI_OFFSET",
    "R_HI_RADIUS",
    "R_HI_SHIFT",
    "R_HI_SUMS",
    "R_LP_STAGE",
    "R_MAG_DIP_REF",
    "R_MAG_NORM_REF",
    "R_Q_ACC",
    "R_Q_GYR",
    "R_SINCE_START",
    "R_STILL",
    "X_BIAS",
    "X_BIAS_SD",
    "X_MAG_OFFSET",
    "X_QUAT6",
]

# -- stages of the accelerometer low-pass (``R_LP_STAGE``) ---------------------------------
LP_EMPTY = 0  # no usable accelerometer sample since the start
LP_FIRST = 1  # holds the first sample (rotated into I); filter states set at the next step
LP_FILTER = 2  # the second-order Butterworth low-pass, running

# -- flag bits (margtrack.estimator.flags.Flag) ---------------------------------------------
MAG_DISTURBED = 64
REST = 128

# -- parameter layout (``coef`` (N_COEF,)) ------------------------------------------------
C_TAU_ACC = 0  # s
C_TAU_MAG = 1  # s
C_BIAS_WALK = 2  # rad/s/√s
C_BIAS_REST_NOISE = 3  # rad/s
C_BIAS_MOTION_NOISE = 4  # rad/s
C_BIAS_MAX = 5  # rad/s
C_REST_GYR = 6  # rad/s
C_REST_ACC = 7  # m/s²
C_REST_MIN_T = 8  # s
C_REST_TAU = 9  # s
C_MAG_NORM_TOL = 10  # relative
C_MAG_DIP_TOL = 11  # rad
C_MAG_NEW_REF_T = 12  # s
C_MAG_REF_TAU = 13  # s
C_NED = 14  # 1: output in NED
C_CONVERGE = 15  # s, longest start-up phase of the heading (0: none)
C_BIAS_SIGMA0 = 16  # rad/s, initial standard deviation of the bias
C_MAG_NORM_REF0 = 17  # initial field norm reference, the field's unit (0: the first sample)
C_MAG_DIP_REF0 = 18  # initial dip reference, rad (nan: the first sample)
C_HI_RATE = 19  # 1/s, forgetting rate of the hard-iron fit (1 / hard_iron_tau_s; 0: off)
N_COEF = 20

# -- row layout (module docstring) ----------------------------------------------------------
R_Q_GYR = contract.N_CONTRACT
R_Q_ACC = R_Q_GYR + 4
R_HEADING = R_Q_ACC + 4
R_BIAS = R_HEADING + 1
R_BIAS_VAR = R_BIAS + 3
R_BIAS_SD = R_BIAS_VAR + 3
R_ACC_LP = R_BIAS_SD + 3
R_ACC_LP_BW = R_ACC_LP + 3
R_LP_STAGE = R_ACC_LP_BW + 6
R_SINCE_START = R_LP_STAGE + 1
R_HEADING_N = R_SINCE_START + 1
R_GYR_REST = R_HEADING_N + 1
R_ACC_REST = R_GYR_REST + 3
R_STILL = R_ACC_REST + 3
R_MAG_NORM_REF = R_STILL + 1
R_MAG_DIP_REF = R_MAG_NORM_REF + 1
R_CAND_NORM = R_MAG_DIP_REF + 1
R_CAND_DIP = R_CAND_NORM + 1
R_CAND_S = R_CAND_DIP + 1
R_HI_SHIFT = R_CAND_S + 1
R_HI_SUMS = R_HI_SHIFT + 3
R_HI_OFFSET = R_HI_SUMS + 15
R_HI_RADIUS = R_HI_OFFSET + 3
R_HI_MOVING = R_HI_RADIUS + 1
R_HI_COUNT = R_HI_MOVING + 1
R_GAINS = R_HI_COUNT + 1
# offsets within a slot of R_GAINS: the key (interval, time constants), then the gains
G_DT, G_TAU_ACC, G_TAU_MAG, G_REST_TAU, G_REF_TAU, G_K_REST, G_K_REF, G_K_MAG, G_BW = range(9)
N_GAINS = G_BW + 3  # (b0, a1, a2) last
R_GAINS_IN_USE = R_GAINS + 2 * N_GAINS  # offset of the slot in use (0 in a fresh row: the first)
N_ROW = R_GAINS_IN_USE + 1

# extra outputs (x_out)
X_QUAT6 = 0
X_BIAS = 4
X_BIAS_SD = 7
X_MAG_OFFSET = 10  # 3: the accepted hard-iron offset (nan until one is accepted)
N_OUT = 13

#: the hard-iron fit is solved once every this many samples (in the scalar pass)
HI_EVERY = 128
