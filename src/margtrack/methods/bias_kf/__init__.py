"""Ang's bias-augmented quaternion Kalman filter (003, section IV): ``--method bias-kf``.

State ``x = [q, b]``: the orientation ``q`` (body to earth, ``[w, x, y, z]``) and the bias
``b`` of the angular-rate input, rad/s (003 eqs. 17-19). The rate input is a gyroscope or
the all-accelerometer IMU's estimate (:mod:`margtrack.single_frame.all_accelerometer`).

- Prediction (eqs. 25-31, 47-48): ``q⁻ = Φ_Q(Ω - b) q``, the exact rotation for a rate
  constant over the period; ``P⁻ = Φ P Φᵀ + W`` with ``Φ = [[Φ_Q, Φ_B], [0, I]]``,
  ``Φ_B = -½ T Φ_Q Q̃``, ``W = diag(¼ Q̃ Ξ_Ω Q̃ᵀ, Ξ_B)``, ``Ξ_Ω = n_g² T``, ``Ξ_B = n_b² T``.
- Measurement (eqs. 13, 38-40): the quaternion of the TRIAD matrix from accelerometer and
  magnetometer, ``H = [I₄ 0]``, computed by the largest of four branches so every
  orientation works, with the sign nearest ``q⁻``.
- Measurement covariance (eqs. 41-46): ``σ_G² = (σ_W² + σ_C²)/|a|²`` with ``σ_W`` the
  accelerometer white noise per sample and ``σ_C = f·g`` the body-acceleration part
  (``f`` = 0.01 in 003 eq. 43); ``σ_N² = σ_M²/|m|²`` with ``σ_M`` given relative to
  the field's norm (``mag_noise_ut_sqrt_hz / mag_field_ut``) and taken to the data's unit
  by the norm of the first field sample, so the result does not depend on the
  magnetometer's unit; the TRIAD error-angle covariance
  ``Ξθ`` (eq. 45) and ``V = ¼ Q̃ Ξθ Q̃ᵀ`` (eq. 46).
- Update (eqs. 49-51) through ``S = L D Lᵀ``: ``P ← P - W D⁻¹ Wᵀ`` with ``W = P Hᵀ L⁻ᵀ``
  (eq. 51, equal to its Joseph form for the optimal gain; exactly symmetric, and
  positive definite over an hour of 25 Hz simulation and over the 16 BROAD trials run as
  one 50-minute stream at 286 Hz, smallest/largest eigenvalue >= 1e-6), then ``q``
  normalised. The covariance algebra is derived by hand for the structure of ``Φ``,
  ``W``, ``V`` and ``H`` (:mod:`margtrack.methods.bias_kf.cov`).
- Input policy (margtrack's, :mod:`margtrack.estimator.screening`): a sample without a
  usable accelerometer or field still corrects what the other observes, the tilt alone or
  the heading alone (TRIAD needs both); a restart after a gap keeps the bias and its
  covariance and measures the orientation afresh.

``W`` and ``V`` are singular along ``q`` as printed. ``W`` gets the Gaussian second moment of
the quaternion error along ``q`` (``E|θ|⁴/64``), which keeps ``P`` positive definite; ``V``
gets unit variance there (the measured quaternion's component along ``q`` is the biased,
information-free ``cos(φ/2) - 1``): with a tiny variance it leaks into the bias through
cross-covariances and the filter becomes inconsistent (see
:func:`margtrack.methods.bias_kf.model.fill_quat_noise` and the consistency test).

Paper slips corrected (the sign of ``Ω×`` in eq. 21, the row order of eq. 24, the missing
``T`` of eq. 28) are listed in :mod:`margtrack.methods.bias_kf.model`.

The whole per-sample path (screening, clock, starts, filter) is one compiled call per
``update`` or ``run`` (:mod:`margtrack.estimator.compiled`,
:mod:`margtrack.methods.bias_kf.kernel`).

Extensions (margtrack's, documented in :class:`BiasKalmanParams`; each has a neutral value
at which the filter is the one above to the last bit, :meth:`BiasKalmanParams.as_printed`
sets them all): a decoupled tilt/heading measurement (eqs. 38, 45), rate-proportional gyro
noise (eq. 31), measurement noise adapted to the accelerometer norm and to the field's
norm and dip (eqs. 41-44), and a robust gate on the tilt innovation. They are the defaults:
on BROAD they take the mean total RMSE from 9.1 deg (filter as printed, tuned) to 4.7 deg.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimator import Estimate, Params, initial_orientation, param
from margtrack.estimator.compiled import CompiledEstimator, CompiledState
from margtrack.estimator.outputs import with_output_types
from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.methods.bias_kf import kernel
from margtrack.sim.all_accelerometer import AllAccelerometerRecording
from margtrack.single_frame import all_accelerometer_kernel as aa_kernel
from margtrack.single_frame.all_accelerometer import differential_acceleration, gravity_estimate

Array = NDArray[np.float64]
Density = float | tuple[float, float, float]

__all__ = [
    "AllAccelerometerTrack",
    "BiasKalman",
    "BiasKalmanParams",
    "covariance",
    "initial_covariance",
    "track_all_accelerometer",
]


@dataclass(frozen=True)
class BiasKalmanParams(Params):
    """Noise densities (SI, as an Allan variance gives them), initial uncertainty, extensions.

    The gains depend only on ratios of these; raising a rate noise makes the filter
    follow the measurement faster, raising an acc/mag noise makes it trust the rate input
    longer. Defaults: the one set for all 16 BROAD trials (286 Hz) found best by a
    coordinate search (3-5 values per parameter, two rounds) over the noise densities and
    the extensions below: mean total RMSE 4.70 deg (heading 3.53, inclination 2.82;
    undisturbed trials 4.51, disturbed 4.96; 4.71 before the field noise became
    relative), against 9.11 deg for the filter as
    printed with its own best noise set (``as_printed()`` with the former defaults
    ``gyr_noise_rad_s_sqrt_hz=1e-4, acc_motion_fraction=0.03``) and about 4.9 deg for
    Madgwick with one tuned beta. Nine tuned numbers against Madgwick's one: the margin
    is within what tuning on the test trials buys. Ablation on BROAD (mean total RMSE
    with one extension neutral, the rest at the defaults, to about 0.02 deg):
    ``decoupled_heading`` off 10.7, ``gyr_scale_noise_sqrt_s`` 0 6.0,
    ``acc_norm_correlation_s`` 0 8.9, ``mag_dip_correlation_s`` 0 5.6,
    ``mag_norm_correlation_s`` 0 5.0, ``tilt_gate`` off 15.0 (fast_combined diverges:
    the rate-proportional noise then lets accelerations through),
    ``tilt_gate_exponent`` 1 4.9.

    Each field is declared with its unit, bounds and a line of help (``margtrack methods``);
    the model behind them:

    gyr_noise_rad_s_sqrt_hz, gyr_bias_walk_rad_s_sqrt_s : a number or one per body axis;
        ``Ξ_Ω = n² T`` rad² and ``Ξ_B = n_b² T`` (rad/s)² per sample (003 eqs. 18, 31).
    acc_noise_m_s2_sqrt_hz : with two accelerometers per axis averaged, ``1/√2`` of one
        sensor's (003 eq. 42). acc_motion_fraction : ``σ_C / g`` (003 eq. 43 uses 0.01
        for microsurgery; human motion needs more).
    mag_noise_ut_sqrt_hz, mag_field_ut : only their ratio enters, the noise relative to
        the field's norm: eq. 44's ``σ_N = σ_M / |m|`` with ``σ_M`` that ratio times the
        norm of the first field sample (``field_reference``), in the data's unit, so the
        estimate does not depend on the magnetometer's unit. Give the sensor's noise
        density and the local field strength in µT whatever unit the data is in;
        0.1/50 is 0.09 µT/√Hz at BROAD's 44 µT (the former absolute default: BROAD
        4.70 deg against 4.71, the filter as printed 9.09 against 9.11).

    Extensions (neutral value in brackets):

    decoupled_heading : replaces TRIAD's quaternion (eq. 38) and covariance (eq. 45) by a
        tilt from the accelerometer and a heading from the field levelled by the
        *predicted* tilt [False]. TRIAD projects the field on the plane normal to the
        measured acceleration, so a tilt error α of the accelerometer becomes a heading
        error of about α·tan(dip) (2.8 α at BROAD's 70 deg). Eq. 45 does model this, as a
        ``σ_G² tan² dip`` heading variance and the tilt-heading correlation through which
        the filter cancels it to first order; but the linear-acceleration tilt errors of
        human motion reach tens of degrees, far outside that first order, and leak into
        heading and bias. Here ``q = TRIAD(ẑ⁻, m) ⊗ r``, ``ẑ⁻`` the predicted up in the body
        frame and ``r`` the shortest rotation taking the measured up to ``ẑ⁻`` (a
        horizontal axis), with ``Ξθ = σ_G² (I - ẑẑᵀ) + σ_N²/|ẑ × n̂|² ẑẑᵀ``. Its heading
        error depends on the state's tilt error; the correlation is neglected (the tilt
        variance of ``P`` is far below ``σ_N²``).
    gyr_scale_noise_sqrt_s : ``κ``, √s [0]: the rate noise density of body axis k
        becomes ``√(n_k² + κ² ω_k²)`` (eq. 31). Scale-factor and misalignment errors of a
        MEMS gyroscope (0.3-1 % on BROAD, measured against the optical truth) give an
        angle error proportional to the rate: 1 % of 500 deg/s is 5 deg/s, while ``n``
        models only the noise at rest, so ``P`` would be far too small during fast
        rotations and the tilt gate would refuse the corrections they need.
    acc_norm_correlation_s : ``τ_a``, s [0]: ``σ_G² += (|a|/g - 1)² · 2τ_a/T``
        (eqs. 41-43). Body acceleration is not white at 286 Hz but correlated over
        0.1-1 s; a correlated error of variance ``σ²`` acts on the filter like white noise
        of ``σ² · 2τ/T`` per sample. ``(|a|/g - 1)²`` is the instantaneous estimate of
        ``(σ_C/g)²`` from the norm (a lower bound: the part of the acceleration normal to
        gravity barely changes the norm). Uses ``g`` (eq. 41), not the sensor's norm at
        rest: on BROAD that norm is 0.5-1 % above g and the resulting small inflation at
        rest scored better than a per-sensor reference (5.0-5.3 deg).
    mag_norm_correlation_s, mag_dip_correlation_s : ``τ_m``, ``τ_δ``, s [0]:
        ``σ_N² += ((|m|/|m₀| - 1)² 2τ_m + (sin δ - sin δ₀)² 2τ_δ)/T`` (eq. 44), the same
        reading of a magnetic disturbance: its size estimated from the field norm and from
        its dip ``δ`` (``sin δ = -ẑ⁻·m̂``, the field's component along the *predicted*
        down, so body acceleration does not enter it), against the norm and dip of the
        first field sample (state: ``BiasKalmanState.field_reference``, kept on restarts).
    tilt_gate : ``γ`` [None: off]: with ``d²`` the squared normalised tilt
        innovation (2 dof: the innovation angle normal to ``ẑ⁻`` against
        ``½ tr P_θ⊥ + σ_G²`` per axis, ``P_θ = 4 Q̃ᵀ P_qq Q̃``), ``σ_G²`` is multiplied by
        ``(d²/γ)^p`` where ``d² > γ`` (eq. 45's ``σ_G²``). A soft chi-square gate
        (Huber's weight for ``p = 1``, a redescending one for ``p > 1``): a large
        innovation still corrects, less than in proportion, so a filter that drifted
        never locks itself out as with hard rejection (tried: 6.8-7.0 deg on BROAD, and
        30 deg on fast_rotation_with_breaks from lock-out). 20 is chi-square(2) at
        p = 4.5e-5; it fires on body acceleration, seldom on noise.
    tilt_gate_exponent : ``p`` [1].
    """

    gyr_noise_rad_s_sqrt_hz: Density = param(
        3e-4, unit="rad/s/√Hz", gt=0,
        help="white noise density of the rate input (one value or one per body axis)",
        calibrated_by="noise.gyr_noise_density_rad_s_sqrt_hz",
    )
    gyr_bias_walk_rad_s_sqrt_s: Density = param(
        1e-7, unit="rad/s/√s", ge=0,
        help="random-walk density of the rate bias (one value or one per body axis)",
        calibrated_by="noise.gyr_bias_walk_rad_s2_sqrt_hz",
    )
    acc_noise_m_s2_sqrt_hz: float = param(
        0.0015,
        unit="m/s²/√Hz",
        gt=0,
        help="white noise density of the gravity estimate",
        calibrated_by="noise.acc_noise_density_m_s2_sqrt_hz",
    )
    acc_motion_fraction: float = param(
        0.02, ge=0, le=1, help="body acceleration as white noise, fraction of g (003: 0.01)"
    )
    mag_noise_ut_sqrt_hz: float = param(
        0.1, unit="µT/√Hz", gt=0,
        help="magnetometer white noise density, at a field of mag_field_ut (only the ratio counts)",
    )
    mag_field_ut: float = param(
        50.0, unit="µT", gt=0,
        help="field strength mag_noise_ut_sqrt_hz refers to (the data may be in any unit)",
    )
    init_angle_std_rad: float = param(
        0.1, unit="rad", gt=0, le=math.pi, help="initial orientation uncertainty per axis"
    )
    init_bias_std_rad_s: float = param(
        0.02, unit="rad/s", gt=0,
        help="initial bias uncertainty per axis (a restart keeps the current one)",
    )
    gravity_m_s2: float = param(
        STANDARD_GRAVITY_M_S2, unit="m/s²", gt=0, help="gravity magnitude g"
    )
    decoupled_heading: bool = param(
        True, help="tilt from acc, heading from the field levelled by the predicted tilt"
    )
    gyr_scale_noise_sqrt_s: float = param(
        1e-3, unit="√s", ge=0, help="rate noise growing with the rate (scale-factor errors)"
    )
    acc_norm_correlation_s: float = param(
        0.5, unit="s", ge=0, help="acc noise raised by the acc norm's distance from g"
    )
    mag_norm_correlation_s: float = param(
        0.05, unit="s", ge=0, help="field noise raised by its norm's distance from the reference"
    )
    mag_dip_correlation_s: float = param(
        0.5, unit="s", ge=0, help="field noise raised by its dip's distance from the reference"
    )
    tilt_gate: float | None = param(
        20.0, gt=0, none_ok=True, help="soft chi-square(2) gate on the tilt innovation (None: off)"
    )
    tilt_gate_exponent: float = param(
        1.5, gt=0, le=10, help="how fast the tilt gate inflates the acc noise beyond it"
    )

    #: the extensions' neutral values: the filter as printed in 003
    AS_PRINTED: ClassVar[dict[str, Any]] = {
        "decoupled_heading": False,
        "gyr_scale_noise_sqrt_s": 0.0,
        "acc_norm_correlation_s": 0.0,
        "mag_norm_correlation_s": 0.0,
        "mag_dip_correlation_s": 0.0,
        "tilt_gate": None,
        "tilt_gate_exponent": 1.0,
    }

    @classmethod
    def as_printed(cls, **values: Any) -> BiasKalmanParams:
        """Parameters of the filter as printed in 003 (every extension neutral), plus ``values``."""
        return cls(**{**cls.AS_PRINTED, **values})

    def check(self) -> None:
        """Per-axis densities come as one number or three."""
        super().check()
        for name in ("gyr_noise_rad_s_sqrt_hz", "gyr_bias_walk_rad_s_sqrt_s"):
            value = getattr(self, name)
            if isinstance(value, tuple) and len(value) != 3:
                raise ValueError(
                    f"parameter {name} must be one number or three (one per body axis); "
                    f"got {len(value)}"
                )

    def axis_variances(self) -> tuple[Array, Array]:
        """Squared rate-noise and bias-walk densities per body axis, (3,) each."""
        gyr = np.broadcast_to(np.asarray(self.gyr_noise_rad_s_sqrt_hz, dtype=np.float64), (3,))
        walk = np.broadcast_to(
            np.asarray(self.gyr_bias_walk_rad_s_sqrt_s, dtype=np.float64), (3,)
        )
        return np.ascontiguousarray(gyr**2), np.ascontiguousarray(walk**2)

    def mag_relative_var(self) -> float:
        """``(σ_M/|M|)²``, 1/Hz: the field's squared noise density relative to its norm."""
        return (self.mag_noise_ut_sqrt_hz / self.mag_field_ut) ** 2


def initial_covariance(quat0: Array, angle_std_rad: float, bias_std_rad_s: float) -> Array:
    """Initial covariance (S, 7, 7): body-frame angle std and bias std per axis, uncorrelated.

    The quaternion block is ``¼ Q̃ σ² I Q̃ᵀ`` plus the second-order term along ``q``.
    """
    q = np.asarray(quat0, dtype=np.float64).reshape(-1, 4)
    cov = np.zeros((q.shape[0], 7, 7))
    angle = np.eye(3) * angle_std_rad**2
    qt = np.empty((4, 3))
    for s in range(q.shape[0]):
        kernel.fill_quat_noise(q[s, 0], q[s, 1], q[s, 2], q[s, 3], angle, qt, cov[s, :4, :4])
        cov[s, 4:, 4:] = np.eye(3) * bias_std_rad_s**2
    return cov


#: the named slots of a sensor's state row (``state.get(name)``; ``kernel``)
STATE_LAYOUT = {
    "filter_quat": (kernel.Q, 4),
    "gyr_bias_rad_s": (kernel.BIAS, 3),
    "gyr_bias_sd_rad_s": (kernel.BIAS_SD, 3),
    "cov": (kernel.COV, 49),
    "field_reference": (kernel.FIELD_REF, 2),
}

_STAMPS = itertools.count(1)
#: ``kernel.coefficients`` as Python (the function itself when numba's JIT is disabled)
_COEFFICIENTS = getattr(kernel.coefficients, "py_func", kernel.coefficients)


def covariance(state: CompiledState) -> Array:
    """(S, 7, 7) the covariance of ``[q (4), b (3)]`` held in a :class:`BiasKalman` state."""
    return state.get("cov").reshape(-1, 7, 7)


class BiasKalman(CompiledEstimator[BiasKalmanParams]):
    """Ang's quaternion + rate-bias Kalman filter with the TRIAD measurement (``bias-kf``).

    Needs a magnetometer (TRIAD does). Inputs per sample: rate (gyroscope or
    all-accelerometer estimate) rad/s, accelerometer m/s², magnetometer (any unit), body
    frame. A sample without a usable accelerometer or field (the screening's zero
    sentinels) gets the partial correction the other allows: tilt only, or heading only.

    Magnetic disturbances are the filter's own business (``rejects_mag_disturbance``: the
    screening's norm/dip gate is off): the field's variance grows with its norm's and
    dip's distance from the field reference (``mag_norm_correlation_s``,
    ``mag_dip_correlation_s``), so a disturbed field still corrects, less and less; a field
    beyond ``mag_norm_tol`` or ``mag_dip_tol_deg`` is flagged MAG_DISTURBED. On BROAD the
    soft weighting alone scores 4.70 deg, with the screening's gate in front 4.99 deg
    (without the partial tilt-only update 5.60), with a hard rejection beyond the
    tolerances added to the soft weighting 4.70.

    The whole per-sample path is compiled (:mod:`margtrack.methods.bias_kf.kernel`). State
    (:class:`~margtrack.estimator.compiled.CompiledState`, ``state.get(name)``, (S, width)):
    ``filter_quat`` (4), ``gyr_bias_rad_s`` (3) the bias of the rate input, rad/s,
    ``gyr_bias_sd_rad_s`` (3) its standard deviation, ``cov`` (49) the 7x7 covariance of
    ``[q (4), b (3)]`` row-major (quaternion part dimensionless, bias part (rad/s)²;
    :func:`covariance` gives it (S, 7, 7)), ``field_reference`` (2) the field norm (mag
    unit) and the sine of its dip of the first field sample, NaN before it (used by
    ``mag_norm_correlation_s`` and ``mag_dip_correlation_s`` and the disturbance flag).
    A restart after a gap keeps the bias, its covariance block and the field reference
    (what is known of the sensor and the place), measures the orientation afresh, starts
    its covariance block from ``init_angle_std_rad`` and drops its correlation with the
    bias.

    Outputs besides ``quat``:

    - ``gyr_bias_rad_s`` (N, 3): the bias estimate, rad/s (subtract it from the rate);
    - ``cov_diag`` (N, 7): the diagonal of the covariance after each sample, order
      ``[q_w, q_x, q_y, q_z, b_x, b_y, b_z]`` (quaternion part dimensionless, bias part
      (rad/s)²); the full 7x7 matrix after the last sample is ``covariance(est.state)``;
    - ``degenerate`` (N,) int8, method detail kept for existing users (the same facts are
      in ``flags``): 0 corrected (or ``dt = 0``, or held), 1 no accelerometer: heading
      corrected only (flag ACC_IGNORED), 2 no field: tilt only (MAG_IGNORED), 3
      accelerometer or predicted up parallel to the field: tilt only (MAG_IGNORED), 5
      innovation covariance not positive definite: not corrected (ACC_IGNORED and
      MAG_IGNORED).

    A field's norm or dip beyond ``mag_norm_tol`` or ``mag_dip_tol_deg`` from the
    reference is flagged MAG_DISTURBED (the former ``mag_disturbed`` output).
    """

    name = "bias-kf"
    params_type = BiasKalmanParams
    mag_optional = False
    rejects_mag_disturbance = True
    kernel = kernel
    state_layout = STATE_LAYOUT
    outputs_layout = (("gyr_bias_rad_s", 3), ("cov_diag", 7), ("degenerate", 1))

    def _coefficients(self) -> Array:
        """The kernel's coefficients (``kernel.coefficients``, run as Python: no compiled
        call when an estimator is built or retuned); a new stamp each time."""
        p = self.params
        gyr_var, bias_var = p.axis_variances()
        return _COEFFICIENTS(
            gyr_var,
            bias_var,
            p.acc_noise_m_s2_sqrt_hz**2,
            (p.acc_motion_fraction * p.gravity_m_s2) ** 2,
            p.gravity_m_s2**2,
            p.mag_relative_var(),
            bool(p.decoupled_heading),
            p.gyr_scale_noise_sqrt_s**2,
            float(p.acc_norm_correlation_s),
            float(p.mag_norm_correlation_s),
            float(p.mag_dip_correlation_s),
            math.inf if p.tilt_gate is None else float(p.tilt_gate),
            float(p.tilt_gate_exponent),
            float(p.mag_norm_tol),
            math.radians(p.mag_dip_tol_deg),
            frames.up(p.frame),
            frames.mag_reference(p.frame, dip_deg=0.0),
            p.init_angle_std_rad**2,
            p.init_bias_std_rad_s**2,
            float(next(_STAMPS)),
        )

    def _run_arrays(self, *args: Any, **kwargs: Any) -> Estimate:
        """The compiled run, with ``degenerate`` (S, N) int8 as before (the kernel writes
        the code as a float output; converted when first read)."""
        return with_output_types(super()._run_arrays(*args, **kwargs), {"degenerate": np.int8})


@dataclass(frozen=True)
class AllAccelerometerTrack:
    """Orientation from the all-accelerometer IMU and the bias filter (003 Fig. 2).

    quat (N, 4) body to ``frame``; rate_rad_s (N, 3) the solver's rates fed to the filter;
    gyr_bias_rad_s (N, 3) the filter's bias estimate; cov_diag (N, 7); degenerate (N,)
    TRIAD flags as in :class:`BiasKalman`.
    """

    quat: Array
    rate_rad_s: Array
    gyr_bias_rad_s: Array
    cov_diag: Array
    degenerate: NDArray[np.int8]
    frame: str


def track_all_accelerometer(
    recording: AllAccelerometerRecording, params: BiasKalmanParams | None = None, *,
    feedback: bool = True, damping: float = 0.0, max_iter: int = 20, tol: float = 1e-12,
) -> AllAccelerometerTrack:
    """Run the rate solver and :class:`BiasKalman` on an all-accelerometer recording.

    Rates from :func:`~margtrack.single_frame.all_accelerometer.solve_angular_velocity`
    (starting at rest, eq. 3), gravity from the averaged channels (eq. 42), TRIAD with the
    magnetometer; the filter starts at the TRIAD orientation of the first sample.
    ``feedback=False`` is 003's Fig. 2 as drawn (solver open loop). ``feedback=True``
    (margtrack's addition) subtracts the bias estimate from the solver's previous rate
    after every sample and resets the bias state: the open-loop solver's error grows
    without bound (integrated noise, then the centripetal terms' instability, see
    :mod:`margtrack.single_frame.all_accelerometer`), and within seconds leaves the range
    where the filter's linear bias model holds. The filter here is the one as printed:
    the extensions of ``params`` (``decoupled_heading`` ...) are not applied.
    """
    p = BiasKalmanParams() if params is None else params
    a_d = differential_acceleration(recording.readings_m_s2)
    grav = np.ascontiguousarray(gravity_estimate(recording.readings_m_s2))
    mag = np.ascontiguousarray(recording.mag, dtype=np.float64)
    n = a_d.shape[0]
    if mag.shape != (n, 3):
        raise ValueError(f"recording.mag must have shape ({n}, 3), got {mag.shape}")
    dt = np.empty(n)
    dt[0] = 0.0
    dt[1:] = np.diff(recording.t)
    q0 = initial_orientation(grav[:1], mag[:1], p.frame)
    cov = initial_covariance(q0, p.init_angle_std_rad, p.init_bias_std_rad_s)
    gyr_var, bias_var = p.axis_variances()
    out = (np.empty((n, 3)), np.empty((n, 4)), np.empty((n, 3)), np.empty((n, 7)),
           np.empty(n, dtype=np.int8))
    aa_kernel.track(
        a_d, grav, mag, dt, recording.array.baselines(), np.zeros(3), q0, np.zeros((1, 3)),
        cov, frames.up(p.frame), frames.mag_reference(p.frame, dip_deg=0.0), gyr_var,
        bias_var, p.acc_noise_m_s2_sqrt_hz**2, (p.acc_motion_fraction * p.gravity_m_s2) ** 2,
        p.gravity_m_s2**2, p.mag_relative_var(), bool(feedback), float(damping),
        int(max_iter), float(tol), *out,
    )
    return AllAccelerometerTrack(out[1], out[0], out[2], out[3], out[4], p.frame)
