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

Outputs: ``quat`` (9-D with a magnetometer, else 6-D), ``quat6d`` (always, heading free),
``gyr_bias_rad_s``, ``gyr_bias_sd_rad_s``, ``rest`` and ``mag_disturbed`` (bool (S, N);
method detail kept for now: the same information is in ``Estimate.flags`` as
``Flag.REST`` and ``Flag.MAG_DISTURBED``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimator import Estimator, Params, State, param
from margtrack.kernels import robust as kernel

Array = NDArray[np.float64]

__all__ = ["Robust", "RobustParams", "RobustState"]

_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


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
        0.01, unit="deg/s/√s", ge=0, help="gyro bias random walk (how fast the bias may wander)"
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
        return c


@dataclass(kw_only=True)
class RobustState(State):
    """State of S robust filters (arrays with the sensor first; ENU inside, see the kernel).

    Orientation, ``q9 = q_z(heading_rad) ⊗ q_acc ⊗ q_gyr``:

    q_gyr : (S, 4) body to the strapdown frame I (gyro integration; identity at a start).
    q_acc : (S, 4) I to the level frame (the inclination; the whole initial orientation
        at a start).
    heading_rad : (S,) rotation about up from the level frame to ENU, rad.

    Gyro bias (kept on restart):

    bias_rad_s : (S, 3) gyro bias estimate, rad/s, body axes.
    bias_var_rad2_s2 : (S, 3) its variance per axis, (rad/s)².

    Inclination low-pass (accelerometer in frame I):

    acc_lp_m_s2 : (S, 3) its output, m/s².
    acc_lp_bw : (S, 3, 2) Butterworth states (s1, s2) per axis, m/s² (transposed direct
        form II; valid in stage ``LP_FILTER``).
    acc_lp_stage : (S,) int8 ``kernel.LP_EMPTY`` (no usable sample since the start),
        ``LP_FIRST`` (holds the first sample; the filter states are set to its steady
        state at the next step), ``LP_FILTER`` (running).

    Start-up:

    since_start_s : (S,) time since the start (first sample or restart), s.
    heading_n : (S,) int64 heading measurements averaged since the start (the initial
        orientation counts as one unless the start had no usable field).

    Rest detector:

    gyr_rest_rad_s : (S, 3) gyro low-passed with ``rest_tau_s``, rad/s.
    acc_rest_m_s2 : (S, 3) accelerometer low-passed with ``rest_tau_s``, m/s².
    still_s : (S,) how long the sensor has been still, s.

    Field reference tracker (kept on restart; the field's unit as given):

    mag_norm_ref : (S,) the field norm taken as undisturbed (0: from the next sample).
    mag_dip_ref_rad : (S,) the dip taken as undisturbed, rad, positive down (nan: from
        the next sample).
    mag_cand_norm, mag_cand_dip_rad : (S,) a new steady field's norm and dip, candidate
        for the reference while the field disagrees with it.
    mag_cand_s : (S,) how long that candidate has been steady, s.
    """

    q_gyr: Array
    q_acc: Array
    heading_rad: Array
    bias_rad_s: Array
    bias_var_rad2_s2: Array
    acc_lp_m_s2: Array
    acc_lp_bw: Array
    acc_lp_stage: NDArray[np.int8]
    since_start_s: Array
    heading_n: NDArray[np.int64]
    gyr_rest_rad_s: Array
    acc_rest_m_s2: Array
    still_s: Array
    mag_norm_ref: Array
    mag_dip_ref_rad: Array
    mag_cand_norm: Array
    mag_cand_dip_rad: Array
    mag_cand_s: Array

    def copy(self) -> RobustState:
        """An independent copy: every array (``ready`` too) and the screening's memory.

        Explicit because the generic field loop cost a third of one ``update``.
        """
        new = object.__new__(type(self))
        new.__dict__.update(
            {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in self.__dict__.items()}
        )
        if self.screen is not None:
            new.screen = self.screen.copy()
        return new

    def gyr_bias_rad_s(self) -> Array:
        """(S, 3) the gyro bias estimate, rad/s."""
        return self.bias_rad_s.copy()

    def gyr_bias_sd_rad_s(self) -> Array:
        """(S, 3) standard deviation of the bias estimate, rad/s."""
        return np.sqrt(self.bias_var_rad2_s2)


class Robust(Estimator[RobustParams, RobustState]):
    """margtrack's robust MARG filter (``--method robust``); see the module docstring."""

    name = "robust"
    params_type = RobustParams
    rejects_mag_disturbance = True
    kept_on_restart = (
        "bias_rad_s",
        "bias_var_rad2_s2",
        "mag_norm_ref",
        "mag_dip_ref_rad",
        "mag_cand_norm",
        "mag_cand_dip_rad",
        "mag_cand_s",
    )

    def _new_state(self, quat0: Array) -> RobustState:
        p = self._params
        n = quat0.shape[0]
        var0 = math.radians(p.bias_sigma_init_deg_s) ** 2
        dip0 = math.nan if p.mag_dip_ref_deg is None else math.radians(p.mag_dip_ref_deg)
        return RobustState(
            quat=np.array(quat0, dtype=np.float64),
            q_gyr=np.tile(_IDENTITY, (n, 1)),
            q_acc=np.ascontiguousarray(frames.convert(quat0, p.frame, "ENU")),
            heading_rad=np.zeros(n),
            bias_rad_s=np.zeros((n, 3)),
            bias_var_rad2_s2=np.full((n, 3), var0),
            acc_lp_m_s2=np.zeros((n, 3)),
            acc_lp_bw=np.zeros((n, 3, 2)),
            acc_lp_stage=np.full(n, kernel.LP_EMPTY, dtype=np.int8),
            since_start_s=np.zeros(n),
            heading_n=np.ones(n, dtype=np.int64),
            gyr_rest_rad_s=np.zeros((n, 3)),
            acc_rest_m_s2=np.zeros((n, 3)),
            still_s=np.zeros(n),
            mag_norm_ref=np.full(n, p.mag_norm_ref or 0.0),
            mag_dip_ref_rad=np.full(n, dip0),
            mag_cand_norm=np.zeros(n),
            mag_cand_dip_rad=np.full(n, math.nan),
            mag_cand_s=np.zeros(n),
        )

    def _process(
        self,
        state: RobustState,
        gyr: Array | None,
        acc: Array,
        mag: Array | None,
        dt: Array,
    ) -> tuple[Array, dict[str, NDArray[Any]]]:
        assert gyr is not None  # guaranteed by uses_gyr; narrows the type
        n_sensors, n = acc.shape[0], acc.shape[1]
        quat = np.empty((n_sensors, n, 4))
        quat6 = np.empty((n_sensors, n, 4))
        bias = np.empty((n_sensors, n, 3))
        bias_sd = np.empty((n_sensors, n, 3))
        rest = np.empty((n_sensors, n), dtype=np.bool_)
        disturbed = np.empty((n_sensors, n), dtype=np.bool_)
        kernel.robust_filter(
            self._params.coefficients(),
            gyr,
            acc,
            acc if mag is None else mag,
            mag is not None,
            dt,
            state.q_gyr,
            state.q_acc,
            state.heading_rad,
            state.bias_rad_s,
            state.bias_var_rad2_s2,
            state.acc_lp_m_s2,
            state.acc_lp_bw,
            state.acc_lp_stage,
            state.heading_n,
            state.since_start_s,
            state.gyr_rest_rad_s,
            state.acc_rest_m_s2,
            state.still_s,
            state.mag_norm_ref,
            state.mag_dip_ref_rad,
            state.mag_cand_norm,
            state.mag_cand_dip_rad,
            state.mag_cand_s,
            quat,
            quat6,
            bias,
            bias_sd,
            rest,
            disturbed,
        )
        state.quat = quat[:, -1].copy()
        return quat, {
            "quat6d": quat6,
            "gyr_bias_rad_s": bias,
            "gyr_bias_sd_rad_s": bias_sd,
            "rest": rest,
            "mag_disturbed": disturbed,
        }
