"""Ang's bias-augmented quaternion Kalman filter (003, section IV): ``--method bias-kf``.

State ``x = [q, b]``: the orientation ``q`` (body to earth, ``[w, x, y, z]``) and the bias
``b`` of the angular-rate input, rad/s (003 eqs. 17-19). The rate input is a gyroscope or
the all-accelerometer IMU's estimate (:mod:`margtrack.estimators.all_accelerometer`).

- Prediction (eqs. 25-31, 47-48): ``q⁻ = Φ_Q(Ω - b) q``, the exact rotation for a rate
  constant over the period; ``P⁻ = Φ P Φᵀ + W`` with ``Φ = [[Φ_Q, Φ_B], [0, I]]``,
  ``Φ_B = -½ T Φ_Q Q̃``, ``W = diag(¼ Q̃ Ξ_Ω Q̃ᵀ, Ξ_B)``, ``Ξ_Ω = n_g² T``, ``Ξ_B = n_b² T``.
- Measurement (eqs. 13, 38-40): the quaternion of the TRIAD matrix from accelerometer and
  magnetometer, ``H = [I₄ 0]``, computed by the largest of four branches so every
  orientation works, with the sign nearest ``q⁻``.
- Measurement covariance (eqs. 41-46): ``σ_G² = (σ_W² + σ_C²)/|a|²`` with ``σ_W`` the
  accelerometer white noise per sample and ``σ_C = f·g`` the body-acceleration part
  (``f`` = 0.01 in 003 eq. 43); ``σ_N² = σ_M²/|m|²``; the TRIAD error-angle covariance
  ``Ξθ`` (eq. 45) and ``V = ¼ Q̃ Ξθ Q̃ᵀ`` (eq. 46).
- Update (eqs. 49-51) in Joseph form (algebraically eq. 51, numerically symmetric and
  positive definite), then ``q`` normalised.

``W`` and ``V`` are singular along ``q`` as printed. ``W`` gets the Gaussian second moment of
the quaternion error along ``q`` (``E|θ|⁴/64``), which keeps ``P`` positive definite; ``V``
gets unit variance there (the measured quaternion's component along ``q`` is the biased,
information-free ``cos(φ/2) - 1``): with a tiny variance it leaks into the bias through
cross-covariances and the filter becomes inconsistent (see
:func:`margtrack.kernels.bias_kf.fill_quat_noise` and the consistency test).

Paper slips corrected (the sign of ``Ω×`` in eq. 21, the row order of eq. 24, the missing
``T`` of eq. 28) are listed in :mod:`margtrack.kernels.bias_kf`.

Extensions (margtrack's, documented in :class:`BiasKalmanParams`; each has a neutral value
at which the filter is the one above to the last bit, :meth:`BiasKalmanParams.as_printed`
sets them all): a decoupled tilt/heading measurement (eqs. 38, 45), rate-proportional gyro
noise (eq. 31), measurement noise adapted to the accelerometer norm and to the field's
norm and dip (eqs. 41-44), and a robust gate on the tilt innovation. They are the defaults:
on BROAD they take the mean total RMSE from 9.1 deg (filter as printed, tuned) to 4.7 deg.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimators.all_accelerometer import differential_acceleration, gravity_estimate
from margtrack.estimators.base import Estimator, Params, State, initial_orientation
from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.kernels import all_accelerometer as aa_kernel
from margtrack.kernels import bias_kf as kernel
from margtrack.sim.all_accelerometer import AllAccelerometerRecording

Array = NDArray[np.float64]
Density = float | tuple[float, float, float]

__all__ = [
    "AllAccelerometerTrack",
    "BiasKalman",
    "BiasKalmanParams",
    "BiasKalmanState",
    "initial_covariance",
    "track_all_accelerometer",
]


def _density(value: Density, name: str, positive: bool) -> tuple[float, ...] | float:
    """A noise density given once or per body axis, validated."""
    arr = np.asarray(value, dtype=np.float64) if not isinstance(value, str) else None
    bound = "> 0" if positive else ">= 0"
    ok = arr is not None and arr.shape in ((), (3,)) and bool(np.all(np.isfinite(arr)))
    if ok:
        ok = bool(np.all(arr > 0.0)) if positive else bool(np.all(arr >= 0.0))
    if not ok:
        raise ValueError(
            f"{name} must be a finite number {bound} (or three of them, one per body axis), "
            f"got {value!r}"
        )
    return float(arr) if arr.ndim == 0 else tuple(float(v) for v in arr)


def _number(value: float, name: str, low: float, high: float = math.inf, closed: bool = False):
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    inside = (low <= x if closed else low < x) and x <= high
    if not (math.isfinite(x) and inside):
        interval = f"{'[' if closed else '('}{low:g}, {high:g}]"
        raise ValueError(f"{name} must be a finite number in {interval}, got {value!r}")
    return x


@dataclass(frozen=True)
class BiasKalmanParams(Params):
    """Noise densities (SI, as an Allan variance gives them), initial uncertainty, extensions.

    The gains depend only on ratios of these; raising a rate noise makes the filter
    follow the measurement faster, raising an acc/mag noise makes it trust the rate input
    longer. Defaults: the one set for all 16 BROAD trials (286 Hz) found best by a
    coordinate search (3-5 values per parameter, two rounds) over the noise densities and
    the extensions below: mean total RMSE 4.71 deg (heading 3.54, inclination 2.82;
    undisturbed trials 4.52, disturbed 4.96), against 9.11 deg for the filter as
    printed with its own best noise set (``as_printed()`` with the former defaults
    ``gyr_noise_rad_s_sqrt_hz=1e-4, acc_motion_fraction=0.03``) and about 4.9 deg for
    Madgwick with one tuned beta. Nine tuned numbers against Madgwick's one: the margin
    is within what tuning on the test trials buys. Ablation on BROAD (mean total RMSE
    with one extension neutral, the rest at the defaults, to about 0.02 deg):
    ``decoupled_heading`` off 10.7, ``gyr_scale_noise_sqrt_s`` 0 6.0,
    ``acc_norm_correlation_s`` 0 8.9, ``mag_dip_correlation_s`` 0 5.6,
    ``mag_norm_correlation_s`` 0 5.0, ``tilt_gate`` inf 15.0 (fast_combined diverges:
    the rate-proportional noise then lets accelerations through),
    ``tilt_gate_exponent`` 1 4.9.

    gyr_noise_rad_s_sqrt_hz : white noise density of the rate input (angle random walk),
        rad/s/√Hz, > 0; a number or one per body axis. ``Ξ_Ω = n² T`` rad² (003 eq. 31).
    gyr_bias_walk_rad_s_sqrt_s : density of the bias random walk, rad/s/√s, >= 0; a number
        or one per body axis. ``Ξ_B = n_b² T`` (rad/s)² per sample (003 eqs. 18, 31).
    acc_noise_m_s2_sqrt_hz : white noise density of the gravity estimate, m/s²/√Hz, > 0
        (with two accelerometers per axis averaged, ``1/√2`` of one sensor's, 003 eq. 42).
    acc_motion_fraction : ``σ_C / g``, the body acceleration treated as white noise on the
        gravity estimate, in [0, 1] (003 eq. 43 uses 0.01 for microsurgery; human motion
        needs more).
    mag_noise_ut_sqrt_hz : white noise density of the magnetometer, in the magnetometer's
        unit (µT) per √Hz, > 0 (003 eq. 44).
    init_angle_std_rad : initial orientation uncertainty per axis, rad, > 0.
    init_bias_std_rad_s : initial bias uncertainty per axis, rad/s, > 0.
    gravity_m_s2 : gravity magnitude ``g`` for ``σ_C``, m/s², > 0.

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
    gyr_scale_noise_sqrt_s : ``κ``, √s, >= 0 [0]: the rate noise density of body axis k
        becomes ``√(n_k² + κ² ω_k²)`` (eq. 31). Scale-factor and misalignment errors of a
        MEMS gyroscope (0.3-1 % on BROAD, measured against the optical truth) give an
        angle error proportional to the rate: 1 % of 500 deg/s is 5 deg/s, while ``n``
        models only the noise at rest, so ``P`` would be far too small during fast
        rotations and the tilt gate would refuse the corrections they need.
    acc_norm_correlation_s : ``τ_a``, s, >= 0 [0]: ``σ_G² += (|a|/g - 1)² · 2τ_a/T``
        (eqs. 41-43). Body acceleration is not white at 286 Hz but correlated over
        0.1-1 s; a correlated error of variance ``σ²`` acts on the filter like white noise
        of ``σ² · 2τ/T`` per sample. ``(|a|/g - 1)²`` is the instantaneous estimate of
        ``(σ_C/g)²`` from the norm (a lower bound: the part of the acceleration normal to
        gravity barely changes the norm). Uses ``g`` (eq. 41), not the sensor's norm at
        rest: on BROAD that norm is 0.5-1 % above g and the resulting small inflation at
        rest scored better than a per-sensor reference (5.0-5.3 deg).
    mag_norm_correlation_s, mag_dip_correlation_s : ``τ_m``, ``τ_δ``, s, >= 0 [0]:
        ``σ_N² += ((|m|/|m₀| - 1)² 2τ_m + (sin δ - sin δ₀)² 2τ_δ)/T`` (eq. 44), the same
        reading of a magnetic disturbance: its size estimated from the field norm and from
        its dip ``δ`` (``sin δ = -ẑ⁻·m̂``, the field's component along the *predicted*
        down, so body acceleration does not enter it), against the norm and dip of the
        first sample after a reset (state: ``BiasKalmanState.field_reference``).
    tilt_gate : ``γ``, > 0, ``inf`` = off [inf]: with ``d²`` the squared normalised tilt
        innovation (2 dof: the innovation angle normal to ``ẑ⁻`` against
        ``½ tr P_θ⊥ + σ_G²`` per axis, ``P_θ = 4 Q̃ᵀ P_qq Q̃``), ``σ_G²`` is multiplied by
        ``(d²/γ)^p`` where ``d² > γ`` (eq. 45's ``σ_G²``). A soft chi-square gate
        (Huber's weight for ``p = 1``, a redescending one for ``p > 1``): a large
        innovation still corrects, less than in proportion, so a filter that drifted
        never locks itself out as with hard rejection (tried: 6.8-7.0 deg on BROAD, and
        30 deg on fast_rotation_with_breaks from lock-out). 20 is chi-square(2) at
        p = 4.5e-5; it fires on body acceleration, seldom on noise.
    tilt_gate_exponent : ``p``, in (0, 10] [1].
    """

    gyr_noise_rad_s_sqrt_hz: Density = 3e-4
    gyr_bias_walk_rad_s_sqrt_s: Density = 1e-7
    acc_noise_m_s2_sqrt_hz: float = 0.0015
    acc_motion_fraction: float = 0.02
    mag_noise_ut_sqrt_hz: float = 0.09
    init_angle_std_rad: float = 0.1
    init_bias_std_rad_s: float = 0.02
    gravity_m_s2: float = STANDARD_GRAVITY_M_S2
    decoupled_heading: bool = True
    gyr_scale_noise_sqrt_s: float = 1e-3
    acc_norm_correlation_s: float = 0.5
    mag_norm_correlation_s: float = 0.05
    mag_dip_correlation_s: float = 0.5
    tilt_gate: float = 20.0
    tilt_gate_exponent: float = 1.5

    #: the extensions' neutral values: the filter as printed in 003
    AS_PRINTED: ClassVar[dict[str, Any]] = {
        "decoupled_heading": False,
        "gyr_scale_noise_sqrt_s": 0.0,
        "acc_norm_correlation_s": 0.0,
        "mag_norm_correlation_s": 0.0,
        "mag_dip_correlation_s": 0.0,
        "tilt_gate": math.inf,
        "tilt_gate_exponent": 1.0,
    }

    @classmethod
    def as_printed(cls, **values: Any) -> BiasKalmanParams:
        """Parameters of the filter as printed in 003 (every extension neutral), plus ``values``."""
        return cls(**{**cls.AS_PRINTED, **values})

    def __post_init__(self) -> None:
        super().__post_init__()
        set_ = object.__setattr__
        set_(self, "gyr_noise_rad_s_sqrt_hz",
             _density(self.gyr_noise_rad_s_sqrt_hz, "gyr_noise_rad_s_sqrt_hz", True))
        set_(self, "gyr_bias_walk_rad_s_sqrt_s",
             _density(self.gyr_bias_walk_rad_s_sqrt_s, "gyr_bias_walk_rad_s_sqrt_s", False))
        set_(self, "acc_noise_m_s2_sqrt_hz",
             _number(self.acc_noise_m_s2_sqrt_hz, "acc_noise_m_s2_sqrt_hz", 0.0))
        set_(self, "acc_motion_fraction",
             _number(self.acc_motion_fraction, "acc_motion_fraction", 0.0, 1.0, closed=True))
        set_(self, "mag_noise_ut_sqrt_hz",
             _number(self.mag_noise_ut_sqrt_hz, "mag_noise_ut_sqrt_hz", 0.0))
        set_(self, "init_angle_std_rad",
             _number(self.init_angle_std_rad, "init_angle_std_rad", 0.0, math.pi))
        set_(self, "init_bias_std_rad_s",
             _number(self.init_bias_std_rad_s, "init_bias_std_rad_s", 0.0))
        set_(self, "gravity_m_s2", _number(self.gravity_m_s2, "gravity_m_s2", 0.0))
        if not isinstance(self.decoupled_heading, (bool, np.bool_)):
            raise ValueError(
                f"decoupled_heading must be True or False, got {self.decoupled_heading!r}"
            )
        set_(self, "decoupled_heading", bool(self.decoupled_heading))
        for name in ("gyr_scale_noise_sqrt_s", "acc_norm_correlation_s",
                     "mag_norm_correlation_s", "mag_dip_correlation_s"):
            set_(self, name, _number(getattr(self, name), name, 0.0, closed=True))
        try:
            tilt_gate = float(self.tilt_gate)
        except (TypeError, ValueError):
            tilt_gate = math.nan
        if not tilt_gate > 0.0:  # also NaN; inf (off) is allowed
            raise ValueError(f"tilt_gate must be a number in (0, inf], got {self.tilt_gate!r}")
        set_(self, "tilt_gate", tilt_gate)
        set_(self, "tilt_gate_exponent",
             _number(self.tilt_gate_exponent, "tilt_gate_exponent", 0.0, 10.0))

    def axis_variances(self) -> tuple[Array, Array]:
        """Squared rate-noise and bias-walk densities per body axis, (3,) each."""
        gyr = np.broadcast_to(np.asarray(self.gyr_noise_rad_s_sqrt_hz, dtype=np.float64), (3,))
        walk = np.broadcast_to(
            np.asarray(self.gyr_bias_walk_rad_s_sqrt_s, dtype=np.float64), (3,)
        )
        return np.ascontiguousarray(gyr**2), np.ascontiguousarray(walk**2)


@dataclass
class BiasKalmanState(State):
    """Filter state per sensor: orientation, rate bias and the 7x7 covariance.

    quat : (S, 4) orientation; gyr_bias_rad_s : (S, 3) bias of the rate input, rad/s;
    cov : (S, 7, 7) covariance of ``[q (4), b (3)]`` (quaternion part dimensionless,
    bias part (rad/s)²); field_reference : (S, 2) the field norm (mag unit) and the sine
    of its dip of the first sample after a reset, NaN before it (used by
    ``mag_norm_correlation_s`` and ``mag_dip_correlation_s``).
    """

    gyr_bias_rad_s: Array = field(default_factory=lambda: np.zeros((0, 3)))
    cov: Array = field(default_factory=lambda: np.zeros((0, 7, 7)))
    field_reference: Array = field(default_factory=lambda: np.zeros((0, 2)))


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


class BiasKalman(Estimator[BiasKalmanParams, BiasKalmanState]):
    """Ang's quaternion + rate-bias Kalman filter with the TRIAD measurement (``bias-kf``).

    Needs a magnetometer (TRIAD does). Inputs per sample: rate (gyroscope or
    all-accelerometer estimate) rad/s, accelerometer m/s², magnetometer (µT), body frame.

    Outputs besides ``quat``:

    - ``gyr_bias_rad_s`` (N, 3): the bias estimate, rad/s (subtract it from the rate);
    - ``cov_diag`` (N, 7): the diagonal of the covariance after each sample, order
      ``[q_w, q_x, q_y, q_z, b_x, b_y, b_z]`` (quaternion part dimensionless, bias part
      (rad/s)²); the full 7x7 matrix after the last sample is ``state.cov``;
    - ``degenerate`` (N,) int8: 0 corrected, 1 zero accelerometer, 2 zero magnetometer,
      3 accelerometer parallel to the field, 5 innovation covariance not positive definite;
      a flagged sample is predicted only.
    """

    name = "bias-kf"
    params_type = BiasKalmanParams
    mag_optional = False

    def _new_state(self, quat0: Array) -> BiasKalmanState:
        p = self.params
        q = np.array(quat0, dtype=np.float64)
        return BiasKalmanState(
            quat=q,
            gyr_bias_rad_s=np.zeros((q.shape[0], 3)),
            cov=initial_covariance(q, p.init_angle_std_rad, p.init_bias_std_rad_s),
            field_reference=np.full((q.shape[0], 2), np.nan),
        )

    def _process(
        self,
        state: BiasKalmanState,
        gyr: Array | None,
        acc: Array,
        mag: Array | None,
        dt: Array,
    ) -> tuple[Array, dict[str, NDArray[Any]]]:
        assert gyr is not None and mag is not None  # uses_gyr, mag_optional = False
        p = self.params
        n_sensors, n = acc.shape[0], acc.shape[1]
        if state.gyr_bias_rad_s.shape != (n_sensors, 3) or state.cov.shape != (n_sensors, 7, 7):
            raise ValueError(
                f"the state must hold gyr_bias_rad_s ({n_sensors}, 3) and cov ({n_sensors}, 7, "
                f"7), got {state.gyr_bias_rad_s.shape} and {state.cov.shape}"
            )
        if state.field_reference.shape != (n_sensors, 2):
            raise ValueError(
                f"the state must hold field_reference ({n_sensors}, 2), got "
                f"{state.field_reference.shape}"
            )
        gyr_var, bias_var = p.axis_variances()
        # one kernel specialisation: numba types read-only arrays (a Recording's) apart
        gyr, acc, mag = (x if x.flags.writeable else x.copy() for x in (gyr, acc, mag))
        quat = np.empty((n_sensors, n, 4))
        bias = np.empty((n_sensors, n, 3))
        cov_diag = np.empty((n_sensors, n, 7))
        flags = np.empty((n_sensors, n), dtype=np.int8)
        kernel.bias_kf_extended(
            state.quat,
            state.gyr_bias_rad_s,
            state.cov,
            state.field_reference,
            gyr,
            acc,
            mag,
            dt,
            frames.up(p.frame),
            frames.mag_reference(p.frame, dip_deg=0.0),
            gyr_var,
            bias_var,
            p.acc_noise_m_s2_sqrt_hz**2,
            (p.acc_motion_fraction * p.gravity_m_s2) ** 2,
            p.gravity_m_s2**2,
            p.mag_noise_ut_sqrt_hz**2,
            p.decoupled_heading,
            p.gyr_scale_noise_sqrt_s**2,
            p.acc_norm_correlation_s,
            p.mag_norm_correlation_s,
            p.mag_dip_correlation_s,
            p.tilt_gate,
            p.tilt_gate_exponent,
            quat,
            bias,
            cov_diag,
            flags,
        )
        return quat, {"gyr_bias_rad_s": bias, "cov_diag": cov_diag, "degenerate": flags}


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

    Rates from :func:`~margtrack.estimators.all_accelerometer.solve_angular_velocity`
    (starting at rest, eq. 3), gravity from the averaged channels (eq. 42), TRIAD with the
    magnetometer; the filter starts at the TRIAD orientation of the first sample.
    ``feedback=False`` is 003's Fig. 2 as drawn (solver open loop). ``feedback=True``
    (margtrack's addition) subtracts the bias estimate from the solver's previous rate
    after every sample and resets the bias state: the open-loop solver's error grows
    without bound (integrated noise, then the centripetal terms' instability, see
    :mod:`margtrack.estimators.all_accelerometer`), and within seconds leaves the range
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
        p.gravity_m_s2**2, p.mag_noise_ut_sqrt_hz**2, bool(feedback), float(damping),
        int(max_iter), float(tol), *out,
    )
    return AllAccelerometerTrack(out[1], out[0], out[2], out[3], out[4], p.frame)
