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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

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
    x = float(value)
    inside = (low <= x if closed else low < x) and x <= high
    if not (math.isfinite(x) and inside):
        interval = f"{'[' if closed else '('}{low:g}, {high:g}]"
        raise ValueError(f"{name} must be a finite number in {interval}, got {value!r}")
    return x


@dataclass(frozen=True)
class BiasKalmanParams(Params):
    """Noise densities (SI, as an Allan variance gives them) and initial uncertainty.

    The gains depend only on ratios of these; raising a rate noise makes the filter
    follow TRIAD faster, raising an acc/mag noise makes it trust the rate input longer.
    Defaults: the one set for all 16 BROAD trials (286 Hz) that ``margtrack.bench.tune``
    found best (grid over ``acc_motion_fraction``, ``mag_noise_ut_sqrt_hz``,
    ``gyr_noise_rad_s_sqrt_hz``, ``gyr_bias_walk_rad_s_sqrt_s``): mean total RMSE 9.1 deg
    (Madgwick with one tuned beta: about 4.9 deg). The optimum is a flat ridge of equal
    noise ratios; the values on it are physically plausible for a MEMS MARG sensor.

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
    """

    gyr_noise_rad_s_sqrt_hz: Density = 1e-4
    gyr_bias_walk_rad_s_sqrt_s: Density = 1e-7
    acc_noise_m_s2_sqrt_hz: float = 0.0015
    acc_motion_fraction: float = 0.03
    mag_noise_ut_sqrt_hz: float = 0.09
    init_angle_std_rad: float = 0.1
    init_bias_std_rad_s: float = 0.02
    gravity_m_s2: float = STANDARD_GRAVITY_M_S2

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
    bias part (rad/s)²).
    """

    gyr_bias_rad_s: Array = field(default_factory=lambda: np.zeros((0, 3)))
    cov: Array = field(default_factory=lambda: np.zeros((0, 7, 7)))


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
        gyr_var, bias_var = p.axis_variances()
        # one kernel specialisation: numba types read-only arrays (a Recording's) apart
        gyr, acc, mag = (x if x.flags.writeable else x.copy() for x in (gyr, acc, mag))
        quat = np.empty((n_sensors, n, 4))
        bias = np.empty((n_sensors, n, 3))
        cov_diag = np.empty((n_sensors, n, 7))
        flags = np.empty((n_sensors, n), dtype=np.int8)
        kernel.bias_kf(
            state.quat,
            state.gyr_bias_rad_s,
            state.cov,
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
    where the filter's linear bias model holds.
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
