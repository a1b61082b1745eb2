"""Marins' quaternion extended Kalman filter for MARG sensors (001), both approaches.

State: the body angular rate ``ω`` (3) and the quaternion ``q`` (4), with a 7x7 covariance
(001 section 4.1; margtrack's order ``[ω_x, ω_y, ω_z, q_w, q_x, q_y, q_z]``, 001 puts the
scalar ``d`` last). Process model: a first-order rate with time constant τ per axis driven
by white noise, and quaternion kinematics with the normalisation term (eqs. 9-15), in the
paper's additive 4-D quaternion form (not an error-state filter: STYLE 12). The
discretisation (exact for the rate and its integral, exact flow of eqs. 12-15 along the
noise-free rate) and the Jacobians are in :mod:`margtrack.methods.ekf.kernel`.

- ``approach=2`` (default, the paper's choice, 001 4.3): the measurement is the gyroscope
  rate plus the Gauss-Newton quaternion of the accelerometer and magnetometer (001 eqs.
  20-23), started from the predicted quaternion with a small iteration cap (001 5.1: when
  tracking, one step is usually enough) and signed nearest the prediction; ``H = I₇``.
- ``approach=1`` (001 4.1): the nine outputs, rate, gravity and field directions in body
  coordinates (eq. 19's form; the printed equation turns the reference the wrong way, see
  the kernel), with their Jacobian.

After each update ``q`` is normalised (001 Fig. 3); the covariance is updated one
measured component at a time (the noise is diagonal), symmetric and positive definite by
construction, with algebra hand-derived for the sparse F and H
(:mod:`margtrack.methods.ekf.model`).

``bias_states=True`` (off by default: the filter as printed) adds a gyroscope bias state,
``[ω, q, b]`` with the gyroscope measuring ``ω + b`` and b a random walk, in the spirit of
003's augmented state (:mod:`margtrack.methods.ekf.bias_kernel`).

Measurement noise that follows the evidence (:mod:`margtrack.methods.ekf.noise`): 001
gives the Gauss-Newton quaternion a fixed noise; with ``mag_disturbance_s`` (on by
default, 1 s) and ``acc_disturbance_s`` (off) a sample's field distance from its reference
norm and the accelerometer's distance from gravity's norm are disturbances of the unit
vectors with that correlation time, carried through the fit's Jacobian into the
quaternion's covariance (no threshold). ``mag_disturbance_s=0`` (and
``acc_disturbance_s=0``) is the filter as printed, to the bit. On BROAD (16 trials,
leave-one-trial-out over the declared grid, :mod:`margtrack.bench.grids`): the field's
evidence takes the cross-validated mean from 4.28 deg (as printed) to 3.34 (heading 2.74
to 2.08, inclination 2.92 to 2.48), below tuned Madgwick's 3.64 (``gradient``, same
run). The accelerometer's makes it worse at every correlation time tried (0.003-1 s:
4.13-4.39 deg in-sample against 3.91 as printed; 3.87-4.04 cross-validated on top of the
field's, never chosen when 0 is a candidate): the model's integration of the rate state
needs the quaternion's pull during motion, so that option stays off (a simulated shake on
a still sensor does tilt it less).

Two properties of the model as 001 writes it:

- the gyroscope measures the rate *state*, the rate at the sample time, while the
  prediction integrates the rate from the previous sample; under margtrack's timing
  (gyro sample ``i`` is the rate over ``(t[i-1], t[i]]``) this leaves an orientation lag of
  at most half a sample of rotation, ``dt |ω| / 2`` (whose rms over BROAD's movement
  samples is 0.07-0.73 deg per trial, 0.36 deg on average);
- the quaternion has no process noise of its own: its uncertainty grows through the rate
  model, whose white driving noise makes the angle within one interval uncertain by
  ``σ² dt³ / (12 τ²)`` rad² (given the rate at both ends). At the defaults that is 250
  (286 Hz) to 2000 (100 Hz) times the gyroscope noise's share ``dt σ_g²``, so the
  correction's time constant, and the best noise parameters, depend on the sample rate
  (at the defaults a 1 deg offset decays by 1/e in 3.3 s at 100 Hz and 9.3 s at
  286 Hz). Tune at the rate you run at.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimator import Estimate
from margtrack.estimator import skeleton as kc
from margtrack.estimator.compiled import CompiledEstimator, CompiledState
from margtrack.estimator.outputs import with_output_types
from margtrack.methods import rest_null_kernel
from margtrack.methods.ekf import bias_kernel, kernel
from margtrack.methods.ekf.params import MarinsEkfParams
from margtrack.methods.rest_null import (
    check_rows,
    rest_null_coefficients,
    rest_null_layout,
)
from margtrack.single_frame.davenport_kernel import field_from_dip
from margtrack.single_frame.prefilter import dip_rad_or_nan

Array = NDArray[np.float64]

__all__ = ["MarinsEkf", "MarinsEkfParams", "initial_covariance"]


def initial_covariance(n_sensors: int, rate_std_rad_s: float, quat_std: float) -> Array:
    """Diagonal initial covariance (S, 7, 7): rate variance, then quaternion variance."""
    cov = np.zeros((n_sensors, 7, 7))
    idx = np.arange(7)
    cov[:, idx[:3], idx[:3]] = rate_std_rad_s**2
    cov[:, idx[3:], idx[3:]] = quat_std**2
    return cov


M = TypeVar("M")


class _ByMode(Generic[M]):
    """A class attribute whose value on an instance follows ``params.bias_states``: the
    7-state filter's on the class and without the option, the bias variant's with it."""

    def __init__(self, plain: M, bias: M) -> None:
        self.plain, self.bias = plain, bias

    def __get__(self, obj: Any, owner: Any = None) -> M:
        params = None if obj is None else obj.__dict__.get("_params")
        return self.bias if params is not None and params.bias_states else self.plain


_LAYOUT: Mapping[str, tuple[int, int]] = {
    "gyr_est_rad_s": (kernel.E_X, 3),
    "quat": (kernel.E_X + 3, 4),
    "cov": (kernel.E_P, 49),
    "dip_rad": (kernel.E_DIP, 1),
    "field_reference": (kernel.E_FIELD, 3),
    "field_norm_reference": (kernel.E_MAG_NORM, 1),
    "gyr_bias_rad_s": (kernel.E_NULL + rest_null_kernel.RN_NULL, 3),
    **rest_null_layout(kernel.E_NULL),
}
_BIAS_LAYOUT: Mapping[str, tuple[int, int]] = {
    "gyr_est_rad_s": (kernel.E_X, 3),
    "quat": (kernel.E_X + 3, 4),
    "bias_state_rad_s": (kernel.E_X + 7, 3),
    "cov": (bias_kernel.E_P, 100),
    "dip_rad": (kernel.E_DIP, 1),
    "field_reference": (kernel.E_FIELD, 3),
    "field_norm_reference": (kernel.E_MAG_NORM, 1),
    "gyr_null_rad_s": (kernel.E_NULL + rest_null_kernel.RN_NULL, 3),
    "gyr_bias_rad_s": (bias_kernel.E_BIAS, 3),
    "gyr_bias_sd_rad_s": (bias_kernel.E_BIAS_SD, 3),
    **rest_null_layout(kernel.E_NULL),
}
_OUTPUTS = (
    ("gyr_est_rad_s", 3),
    ("cov_diag", 7),
    ("iterations", 1),
    ("degenerate", 1),
    ("gyr_null_rad_s", 3),
)
_BIAS_OUTPUTS = (
    ("gyr_est_rad_s", 3),
    ("cov_diag", 10),
    ("iterations", 1),
    ("degenerate", 1),
    ("gyr_null_rad_s", 3),
    ("gyr_bias_rad_s", 3),
    ("gyr_bias_sd_rad_s", 3),
)


class MarinsEkf(CompiledEstimator[MarinsEkfParams]):
    """Marins' 7-state quaternion EKF (``--method ekf``), 001 sections 3-4.

    Needs a magnetometer. Inputs per sample: gyroscope rad/s, accelerometer m/s²,
    magnetometer (any unit), body frame. Starts at the TRIAD orientation of the first usable
    sample (or ``reset(q0)``) with zero rate.

    Outputs besides ``quat`` (unit, sign continuous):

    - ``gyr_est_rad_s`` (N, 3): the rate state ω after each update, rad/s;
    - ``cov_diag`` (N, 7): the covariance diagonal, order ``[ω_x, ω_y, ω_z, q_w, q_x, q_y,
      q_z]`` ((rad/s)², dimensionless); the full matrix after the last sample is
      ``state.get("cov")`` (S, 49), row-major;
    - ``iterations`` (N,) int32: Gauss-Newton updates applied (0 for approach 1);
    - ``gyr_null_rad_s`` (N, 3): the gyro null subtracted (``gyr_null_rest_s``), rad/s;
    - ``degenerate`` (N,) int8, method detail: 0 ok; 2 zero magnetometer (updated from
      the gyroscope and the gravity direction; the screening's MAG_IGNORED or
      MAG_DISTURBED says why); 1 zero accelerometer (flagged ACC_IGNORED), 3
      accelerometer parallel to the field, 4 Gauss-Newton failed (these three updated by
      the gyroscope alone, flagged ACC_IGNORED and MAG_IGNORED); 5 an innovation variance
      not positive (that measured component and the later ones skipped, flagged
      ACC_IGNORED and MAG_IGNORED).

    State (:class:`~margtrack.estimator.compiled.CompiledState`, ``state.get(name)``, each
    (S, width)): ``quat`` the quaternion state (unit after every update; one set by hand
    may have any non-zero norm, which eqs. 12-15 account for); ``gyr_est_rad_s`` the rate
    state ω; ``cov`` the 7x7 covariance of ``[ω (rad/s)², q]``, row-major; ``dip_rad`` the
    reference dip measured at the first valid sample (NaN until then, and when
    ``mag_dip_ref_deg`` is given); ``field_reference`` the unit field from it;
    ``field_norm_reference`` the field norm the evidence-driven noise measures against
    (``mag_disturbance_s``; 0 until the first usable field); ``gyr_bias_rad_s`` the gyro
    null in use (the still start's mean rate; 0 without one) and the rest null's progress
    (``rest_null_*``).

    A restart after a gap keeps the dip, the field norm reference and the gyro null and
    starts the rate, the quaternion and the whole covariance afresh (``init_*``): the new
    start is TRIAD's, not the old estimate's.

    With ``bias_states=True`` (kernel :mod:`margtrack.methods.ekf.bias_kernel`) the state is
    ``[ω, q, b]``: ``cov_diag`` (N, 10) and ``cov`` (S, 100) cover b too, the outputs add
    ``gyr_bias_rad_s`` (N, 3) the bias of the raw rate (null + b, rad/s: subtract it from
    the gyroscope) and ``gyr_bias_sd_rad_s`` (N, 3) its sd; in the state
    ``gyr_bias_rad_s`` and ``gyr_bias_sd_rad_s`` are those, ``bias_state_rad_s`` is b and
    ``gyr_null_rad_s`` the null. A restart keeps b and its covariance. The mode cannot
    change while a state is held (``reset()`` first).
    """

    name = "ekf"
    params_type = MarinsEkfParams
    mag_optional = False
    # per instance, from params.bias_states (on the class: the 7-state filter's)
    kernel = _ByMode(kernel, bias_kernel)  # type: ignore[assignment]
    state_layout = _ByMode(_LAYOUT, _BIAS_LAYOUT)  # type: ignore[assignment]
    outputs_layout = _ByMode(_OUTPUTS, _BIAS_OUTPUTS)  # type: ignore[assignment]
    #: parameters with kernels of their own, compiled too by ``margtrack compile ekf``
    compile_variants = ({"bias_states": True},)

    @CompiledEstimator.params.setter  # type: ignore[attr-defined]
    def params(self, value: MarinsEkfParams) -> None:
        """Set the parameters; ``bias_states`` changes the state's layout, so it cannot
        change while a state is held."""
        if (
            isinstance(value, MarinsEkfParams)
            and value.bias_states != self._params.bias_states
            and self._state is not None
        ):
            raise ValueError("bias_states cannot change while running; reset() first")
        CompiledEstimator.params.fset(self, value)  # type: ignore[attr-defined]
        self._buffers = None

    def _coefficients(self) -> Array:
        p = self.params
        c = np.zeros(kernel.N_COEF)
        c[kernel.C_APPROACH] = p.approach
        c[kernel.C_TAU : kernel.C_TAU + 3] = p.axis_values("tau_s")
        rate = p.axis_values("rate_noise_rad_s_sqrt_hz")
        gyr = p.axis_values("gyr_noise_rad_s_sqrt_hz")
        c[kernel.C_RATE_VAR : kernel.C_RATE_VAR + 3] = rate**2
        c[kernel.C_GYR_VAR : kernel.C_GYR_VAR + 3] = gyr**2
        c[kernel.C_QUAT_VAR] = p.quat_noise_per_sqrt_hz**2
        c[kernel.C_ACC_VAR] = p.acc_noise_m_s2_sqrt_hz**2
        c[kernel.C_MAG_VAR] = p.mag_noise_rel_sqrt_hz**2
        c[kernel.C_GRAVITY2] = p.gravity_m_s2**2
        c[kernel.C_MAG_WEIGHT] = p.mag_weight
        c[kernel.C_GN_TOL] = p.gn_tolerance
        c[kernel.C_GN_MAX_IT] = p.gn_max_iterations
        up, north = frames.up(p.frame), frames.mag_reference(p.frame, dip_deg=0.0)
        c[kernel.C_UP : kernel.C_UP + 3] = up
        c[kernel.C_NORTH : kernel.C_NORTH + 3] = north
        dip = dip_rad_or_nan(p.mag_dip_ref_deg)
        c[kernel.C_DIP] = dip
        c[kernel.C_FIELD : kernel.C_FIELD + 3] = field_from_dip(
            math.sin(dip), math.cos(dip), *up, *north
        )
        c[kernel.C_INIT_RATE_VAR] = p.init_rate_std_rad_s**2
        c[kernel.C_INIT_QUAT_VAR] = p.init_quat_std**2
        c[kernel.C_GEN] = next(_GENERATIONS)
        c[kernel.C_NULL : kernel.C_NULL + rest_null_kernel.N_RC] = rest_null_coefficients(
            p.gyr_null_rest_s
        )
        walk = p.axis_values("gyr_bias_walk_rad_s_sqrt_s")
        c[kernel.C_BIAS_WALK_VAR : kernel.C_BIAS_WALK_VAR + 3] = walk**2
        c[kernel.C_INIT_BIAS_VAR] = p.init_bias_std_rad_s**2
        c[kernel.C_ACC_DIST_S] = p.acc_disturbance_s
        c[kernel.C_MAG_DIST_S] = p.mag_disturbance_s
        return c

    @CompiledEstimator.state.setter  # type: ignore[attr-defined]
    def state(self, value: CompiledState | None) -> None:
        """Set the state; one whose quaternion is not finite and non-zero is refused."""
        if value is not None:
            check_rows(value, self.kernel.N_ROW, kernel.E_X + 3, value.rows[:, kc.K_READY] > 0)
        CompiledEstimator.state.fset(self, value)  # type: ignore[attr-defined]

    def _run_arrays(self, *args: Any, **kwargs: Any) -> Estimate:
        return with_output_types(super()._run_arrays(*args, **kwargs), _OUTPUT_TYPES)


#: the generations of coefficient vectors: a row's interval constants are recomputed when
#: the coefficients change (parameters retuned, a state moved between estimators)
_GENERATIONS = itertools.count(1)
#: outputs as they were before the compiled path: width-1 series squeezed to (…, N), typed
_OUTPUT_TYPES = {"iterations": np.int32, "degenerate": np.int8}
