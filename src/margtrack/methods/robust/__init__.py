"""margtrack's robust filter: bias-estimating, disturbance-rejecting MARG orientation.

Built from the seeds' ideas and what users of current filters expect:

- the orientation is factored into heading and inclination (FQA's decoupling, 002), so the
  magnetometer can only ever change the heading, and only through the horizontal direction
  of the field (004's vector rejection);
- inclination is corrected by the accelerometer low-pass filtered in a quasi-inertial frame
  (the strapdown frame of the gyro), where a moving person's linear acceleration averages
  out while gravity does not; the time constant ``tau_acc_s`` sets the trade-off;
- the gyro bias is a Kalman state per axis (Ang's bias states, 003): updated at rest from
  the gyro itself, during motion from the inclination correction (which is minus the
  horizontal bias error), with its standard deviation as an output;
- magnetic disturbances are detected from the field's norm and dip against a tracked
  reference and rejected (Bachmann's magnetometer weight, 000, taken to 0); a new steady
  field is adopted after ``mag_new_reference_s``. The method does this itself
  (``rejects_mag_disturbance``), so the input screening's norm/dip gate is off for it;
- after a start (the first sample, or a restart after a gap) the heading is the mean of
  its measurements since the start while that is a shorter memory than ``tau_mag_s``
  (for at most ``converge_s``; VQF's start-up), so the heading of one start sample taken
  during motion is forgotten in a second or two rather than after several ``tau_mag_s``.

A restart after a gap keeps what the filter knows of the sensor (gyro bias, its variance,
the field reference) and starts the orientation, low-passes and rest detector afresh.

- a magnet carried by the sensor (a hard-iron offset that turns with it) is estimated
  online by a sphere fit over the rotation seen (``hard_iron_tau_s``;
  ``methods/robust/hard_iron.py``), accepted only when well conditioned, on the sphere and
  of an earth field's radius, and then subtracted from every field sample; while none is
  accepted and the field's norm is seen to move with the orientation, the field is
  rejected and the heading held on the gyro.

Outputs: ``quat`` (9-D with a magnetometer, else 6-D), ``quat6d`` (always, heading free,
output frame), ``gyr_bias_rad_s`` and ``gyr_bias_sd_rad_s`` (rad/s, body axes),
``mag_offset_ut`` (the accepted hard-iron offset, body axes, the field's unit: µT for an
earth field in µT; nan until one is accepted); rest and
rejected field disturbances are the flags ``Flag.REST`` and ``Flag.MAG_DISTURBED`` of
``Estimate.flags``.

The whole per-sample path (screening, (re)starts, the filter) is one compiled call
(:mod:`margtrack.estimator.compiled`, kernel ``methods/robust/kernel.py``), so ``update`` costs
about as much as one sample of ``run``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator import Params, param
from margtrack.estimator.compiled import CompiledEstimator, CompiledState
from margtrack.methods.robust import kernel

Array = NDArray[np.float64]

__all__ = ["Robust", "RobustParams"]


@dataclass(frozen=True)
class RobustParams(Params):
    """Parameters of the robust filter, in physical units (see ``margtrack methods``).

    Raising ``tau_acc_s`` makes the inclination less sensitive to linear acceleration and
    slower to remove gyro drift; raising ``tau_mag_s`` the heading less sensitive to
    magnetic noise and undetected disturbances and slower to remove heading drift.
    ``mag_norm_tol`` and ``mag_dip_tol_deg`` re-declare the shared fields with this
    filter's tighter defaults (it rejects disturbances itself); ``mag_norm_ref`` and
    ``mag_dip_ref_deg``, when given, are its tracker's initial reference.
    """

    tau_acc_s: float = param(
        3.0, unit="s", gt=0, help="time constant of the inclination correction (acc low-pass)"
    )
    tau_mag_s: float = param(
        20.0, unit="s", gt=0, help="time constant of the heading correction from the field"
    )
    converge_s: float = param(
        20.0,
        unit="s",
        ge=0,
        help="after a (re)start the heading averages its measurements for up to this long",
    )
    bias_sigma_init_deg_s: float = param(
        0.5, unit="deg/s", gt=0, help="initial standard deviation of the gyro bias"
    )
    bias_walk_deg_s_sqrt_s: float = param(
        0.01,
        unit="deg/s/√s",
        ge=0,
        help="gyro bias random walk (how fast the bias may wander)",
        calibrated_by="noise.gyr_bias_walk_rad_s2_sqrt_hz",
    )
    bias_rest_noise_deg_s: float = param(
        0.05, unit="deg/s", gt=0, help="noise of the low-passed gyro used as the bias at rest"
    )
    bias_motion_noise_deg_s: float = param(
        30.0,
        unit="deg/s",
        gt=0,
        help="noise of the inclination correction rate as a bias measurement in motion",
    )
    bias_max_deg_s: float = param(
        2.0, unit="deg/s", gt=0, help="largest plausible gyro bias; the estimate is clipped to it"
    )
    rest_gyr_deg_s: float = param(
        2.0, unit="deg/s", gt=0, help="largest deviation of the gyro from its slow mean at rest"
    )
    rest_acc_m_s2: float = param(
        0.5, unit="m/s²", gt=0, help="largest deviation of the acc from its slow mean at rest"
    )
    rest_min_s: float = param(
        1.5, unit="s", ge=0, help="how long the sensor must be still to count as at rest"
    )
    rest_tau_s: float = param(
        0.5, unit="s", gt=0, help="time constant of the rest detector's slow means"
    )
    mag_norm_tol: float = param(
        0.1,
        gt=0,
        help="relative deviation of the field norm from its reference that counts as disturbed",
    )
    mag_dip_tol_deg: float = param(
        10.0,
        unit="deg",
        gt=0,
        help="deviation of the dip from its reference that counts as disturbed",
    )
    mag_new_reference_s: float = param(
        20.0, unit="s", ge=0, help="how long a new steady field must last to become the reference"
    )
    mag_reference_tau_s: float = param(
        60.0, unit="s", gt=0, help="time constant of the field reference tracking"
    )
    hard_iron_tau_s: float = param(
        30.0,
        unit="s",
        ge=0,
        help="memory of the online hard-iron (attached magnet) sphere fit (0: off)",
    )

    def coefficients(self) -> Array:
        """The kernel's coefficient vector (SI units, rad)."""
        c = np.zeros(kernel.N_COEF)
        rad = math.radians
        c[kernel.C_TAU_ACC] = self.tau_acc_s
        c[kernel.C_TAU_MAG] = self.tau_mag_s
        c[kernel.C_BIAS_WALK] = rad(self.bias_walk_deg_s_sqrt_s)
        c[kernel.C_BIAS_REST_NOISE] = rad(self.bias_rest_noise_deg_s)
        c[kernel.C_BIAS_MOTION_NOISE] = rad(self.bias_motion_noise_deg_s)
        c[kernel.C_BIAS_MAX] = rad(self.bias_max_deg_s)
        c[kernel.C_REST_GYR] = rad(self.rest_gyr_deg_s)
        c[kernel.C_REST_ACC] = self.rest_acc_m_s2
        c[kernel.C_REST_MIN_T] = self.rest_min_s
        c[kernel.C_REST_TAU] = self.rest_tau_s
        c[kernel.C_MAG_NORM_TOL] = self.mag_norm_tol
        c[kernel.C_MAG_DIP_TOL] = rad(self.mag_dip_tol_deg)
        c[kernel.C_MAG_NEW_REF_T] = self.mag_new_reference_s
        c[kernel.C_MAG_REF_TAU] = self.mag_reference_tau_s
        c[kernel.C_NED] = 1.0 if self.frame == "NED" else 0.0
        c[kernel.C_CONVERGE] = self.converge_s
        c[kernel.C_HI_RATE] = 1.0 / self.hard_iron_tau_s if self.hard_iron_tau_s > 0 else 0.0
        c[kernel.C_BIAS_SIGMA0] = rad(self.bias_sigma_init_deg_s)
        c[kernel.C_MAG_NORM_REF0] = self.mag_norm_ref or 0.0
        c[kernel.C_MAG_DIP_REF0] = (
            math.nan if self.mag_dip_ref_deg is None else rad(self.mag_dip_ref_deg)
        )
        return c


class Robust(CompiledEstimator[RobustParams]):
    """margtrack's robust MARG filter (``--method robust``); see the module docstring.

    State (:class:`~margtrack.estimator.compiled.CompiledState`): one row per sensor, its
    parts named by ``state_layout`` (read them with ``state.get(name)``; the kernel's
    module docstring gives the meaning of each). A restart after a gap keeps the bias,
    its variance and the field reference; before a sensor's first start they are set
    from the parameters (``bias_sigma_init_deg_s``, ``mag_norm_ref``,
    ``mag_dip_ref_deg``).
    """

    name = "robust"
    params_type = RobustParams
    rejects_mag_disturbance = True
    kernel = kernel
    state_layout: ClassVar[Mapping[str, tuple[int, int]]] = {
        "q_gyr": (kernel.R_Q_GYR, 4),
        "q_acc": (kernel.R_Q_ACC, 4),
        "heading_rad": (kernel.R_HEADING, 1),
        "gyr_bias_rad_s": (kernel.R_BIAS, 3),
        "bias_var_rad2_s2": (kernel.R_BIAS_VAR, 3),
        "gyr_bias_sd_rad_s": (kernel.R_BIAS_SD, 3),
        "acc_lp_m_s2": (kernel.R_ACC_LP, 3),
        "acc_lp_bw": (kernel.R_ACC_LP_BW, 6),
        "acc_lp_stage": (kernel.R_LP_STAGE, 1),
        "since_start_s": (kernel.R_SINCE_START, 1),
        "heading_n": (kernel.R_HEADING_N, 1),
        "gyr_rest_rad_s": (kernel.R_GYR_REST, 3),
        "acc_rest_m_s2": (kernel.R_ACC_REST, 3),
        "still_s": (kernel.R_STILL, 1),
        "mag_norm_ref": (kernel.R_MAG_NORM_REF, 1),
        "mag_dip_ref_rad": (kernel.R_MAG_DIP_REF, 1),
        "mag_cand_norm": (kernel.R_CAND_NORM, 1),
        "mag_cand_dip_rad": (kernel.R_CAND_DIP, 1),
        "mag_cand_s": (kernel.R_CAND_S, 1),
        "hard_iron_origin": (kernel.R_HI_SHIFT, 3),
        "hard_iron_sums": (kernel.R_HI_SUMS, 15),
        "mag_offset_ut": (kernel.R_HI_OFFSET, 3),
        "hard_iron_radius": (kernel.R_HI_RADIUS, 1),
        "mag_moves_with_sensor": (kernel.R_HI_MOVING, 1),
        "hard_iron_count": (kernel.R_HI_COUNT, 1),
    }
    outputs_layout = (("quat6d", 4), ("gyr_bias_rad_s", 3), ("gyr_bias_sd_rad_s", 3),
                      ("mag_offset_ut", 3))

    def _coefficients(self) -> Array:
        return self._params.coefficients()

    def _new_rows(self, n_sensors: int) -> CompiledState:
        """Rows of sensors that have seen nothing, with what is known of the sensor (the
        bias variance, a given field reference) already set."""
        state = super()._new_rows(n_sensors)
        kernel.fresh(state.rows, self._coefs)
        return state
