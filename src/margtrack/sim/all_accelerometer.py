"""The magnetometer-aided all-accelerometer IMU of 003 (section II-B/C, Fig. 1), simulated.

Three dual-axis accelerometers at body positions ``r_1, r_2, r_3`` (m) on a rigid body,
plus a three-axis magnetometer. Sensor {1} senses body x and z, {2} y and z, {3} x and y,
so the six channels are, in this order, ``CHANNELS = (1x, 1z, 2y, 2z, 3x, 3y)``.

Rigid-body kinematics give each sensor's specific force in body coordinates::

    f_i = Rᵀ (a + g_up) + α × r_i + ω × (ω × r_i)

with ``R`` body-to-earth, ``a`` the earth-frame linear acceleration of the body origin,
``g_up`` the gravity reference (what a level accelerometer reads at rest), ``ω`` and ``α``
the body-frame angular velocity and acceleration. Differences between two sensors cancel
the first term: ``f_j - f_i = (Ω×Ω× + Ω̇×) P_ij`` (003 eq. 1), which
:mod:`margtrack.single_frame.all_accelerometer` solves for ``ω``.

Motions come with analytic ``ω`` and ``α``: :func:`tremor_motion` (slow hand motion plus
8-12 Hz physiological tremor of tens of µm, 003 II-A) or any
:class:`~margtrack.sim.trajectories.Trajectory` through :func:`motion_from_trajectory`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as qt
from margtrack.frames import STANDARD_GRAVITY_M_S2, check_frame, gravity_reference, mag_reference
from margtrack.sim._validate import check_seed, number
from margtrack.sim.sensor_model import SensorErrors
from margtrack.sim.simulate import DEFAULT_DIP_DEG, DEFAULT_FIELD_UT
from margtrack.sim.trajectories import Trajectory

Array = NDArray[np.float64]

__all__ = [
    "ADXL203_NOISE_M_S2_SQRT_HZ",
    "CHANNELS",
    "AccelerometerArray",
    "AllAccelerometerRecording",
    "RigidBodyMotion",
    "motion_from_trajectory",
    "simulate_all_accelerometer",
    "specific_forces",
    "tremor_motion",
]

#: The six channels: (sensor index 0-2, body axis 0-2) of 1x, 1z, 2y, 2z, 3x, 3y (Fig. 1).
CHANNELS: tuple[tuple[int, int], ...] = ((0, 0), (0, 2), (1, 1), (1, 2), (2, 0), (2, 1))

#: ADXL-203 noise density, 110 µg/√Hz (Analog Devices datasheet), in m/s²/√Hz.
ADXL203_NOISE_M_S2_SQRT_HZ = 110e-6 * STANDARD_GRAVITY_M_S2

# Tag mixed into the seed so tremor_motion's draws differ from the sensor-noise stream.
_TREMOR_TAG = 0x54524D52


@dataclass(frozen=True)
class AccelerometerArray:
    """Positions of the three dual-axis accelerometers in the body frame, m.

    ``positions_m[i]`` is sensor ``{i+1}``. The three differential equations of 003 eq. 5
    must determine the angular acceleration: the matrix ``M`` of
    :meth:`tangential_matrix` must be invertible, else ``ValueError``.
    """

    positions_m: tuple[tuple[float, float, float], ...]

    def __post_init__(self) -> None:
        r = np.asarray(self.positions_m, dtype=np.float64)
        if r.shape != (3, 3) or not np.all(np.isfinite(r)):
            raise ValueError(f"positions_m must be 3 finite (x, y, z) positions, got {r.shape}")
        object.__setattr__(self, "positions_m", tuple(tuple(float(v) for v in p) for p in r))
        m = self.tangential_matrix()
        scale = float(np.max(np.abs(m)))
        if not scale > 0.0 or abs(np.linalg.det(m)) < 1e-9 * scale**3:
            raise ValueError(
                "positions_m do not determine the angular acceleration: the baselines "
                "P13 (x), P23 (y) and P12 (z) need P13z·P23x·P12y ≠ P13y·P23z·P12x "
                "(move sensor {2} off the line of {1} and {3})"
            )

    @classmethod
    def handheld_instrument(
        cls, length_m: float = 0.1, offset_m: float = 0.02
    ) -> AccelerometerArray:
        """The layout of 003 Fig. 1 along a pen-like instrument whose long axis is body z.

        Back suite: {1} at the origin (beside the magnetometer), {2} offset by
        ``offset_m`` in x and y; front suite: {3} ``length_m`` ahead on the z axis. 003 gives
        no dimensions; 100 mm and 20 mm fit a handheld microsurgical tool. The rate about z
        is sensed through the small offset only (``Ω̇_z`` enters ``a23y`` as ``-P23x Ω̇_z``),
        so it is the noisiest axis, as 003 II-B reports, and the solver's error dynamics
        ``δΩ̇ = -M⁻¹ C(Ω) δΩ`` grow at a rate of order ``|Ω| length/offset``: a smaller
        offset makes the open-loop rates unstable sooner (see the estimator's docstring).
        """
        length_m = number(length_m, "length_m", 0.0)
        offset_m = number(offset_m, "offset_m", 0.0)
        return cls(((0.0, 0.0, 0.0), (offset_m, offset_m, 0.0), (0.0, 0.0, length_m)))

    def positions(self) -> Array:
        """(3, 3) positions, rows r_1, r_2, r_3, m."""
        return np.array(self.positions_m)

    def baselines(self) -> Array:
        """(3, 3) rows ``P13, P23, P12`` (``P_ij = r_j - r_i``, m) of the rows of eq. 5."""
        r = self.positions()
        return np.stack([r[2] - r[0], r[2] - r[1], r[1] - r[0]])

    def tangential_matrix(self) -> Array:
        """``M`` (3, 3) with ``[a13x, a23y, a12z] = M Ω̇`` when ``Ω = 0`` (eq. 5, α only)."""
        p13, p23, p12 = self.baselines()
        return np.array(
            [
                [0.0, p13[2], -p13[1]],  # (Ω̇ × P13)_x
                [-p23[2], 0.0, p23[0]],  # (Ω̇ × P23)_y
                [p12[1], -p12[0], 0.0],  # (Ω̇ × P12)_z
            ]
        )


def specific_forces(
    array: AccelerometerArray, omega_rad_s: ArrayLike, alpha_rad_s2: ArrayLike,
    f_origin_m_s2: ArrayLike,
) -> Array:
    """The six channel readings (N, 6), m/s², in :data:`CHANNELS` order, noise-free.

    ``omega_rad_s``, ``alpha_rad_s2`` (N, 3) body frame; ``f_origin_m_s2`` (N, 3) the
    specific force at the body origin in body coordinates, ``Rᵀ(a + g_up)``.
    ``f_i = f_origin + α × r_i + ω × (ω × r_i)``.
    """
    w = np.asarray(omega_rad_s, dtype=np.float64)
    a = np.asarray(alpha_rad_s2, dtype=np.float64)
    f0 = np.asarray(f_origin_m_s2, dtype=np.float64)
    out = np.empty((f0.shape[0], 6))
    r = array.positions()
    for k, (sensor, axis) in enumerate(CHANNELS):
        ri = np.broadcast_to(r[sensor], w.shape)
        f = f0 + np.cross(a, ri) + np.cross(w, np.cross(w, ri))
        out[:, k] = f[:, axis]
    return out


@dataclass(frozen=True, eq=False)
class RigidBodyMotion:
    """A trajectory with its body-frame angular velocity and acceleration at each sample.

    trajectory : orientation, position and linear acceleration of the body origin.
    omega_rad_s : (N, 3) instantaneous angular velocity at ``trajectory.t``, body frame.
    alpha_rad_s2 : (N, 3) its time derivative, body frame.
    """

    trajectory: Trajectory
    omega_rad_s: Array
    alpha_rad_s2: Array

    def __post_init__(self) -> None:
        n = self.trajectory.n_samples
        for name in ("omega_rad_s", "alpha_rad_s2"):
            value = np.array(getattr(self, name), dtype=np.float64)
            if value.shape != (n, 3) or not np.all(np.isfinite(value)):
                raise ValueError(f"{name} must be a finite ({n}, 3) array, got {value.shape}")
            value.flags.writeable = False
            object.__setattr__(self, name, value)


def _smooth_start(t: Array, ramp_s: float) -> tuple[Array, Array, Array]:
    """Septic smoothstep over ``[0, ramp_s]`` and its first two derivatives, (N, 1) each."""
    s = np.clip(t / ramp_s, 0.0, 1.0)[:, None]
    inside = (t < ramp_s)[:, None]
    w = s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)
    w1 = np.where(inside, 140.0 * s**3 * (1.0 - s) ** 3 / ramp_s, 0.0)
    w2 = np.where(inside, 420.0 * s**2 * (1.0 - s) ** 2 * (1.0 - 2.0 * s) / ramp_s**2, 0.0)
    return w, w1, w2


def _sines(t: Array, freq: Array, phase: Array, amp: Array) -> tuple[Array, Array, Array]:
    """Sum over the last axis of ``amp sin(2π f t + φ)``: value, first, second derivative (N, 3)."""
    k = 2.0 * np.pi * freq
    arg = k[None] * t[:, None, None] + phase[None]
    return (
        np.sum(amp * np.sin(arg), -1),
        np.sum(amp * k * np.cos(arg), -1),
        -np.sum(amp * k**2 * np.sin(arg), -1),
    )


def tremor_motion(
    duration_s: float, rate_hz: float, seed: int, tremor_amplitude_m: float = 30e-6,
    tremor_band_hz: tuple[float, float] = (8.0, 12.0), lever_m: float = 0.1,
    hand_amplitude_deg: float = 5.0, hand_translation_m: float = 0.005,
    hand_bandwidth_hz: float = 0.5, q0: ArrayLike | None = None,
) -> RigidBodyMotion:
    """A handheld instrument: slow hand motion plus physiological tremor (003 II-A, III).

    ZYX Euler angles ``(ψ, θ, φ)`` and the origin's position are each a sum of three slow
    sines (frequencies log-uniform in ``[hand_bandwidth_hz/10, hand_bandwidth_hz]``, peaks
    scaled to ``hand_amplitude_deg`` and ``hand_translation_m``) plus one tremor sine per
    axis (frequency uniform in ``tremor_band_hz``): ``tremor_amplitude_m`` of translation
    and ``tremor_amplitude_m / lever_m`` rad of rotation (the tip, ``lever_m`` ahead,
    moves by tens of µm). Everything fades in over the first second (septic smoothstep),
    so the body starts at rest: ``ω(0) = 0`` as eq. 3 assumes. ``q = q0 ⊗ q_zyx(ψ, θ, φ)``;
    ``ω`` and ``α`` are analytic (ZYX kinematics), as is the linear acceleration.
    """
    seed = check_seed(seed)
    rate_hz = number(rate_hz, "rate_hz", 0.0)
    n = round(number(duration_s, "duration_s", 0.0) * rate_hz) + 1
    if n < 2:
        raise ValueError(f"duration_s * rate_hz must give at least 2 samples, got {n}")
    low, high = (float(f) for f in tremor_band_hz)
    if not 0.0 < low <= high < 0.5 * rate_hz:
        raise ValueError(f"tremor_band_hz must satisfy 0 < low <= high < rate_hz/2, got "
                         f"{tremor_band_hz}")
    tremor_m = number(tremor_amplitude_m, "tremor_amplitude_m", 0.0, or_equal=True)
    lever_m = number(lever_m, "lever_m", 0.0)
    hand_rad = math.radians(number(hand_amplitude_deg, "hand_amplitude_deg", 0.0, True))
    hand_m = number(hand_translation_m, "hand_translation_m", 0.0, or_equal=True)
    band = number(hand_bandwidth_hz, "hand_bandwidth_hz", 0.0)
    t = np.arange(n) / rate_hz
    rng = np.random.default_rng([seed, _TREMOR_TAG])

    def component(peak: float, tremor: float) -> tuple[Array, Array, Array]:
        freq = band * 10.0 ** -rng.uniform(0.0, 1.0, (3, 3))
        phase = rng.uniform(0.0, 2.0 * np.pi, (3, 3))
        amp = rng.uniform(0.5, 1.0, (3, 3))
        v, v1, v2 = _sines(t, freq, phase, amp)
        gain = peak / np.maximum(np.max(np.abs(v), axis=0), 1e-300)
        tf = rng.uniform(low, high, (3, 1))
        tp = rng.uniform(0.0, 2.0 * np.pi, (3, 1))
        u, u1, u2 = _sines(t, tf, tp, np.full((3, 1), tremor))
        v, v1, v2 = v * gain + u, v1 * gain + u1, v2 * gain + u2
        w, w1, w2 = _smooth_start(t, min(1.0, float(t[-1])))
        return w * v, w1 * v + w * v1, w2 * v + 2.0 * w1 * v1 + w * v2

    ang, ang1, ang2 = component(hand_rad, tremor_m / lever_m)
    pos, _, acc = component(hand_m, tremor_m)
    th, ph = ang[:, 1], ang[:, 2]  # ψ does not enter the body rates
    dpsi, dth, dph = ang1.T
    ddpsi, ddth, ddph = ang2.T
    s_th, c_th, s_ph, c_ph = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph)
    # body rates of R = Rz(ψ) Ry(θ) Rx(φ) and their time derivatives
    omega = np.stack(
        [dph - dpsi * s_th, dth * c_ph + dpsi * c_th * s_ph, -dth * s_ph + dpsi * c_th * c_ph], 1
    )
    alpha = np.stack(
        [
            ddph - ddpsi * s_th - dpsi * dth * c_th,
            ddth * c_ph - dth * dph * s_ph + ddpsi * c_th * s_ph
            - dpsi * dth * s_th * s_ph + dpsi * dph * c_th * c_ph,
            -ddth * s_ph - dth * dph * c_ph + ddpsi * c_th * c_ph
            - dpsi * dth * s_th * c_ph - dpsi * dph * c_th * s_ph,
        ],
        1,
    )
    start = qt.identity() if q0 is None else qt.normalize(np.asarray(q0, dtype=np.float64))
    quat = qt.multiply(start, qt.from_euler(ang))
    # the earth-frame path of the origin is the position series itself (any frame)
    meta = {"seed": seed, "duration_s": duration_s, "rate_hz": rate_hz,
            "tremor_amplitude_m": tremor_m, "tremor_band_hz": [low, high], "lever_m": lever_m,
            "hand_amplitude_deg": hand_amplitude_deg, "hand_translation_m": hand_m,
            "hand_bandwidth_hz": band, "q0": start.tolist()}
    traj = Trajectory(t, quat, pos, acc, "tremor_motion", meta)
    return RigidBodyMotion(traj, omega, alpha)


def motion_from_trajectory(trajectory: Trajectory) -> RigidBodyMotion:
    """ω and α of any trajectory by central differences of its orientation (O(T²) error).

    ``ω_k = to_rotvec(q_{k-1}* ⊗ q_{k+1}) / (t_{k+1} - t_{k-1})`` (one-sided at the ends),
    ``α = dω/dt`` by ``numpy.gradient``. For analytic ω, α use :func:`tremor_motion`.
    """
    q, t = trajectory.quat, trajectory.t
    if trajectory.n_samples < 3:
        raise ValueError("motion_from_trajectory needs at least 3 samples")
    omega = np.empty((trajectory.n_samples, 3))
    omega[1:-1] = qt.to_rotvec(qt.multiply(qt.conjugate(q[:-2]), q[2:])) / (t[2:] - t[:-2])[
        :, None
    ]
    omega[0] = qt.to_rotvec(qt.multiply(qt.conjugate(q[0]), q[1])) / (t[1] - t[0])
    omega[-1] = qt.to_rotvec(qt.multiply(qt.conjugate(q[-2]), q[-1])) / (t[-1] - t[-2])
    return RigidBodyMotion(trajectory, omega, np.gradient(omega, t, axis=0))


@dataclass(frozen=True, eq=False)
class AllAccelerometerRecording:
    """What the all-accelerometer IMU measured, with the truth.

    t (N,) s; readings_m_s2 (N, 6) in :data:`CHANNELS` order; mag (N, 3) µT, body frame;
    quat_true (N, 4) body to ``frame``; omega_rad_s, alpha_rad_s2 (N, 3) true body rates;
    array the sensor layout; meta the simulation's parameters.
    """

    t: Array
    readings_m_s2: Array
    mag: Array
    quat_true: Array
    omega_rad_s: Array
    alpha_rad_s2: Array
    frame: str
    array: AccelerometerArray
    meta: dict[str, Any] = field(default_factory=dict)


def simulate_all_accelerometer(
    motion: RigidBodyMotion, array: AccelerometerArray | None = None, frame: str = "ENU",
    dip_deg: float = DEFAULT_DIP_DEG, field_ut: float = DEFAULT_FIELD_UT,
    acc_noise_m_s2_sqrt_hz: float = 0.0, acc_bias_walk_m_s2_sqrt_s: float = 0.0,
    mag_errors: SensorErrors | None = None, gravity_m_s2: float = STANDARD_GRAVITY_M_S2,
    seed: int = 0,
) -> AllAccelerometerRecording:
    """Readings of the six accelerometer channels and the magnetometer for ``motion``.

    Each channel gets white noise of density ``acc_noise_m_s2_sqrt_hz`` (std
    ``density·√rate`` per sample; 003 III-B found velocity random walk dominant) and a bias
    random walk of density ``acc_bias_walk_m_s2_sqrt_s`` (acceleration random walk),
    independent between channels; ``mag_errors`` (default none) is applied to the field.
    Draw order from ``default_rng(seed)``: white (N, 6), walk (N, 6), then the magnetometer's
    two (N, 3) blocks. ``array`` defaults to :meth:`AccelerometerArray.handheld_instrument`.
    """
    frame = check_frame(frame)
    built_for = motion.trajectory.meta.get("frame")
    if built_for is not None and check_frame(built_for) != frame:
        raise ValueError(f"the motion was built for {built_for!r}, not {frame!r}")
    array = AccelerometerArray.handheld_instrument() if array is None else array
    noise = number(acc_noise_m_s2_sqrt_hz, "acc_noise_m_s2_sqrt_hz", 0.0, or_equal=True)
    walk = number(acc_bias_walk_m_s2_sqrt_s, "acc_bias_walk_m_s2_sqrt_s", 0.0, or_equal=True)
    seed = check_seed(seed)
    traj = motion.trajectory
    rate = traj.rate_hz
    f0 = qt.rotate_inverse(traj.quat, traj.acc_lin_m_s2 + gravity_reference(frame, gravity_m_s2))
    readings = specific_forces(array, motion.omega_rad_s, motion.alpha_rad_s2, f0)
    rng = np.random.default_rng(seed)
    white = rng.standard_normal(readings.shape)
    steps = rng.standard_normal(readings.shape)
    steps[0] = 0.0
    readings = readings + white * (noise * math.sqrt(rate))
    readings += np.cumsum(steps, axis=0) * (walk / math.sqrt(rate))
    errors = SensorErrors.none() if mag_errors is None else mag_errors
    field_b = qt.rotate_inverse(traj.quat, mag_reference(frame, dip_deg, field_ut))
    mag = errors.apply(field_b, rate, rng)
    meta = {"source": "margtrack.sim.all_accelerometer", "seed": seed, "frame": frame,
            "dip_deg": float(dip_deg), "field_ut": float(field_ut),
            "acc_noise_m_s2_sqrt_hz": noise, "acc_bias_walk_m_s2_sqrt_s": walk,
            "positions_m": [list(p) for p in array.positions_m],
            "trajectory": {"name": traj.name, **traj.meta}}
    return AllAccelerometerRecording(
        t=traj.t.copy(), readings_m_s2=readings, mag=mag, quat_true=traj.quat.copy(),
        omega_rad_s=np.array(motion.omega_rad_s), alpha_rad_s2=np.array(motion.alpha_rad_s2),
        frame=frame, array=array, meta=meta,
    )
