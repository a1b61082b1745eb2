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
  field is adopted after ``mag_new_reference_s``.

Outputs: ``quat`` (9-D with a magnetometer, else 6-D), ``quat6d`` (always, heading free),
``gyr_bias_rad_s``, ``gyr_bias_sd_rad_s``, ``rest`` and ``mag_disturbed`` flags.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimators.base import Estimator, Params, State
from margtrack.kernels import robust as kernel

Array = NDArray[np.float64]

__all__ = ["Robust", "RobustParams", "RobustState"]


def _positive(name: str, value: float, allow_zero: bool = False) -> None:
    ok = np.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite number {bound}, got {value!r}")


@dataclass(frozen=True)
class RobustParams(Params):
    """Parameters of the robust filter, in physical units.

    tau_acc_s : time constant of the inclination correction (low-pass of the accelerometer
        in the strapdown frame), s. Larger: less sensitive to linear acceleration, slower
        to remove gyro drift.
    tau_mag_s : time constant of the heading correction, s. Larger: less sensitive to
        magnetic noise and undetected disturbances, slower to remove heading drift.
    bias_sigma_init_deg_s : initial standard deviation of the gyro bias, deg/s.
    bias_walk_deg_s_sqrt_s : bias random walk, deg/s/√s (how fast the bias may wander).
    bias_rest_noise_deg_s : noise of the low-passed gyro used as bias at rest, deg/s.
    bias_motion_noise_deg_s : noise of the per-sample inclination correction rate used as
        a bias measurement in motion, deg/s. Larger: slower bias learning in motion.
    bias_max_deg_s : largest plausible bias; the estimate is clipped to it, deg/s.
    rest_gyr_deg_s, rest_acc_m_s2 : largest deviation from their slow means for "still".
    rest_min_s : how long the sensor must be still before it counts as at rest, s.
    rest_tau_s : time constant of the slow means of the rest detector, s.
    mag_norm_tol : largest relative deviation of the field norm from its reference.
    mag_dip_tol_deg : largest deviation of the dip angle from its reference, deg.
    mag_new_reference_s : how long a new steady field must last to become the reference, s.
    mag_reference_tau_s : time constant of the reference tracking, s.
    """

    tau_acc_s: float = 3.0
    tau_mag_s: float = 20.0
    bias_sigma_init_deg_s: float = 0.5
    bias_walk_deg_s_sqrt_s: float = 0.01
    bias_rest_noise_deg_s: float = 0.05
    bias_motion_noise_deg_s: float = 30.0
    bias_max_deg_s: float = 2.0
    rest_gyr_deg_s: float = 2.0
    rest_acc_m_s2: float = 0.5
    rest_min_s: float = 1.5
    rest_tau_s: float = 0.5
    mag_norm_tol: float = 0.1
    mag_dip_tol_deg: float = 10.0
    mag_new_reference_s: float = 20.0
    mag_reference_tau_s: float = 60.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in (
            "tau_acc_s",
            "tau_mag_s",
            "bias_sigma_init_deg_s",
            "bias_rest_noise_deg_s",
            "bias_motion_noise_deg_s",
            "bias_max_deg_s",
            "rest_gyr_deg_s",
            "rest_acc_m_s2",
            "rest_tau_s",
            "mag_norm_tol",
            "mag_dip_tol_deg",
            "mag_reference_tau_s",
        ):
            _positive(name, getattr(self, name))
        for name in ("bias_walk_deg_s_sqrt_s", "rest_min_s", "mag_new_reference_s"):
            _positive(name, getattr(self, name), allow_zero=True)

    def coefficients(self) -> Array:
        """The kernel's coefficient vector (SI units, rad)."""
        c = np.zeros(kernel.N_COEF)
        rad = np.radians
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
        return c


@dataclass
class RobustState(State):
    """State of S robust filters.

    filter : (S, N_STATE) the kernel's state vector (layout in ``kernels/robust.py``).
    fresh : (S,) True until the first sample has initialised the filter.
    """

    filter: Array | None = None
    fresh: NDArray[np.bool_] | None = None


class Robust(Estimator[RobustParams, RobustState]):
    """margtrack's robust MARG filter (``--method robust``); see the module docstring."""

    name = "robust"
    params_type = RobustParams

    def _new_state(self, quat0: Array) -> RobustState:
        n = quat0.shape[0]
        st = np.zeros((n, kernel.N_STATE))
        var0 = np.radians(self.params.bias_sigma_init_deg_s) ** 2
        st[:, kernel.I_BIAS_VAR : kernel.I_BIAS_VAR + 3] = var0
        return RobustState(
            quat=np.array(quat0, dtype=np.float64),
            filter=st,
            fresh=np.ones(n, dtype=bool),
        )

    def _process(
        self,
        state: RobustState,
        gyr: Array | None,
        acc: Array,
        mag: Array | None,
        dt: Array,
    ) -> tuple[Array, dict[str, NDArray[Any]]]:
        assert gyr is not None and state.filter is not None and state.fresh is not None
        n_sensors, n = acc.shape[0], acc.shape[1]
        if np.any(state.fresh) and dt[0] != 0.0:
            raise ValueError("a fresh filter must start with the initialising sample")
        # the bias variance of a fresh state follows the current parameter
        var0 = np.radians(self.params.bias_sigma_init_deg_s) ** 2
        state.filter[state.fresh, kernel.I_BIAS_VAR : kernel.I_BIAS_VAR + 3] = var0
        q_init = frames.convert(state.quat, self.params.frame, "ENU")
        quat = np.empty((n_sensors, n, 4))
        quat6 = np.empty((n_sensors, n, 4))
        bias = np.empty((n_sensors, n, 3))
        bias_sd = np.empty((n_sensors, n, 3))
        rest = np.empty((n_sensors, n), dtype=np.bool_)
        disturbed = np.empty((n_sensors, n), dtype=np.bool_)
        kernel.robust_filter(
            state.filter,
            self.params.coefficients(),
            gyr,
            acc,
            acc if mag is None else mag,
            mag is not None,
            dt,
            state.fresh,
            np.ascontiguousarray(q_init),
            quat,
            quat6,
            bias,
            bias_sd,
            rest,
            disturbed,
        )
        state.fresh[:] = False
        state.quat = quat[:, -1].copy()
        return quat, {
            "quat6d": quat6,
            "gyr_bias_rad_s": bias,
            "gyr_bias_sd_rad_s": bias_sd,
            "rest": rest,
            "mag_disturbed": disturbed,
        }
