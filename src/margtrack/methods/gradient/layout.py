"""Layout of the gradient-descent kernel's rows, coefficients and outputs
(``methods/gradient/kernel.py``, whose docstring has them in words), and its constants.
"""

from __future__ import annotations

from margtrack.estimator import skeleton as contract

__all__ = [  # every constant: methods/gradient/kernel.py takes them all
    "ACC_IGNORED",
    "C_BETA",
    "C_EXACT",
    "C_GRAVITY",
    "C_MAG_MODE",
    "C_TO_FRAME",
    "C_UP",
    "FIELD_SAFE",
    "FORWARD_ESTIMATED",
    "FORWARD_MEASURED",
    "FORWARD_MIN",
    "FULL_ADAPTIVE",
    "FULL_FIXED",
    "GRADIENT_MIN",
    "G_ACC_HELD",
    "G_MAG_HELD",
    "G_MAG_REF",
    "G_Q",
    "L_ACC",
    "L_IGNORED",
    "MAG_IGNORED",
    "MAG_REJECTED",
    "N_COEF",
    "N_LEAN",
    "N_OUT",
    "N_ROW",
    "N_X",
    "X_EULER",
    "X_GRAVITY",
    "X_IGNORED",
    "X_LIN_ACC",
]

#: ``ignored`` flag bits: no accelerometer correction (zero vector, the screening's "no
#: measurement"; the sample is gyro-only, without a magnetometer term either)
ACC_IGNORED = 1
#: ... the accelerometer was used but no magnetometer term (zero vector, or its forward
#: component vanishes)
MAG_IGNORED = 2
#: ... a non-zero field that the filter itself did not use: its forward component vanished
#: (with MAG_IGNORED) or there was no accelerometer to go with it (with ACC_IGNORED); the
#: screening's zero sentinel is not this (it flags those samples itself)
MAG_REJECTED = 4

# Below this |∇f| the estimate fits the measurements to rounding (|f| ~ 1e-16); the
# normalised step ∇f/|∇f| would then point in a direction set by rounding noise (and a
# reset to the measured orientation followed by the same sample would step at random), so
# no correction is made. Real data never comes this close (ahrs, which has no such floor,
# gives the same results on BROAD to 1e-15).
GRADIENT_MIN = 1e-12

# magnetic objectives (``C_MAG_MODE``)
FORWARD_ESTIMATED = 0
FORWARD_MEASURED = 1
FULL_ADAPTIVE = 2
FULL_FIXED = 3

# The field's norm is computed directly inside this range and after scaling by its largest
# component outside it (where the squares would over- or underflow): any field unit works.
FIELD_SAFE = (1e-150, 1e150)

# Below this |m_f| / |m| the magnetometer is (almost) parallel to the measured gravity and
# its forward component no longer defines a horizontal direction (sin of about 0.6 deg).
FORWARD_MIN = 1e-2


# -- row slots (after the contract's) ----------------------------------------------------
G_Q = contract.N_CONTRACT  # 4: orientation, body to NWU
G_MAG_REF = G_Q + 4  # 2: fixed field reference [b_x, b_z] (b_x = 0: none yet)
G_ACC_HELD = G_MAG_REF + 2  # 3: held accelerometer sample, m/s²
G_MAG_HELD = G_ACC_HELD + 3  # 3: held magnetometer sample, field unit
N_ROW = G_MAG_HELD + 3

# -- coefficients ---------------------------------------------------------------------------
C_BETA = 0  # rad/s
C_MAG_MODE = 1  # FORWARD_ESTIMATED ... FULL_FIXED
C_EXACT = 2  # 1: q ⊗ exp(ω dt/2); 0: q + q̇ dt
C_GRAVITY = 3  # m/s²
C_TO_FRAME = 4  # 4: c, q_frame = c ⊗ q_nwu
C_UP = 8  # 3: up in the output frame
N_COEF = 11

# -- extra outputs ----------------------------------------------------------------------------
X_EULER = 0  # 3: [yaw, pitch, roll], rad
X_GRAVITY = 3  # 3: gravity component, body, m/s²
X_LIN_ACC = 6  # 3: linear acceleration, output frame, m/s²
X_IGNORED = 9  # 1: ``ignored`` bits
N_OUT = 10

# -- what ``run`` keeps per sample instead (``x_run``; :func:`expand` makes the outputs) ----
L_ACC = 0  # 3: the screened accelerometer sample the step used, m/s² (zeros: none)
L_IGNORED = 3  # 1: ``ignored`` bits
N_LEAN = 4
N_X = N_LEAN  # values per sample ``run`` writes
