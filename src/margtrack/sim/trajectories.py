"""Ground-truth motions: orientation, position and linear acceleration of a sensor over time.

A :class:`Trajectory` is pure kinematics in an earth frame; :func:`margtrack.sim.simulate`
turns it into sensor readings. ``quat`` is body-to-earth (``v_earth = rotate(q, v_body)``),
axes given to the generators are earth-frame 3-vectors, angles at this edge are in degrees.

Gyro convention (:func:`body_rate`): sample ``i`` covers the interval ``(t[i-1], t[i]]``,
``ω_i = to_rotvec(q[i-1]* ⊗ q[i]) / (t[i] - t[i-1])`` and ``ω_0 = 0``, so integrating with
``quaternion.integrate(q, ω_i, dt_i)`` for ``i >= 1`` reproduces ``quat`` exactly.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as qt
from margtrack.frames import check_frame, up
from margtrack.sim._validate import check_seed as _check_seed
from margtrack.sim._validate import number as _number
from margtrack.sim._validate import unit_axis as _unit_axis

Array = NDArray[np.float64]

__all__ = [
    "Hold", "Rotate", "Trajectory", "body_rate", "constant_rotation", "limb_swing",
    "random_motion", "rotation_sequence", "static",
]

# Entropy tag mixed with the user's seed so random_motion's stream differs from the
# noise stream simulate() draws from default_rng(seed) with the same seed.
_RANDOM_MOTION_TAG = 0x52414E44
_N_SINES = 6  # sinusoids per axis in random_motion


def _start(q0: ArrayLike | None) -> Array:
    if q0 is None:
        return qt.identity()
    q = np.asarray(q0, dtype=np.float64)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1.0) > 1e-6:
        raise ValueError(f"q0 must be a unit quaternion [w, x, y, z] of shape (4,), got {q0!r}")
    return q / np.linalg.norm(q)


def _time(duration_s: float, rate_hz: float) -> Array:
    """Timestamps ``i / rate_hz``, ``i = 0 .. round(duration_s * rate_hz)``: t[-1] ≈ duration_s."""
    duration_s = _number(duration_s, "duration_s", 0.0)
    rate_hz = _number(rate_hz, "rate_hz", 0.0)
    n = round(duration_s * rate_hz) + 1
    if n < 2:
        raise ValueError(f"duration_s * rate_hz must give at least 2 samples, got {n}")
    return np.arange(n) / rate_hz


def _check_step(peak_rate_rad_s: float, rate_hz: float, name: str) -> None:
    """Refuse motions that turn 180 deg or more between samples (the rotation would alias)."""
    if peak_rate_rad_s / rate_hz >= np.pi:
        turn_deg = np.degrees(peak_rate_rad_s / rate_hz)
        raise ValueError(f"{name} gives {turn_deg:.1f} deg/sample (< 180 needed): raise rate_hz")


def _column(values: ArrayLike, name: str, width: int, n: int) -> Array:
    a = np.array(values, dtype=np.float64)
    if a.shape != (n, width):
        raise ValueError(f"{name} must have shape ({n}, {width}), got {a.shape}")
    bad = np.argwhere(~np.isfinite(a))
    if bad.size:
        raise ValueError(f"{name} has a non-finite value at sample {int(bad[0, 0])}")
    return a


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Ground truth of one sensor's motion, sampled at times ``t``.

    Attributes
    ----------
    t : (N,) s, strictly increasing, N >= 2.
    quat : (N, 4) body-to-earth orientation ``[w, x, y, z]``; normalised and made sign
        continuous (consecutive dot products > 0) at construction.
    pos_m : (N, 3) m, earth-frame position of the sensor (zeros for pure rotation).
    acc_lin_m_s2 : (N, 3) m/s², earth-frame linear acceleration, the second derivative of
        ``pos_m``. Every generator here computes it analytically (no finite differences).
    name : the generator's name.
    meta : the generator's parameters (copied into a simulated Recording's meta). A
        ``"frame"`` entry says the motion was built for that earth frame (``limb_swing``).

    Arrays are stored as read-only float64 copies; bad shapes, non-finite values,
    non-increasing timestamps or non-unit quaternions raise ``ValueError``.
    """

    t: Array
    quat: Array
    pos_m: Array
    acc_lin_m_s2: Array
    name: str = ""
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = np.array(self.t, dtype=np.float64)
        if t.ndim != 1 or t.shape[0] < 2 or not np.all(np.isfinite(t)):
            raise ValueError(f"t must be a finite (N,) array with N >= 2, got shape {t.shape}")
        bad = np.flatnonzero(np.diff(t) <= 0.0)
        if bad.size:
            raise ValueError(f"t must be strictly increasing; t[{bad[0] + 1}] <= t[{bad[0]}]")
        n = t.shape[0]
        q = _column(self.quat, "quat", 4, n)
        norms = np.linalg.norm(q, axis=1)
        off = np.flatnonzero(np.abs(norms - 1.0) > 1e-6)
        if off.size:
            raise ValueError(f"quat is not unit at sample {off[0]} (norm {norms[off[0]]:.9f})")
        pos = _column(self.pos_m, "pos_m", 3, n)
        acc = _column(self.acc_lin_m_s2, "acc_lin_m_s2", 3, n)
        quat = qt.continuous(q / norms[:, None])
        for key, value in {"t": t, "quat": quat, "pos_m": pos, "acc_lin_m_s2": acc}.items():
            value.flags.writeable = False
            object.__setattr__(self, key, value)
        object.__setattr__(self, "meta", dict(self.meta))

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.shape[0])

    @property
    def rate_hz(self) -> float:
        """Median sample rate, Hz."""
        return float(1.0 / np.median(np.diff(self.t)))


def body_rate(traj: Trajectory) -> Array:
    """True gyroscope signal (N, 3), rad/s, body frame, consistent with ``quaternion.integrate``.

    Sample ``i`` is the constant body rate that carries ``quat[i-1]`` to ``quat[i]`` over
    ``(t[i-1], t[i]]``: ``ω_i = to_rotvec(q[i-1]* ⊗ q[i]) / dt_i``, and ``ω_0 = 0``. Hence
    ``q[i] = integrate(q[i-1], ω_i, dt_i)`` to rounding for every ``i >= 1``. Identical
    consecutive quaternions give exactly 0 (the product ``q* ⊗ q`` alone leaves ~1e-17).
    """
    q = traj.quat
    omega = np.zeros((traj.n_samples, 3))
    delta = qt.multiply(qt.conjugate(q[:-1]), q[1:])
    omega[1:] = qt.to_rotvec(delta) / np.diff(traj.t)[:, None]
    omega[1:][np.all(q[1:] == q[:-1], axis=1)] = 0.0
    return omega


def static(duration_s: float, rate_hz: float, q0: ArrayLike | None = None) -> Trajectory:
    """A sensor at rest at orientation ``q0`` (identity: body axes on the earth axes).

    000's static-stability experiment. ``N = round(duration_s * rate_hz) + 1`` samples.
    """
    t = _time(duration_s, rate_hz)
    q = _start(q0)
    zeros = np.zeros((t.shape[0], 3))
    meta = {"duration_s": duration_s, "rate_hz": rate_hz, "q0": q.tolist()}
    return Trajectory(t, np.tile(q, (t.shape[0], 1)), zeros, zeros, "static", meta)


def constant_rotation(
    axis: ArrayLike, rate_deg_s: float, duration_s: float, rate_hz: float,
    q0: ArrayLike | None = None,
) -> Trajectory:
    """Rotation at a constant rate about a fixed earth-frame axis, like a tilt table (000, 002).

    ``q(t) = from_rotvec(axis · rate · t) ⊗ q0``: after ``duration_s`` the sensor has turned by
    ``rate_deg_s * duration_s`` deg (negative rates turn the other way). The sensor sits
    on the axis, so ``pos_m`` and ``acc_lin_m_s2`` are zero.
    """
    unit = _unit_axis(axis)
    rate_rad_s = np.radians(_number(rate_deg_s, "rate_deg_s"))
    t = _time(duration_s, rate_hz)
    _check_step(abs(rate_rad_s), rate_hz, "rate_deg_s")
    q = _start(q0)
    quat = qt.multiply(qt.from_rotvec(unit * (rate_rad_s * t)[:, None]), q)
    zeros = np.zeros((t.shape[0], 3))
    meta = {"axis": unit.tolist(), "rate_deg_s": rate_deg_s, "duration_s": duration_s,
            "rate_hz": rate_hz, "q0": q.tolist()}
    return Trajectory(t, quat, zeros, zeros, "constant_rotation", meta)


@dataclass(frozen=True)
class Rotate:
    """A step of :func:`rotation_sequence`: turn ``angle_deg`` at ``rate_deg_s`` about ``axis``.

    ``axis`` is a non-zero earth-frame 3-vector (stored unit length), ``angle_deg`` signed and
    non-zero, ``rate_deg_s`` > 0 the constant speed: the step lasts ``|angle_deg| / rate_deg_s``.
    """

    axis: tuple[float, float, float]
    angle_deg: float
    rate_deg_s: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "axis", tuple(float(a) for a in _unit_axis(self.axis)))
        object.__setattr__(self, "angle_deg", _number(self.angle_deg, "angle_deg"))
        object.__setattr__(self, "rate_deg_s", _number(self.rate_deg_s, "rate_deg_s", 0.0))
        if self.angle_deg == 0.0:
            raise ValueError("angle_deg must be non-zero (use Hold to stay still)")

    @property
    def duration_s(self) -> float:
        """Time the step takes, s."""
        return abs(self.angle_deg) / self.rate_deg_s


@dataclass(frozen=True)
class Hold:
    """One step of :func:`rotation_sequence`: stay still for ``duration_s`` > 0 s."""

    duration_s: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "duration_s", _number(self.duration_s, "duration_s", 0.0))


def rotation_sequence(
    steps: Sequence[Rotate | Hold], rate_hz: float, q0: ArrayLike | None = None
) -> Trajectory:
    """Constant-rate rotations and holds one after another, starting at ``q0``.

    000's dynamic test ("45 degree roll excursions at 10 degrees/second", about 15 s still
    after each move) is ``[Rotate((1, 0, 0), 45, 10), Hold(15), Rotate((1, 0, 0), -45, 10),
    Hold(15)]``. Within a step of angle ``A`` starting at ``T_k`` from orientation ``Q_k``
    the orientation is ``from_rotvec(axis · A (t - T_k) / duration) ⊗ Q_k``. A hold repeats
    ``Q_k`` exactly, so its gyro samples are exactly zero (except the first, whose interval
    still holds the end of a rotation when the boundary falls between samples). The sensor
    sits on every axis: no translation.
    """
    steps = tuple(steps)
    if not steps or not all(isinstance(s, (Rotate, Hold)) for s in steps):
        raise ValueError("steps must be a non-empty sequence of Rotate and Hold")
    durations = np.array([s.duration_s for s in steps])
    starts = np.concatenate([[0.0], np.cumsum(durations)])
    t = _time(starts[-1], rate_hz)
    peak = max((np.radians(s.rate_deg_s) for s in steps if isinstance(s, Rotate)), default=0.0)
    _check_step(peak, rate_hz, "rate_deg_s")
    segment = np.clip(np.searchsorted(starts[1:], t, side="right"), 0, len(steps) - 1)
    quat = np.empty((t.shape[0], 4))
    q_k = q_start = _start(q0)
    for k, step in enumerate(steps):
        mask = segment == k
        if isinstance(step, Hold):
            quat[mask] = q_k
            continue
        fraction = np.clip((t[mask] - starts[k]) / durations[k], 0.0, 1.0)
        angle = np.radians(step.angle_deg) * np.append(fraction, 1.0)  # last: the step's end
        turn = qt.from_rotvec(np.asarray(step.axis) * angle[:, None])
        q = qt.multiply(turn, q_k)
        quat[mask] = q[:-1]
        q_k = q[-1]
    zeros = np.zeros((t.shape[0], 3))
    meta = {"steps": [repr(s) for s in steps], "rate_hz": rate_hz, "q0": q_start.tolist()}
    return Trajectory(t, quat, zeros, zeros, "rotation_sequence", meta)


def _sines(rng: np.random.Generator, bandwidth_hz: float) -> tuple[Array, Array, Array]:
    """Random log-uniform frequencies (Hz) in [bandwidth/50, bandwidth], phases, amplitudes.

    Each (3, K). Log-uniform frequencies give slow wide excursions as well as fast ones.
    """
    freq = bandwidth_hz * 50.0 ** -rng.uniform(0.0, 1.0, (3, _N_SINES))
    phase = rng.uniform(0.0, 2.0 * np.pi, (3, _N_SINES))
    amplitude = rng.uniform(0.5, 1.0, (3, _N_SINES))
    return freq, phase, amplitude


def _cumulative_product(d: Array) -> Array:
    """``P_i = d_0 ⊗ d_1 ⊗ ... ⊗ d_i`` for (N, 4) by a log2(N)-pass vectorised prefix scan."""
    p = d.copy()
    shift = 1
    while shift < p.shape[0]:
        p[shift:] = qt.multiply(p[:-shift], p[shift:])
        shift *= 2
    return qt.normalize(p)


def random_motion(
    duration_s: float, rate_hz: float, seed: int, max_rate_deg_s: float = 200.0,
    bandwidth_hz: float = 2.0, translation_m: float = 0.0, q0: ArrayLike | None = None,
) -> Trajectory:
    """Smooth band-limited random rotation, optionally translation; deterministic in ``seed``.

    The body rate is ``ω_j(t) = Σ_k a_jk cos(2π f_jk t + φ_jk)`` per axis with 6 random
    log-uniform frequencies in ``[bandwidth_hz/50, bandwidth_hz]``, scaled so the largest
    ``|ω|`` over the interval midpoints is exactly ``max_rate_deg_s``; over a minute it
    visits all headings and inclinations. Orientation is its exact integral with ω held
    at the midpoint value over each interval, ``q_i = integrate(q_{i-1}, ω(t_i - dt/2), dt)``,
    so :func:`body_rate` returns those midpoint rates. With ``translation_m`` > 0 each
    position axis is a sum of 6 sines in the same band, faded in over the first second by a
    septic smoothstep (so position, velocity and acceleration are zero at t = 0), scaled to
    a peak ``|pos|`` of ``translation_m``; ``acc_lin_m_s2`` is its analytic second derivative.
    Draws come from ``numpy.random.default_rng([seed, tag])`` in a fixed order (rotation,
    then translation), a stream independent of :func:`simulate`'s noise for the same seed.
    """
    seed = _check_seed(seed)
    t = _time(duration_s, rate_hz)
    max_rate = np.radians(_number(max_rate_deg_s, "max_rate_deg_s", 0.0))
    if not 0.0 < bandwidth_hz < 0.5 * rate_hz:
        raise ValueError(f"bandwidth_hz must be in (0, rate_hz / 2), got {bandwidth_hz}")
    _number(translation_m, "translation_m", 0.0, or_equal=True)
    _check_step(max_rate, rate_hz, "max_rate_deg_s")
    rng = np.random.default_rng([seed, _RANDOM_MOTION_TAG])
    freq, phase, amplitude = _sines(rng, bandwidth_hz)
    t_mid = 0.5 * (t[1:] + t[:-1])
    arg = 2.0 * np.pi * freq[None] * t_mid[:, None, None] + phase[None]  # (N-1, 3, K)
    omega = np.sum(amplitude * np.cos(arg), axis=-1)
    omega *= max_rate / np.max(np.linalg.norm(omega, axis=1))
    step = qt.from_rotvec(omega * np.diff(t)[:, None])
    q = _start(q0)
    quat = _cumulative_product(np.concatenate([q[None], step]))

    freq, phase, amplitude = _sines(rng, bandwidth_hz)
    arg = 2.0 * np.pi * freq[None] * t[:, None, None] + phase[None]  # (N, 3, K)
    omega_k = 2.0 * np.pi * freq
    raw = np.sum(amplitude * (np.sin(arg) - np.sin(phase)), axis=-1)
    raw_vel = np.sum(amplitude * omega_k * np.cos(arg), axis=-1)
    raw_acc = -np.sum(amplitude * omega_k**2 * np.sin(arg), axis=-1)
    # fade the translation in over the first second with a septic smoothstep (value and
    # first three derivatives zero at both ends, so the acceleration stays smooth), so the
    # sensor starts at rest and the first accelerometer sample reads pure gravity:
    # estimators initialised from it start exact
    ramp_s = min(1.0, t[-1])
    s = np.clip(t / ramp_s, 0.0, 1.0)[:, None]
    inside = (t < ramp_s)[:, None]
    w = s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)
    w_dot = np.where(inside, 140.0 * s**3 * (1.0 - s) ** 3 / ramp_s, 0.0)
    w_ddot = np.where(inside, 420.0 * s**2 * (1.0 - s) ** 2 * (1.0 - 2.0 * s) / ramp_s**2, 0.0)
    pos = w * raw
    acc = w_ddot * raw + 2.0 * w_dot * raw_vel + w * raw_acc
    peak = np.max(np.abs(pos), axis=0)
    gain = translation_m / np.where(peak > 0, peak, 1.0)
    meta = {"seed": seed, "duration_s": duration_s, "rate_hz": rate_hz,
            "max_rate_deg_s": max_rate_deg_s, "bandwidth_hz": bandwidth_hz,
            "translation_m": translation_m, "q0": q.tolist()}
    return Trajectory(t, quat, pos * gain, acc * gain, "random_motion", meta)


def limb_swing(
    duration_s: float, rate_hz: float, amplitude_deg: float = 30.0, frequency_hz: float = 1.0,
    length_m: float = 0.4, axis: ArrayLike = (1.0, 0.0, 0.0), q0: ArrayLike | None = None,
    frame: str = "ENU",
) -> Trajectory:
    """A limb swinging like a pendulum: angle ``θ = A sin(2π f t)`` about a horizontal axis.

    The pivot is the earth-frame origin; the sensor rides the limb ``length_m`` below it
    (``pos(0) = -length_m · up(frame)``: give the ``frame`` you will simulate in) and turns
    with it: with ``s = from_rotvec(n θ)``, ``q = s ⊗ q0`` and ``pos = rotate(s, pos(0))``.
    As ``pos ⊥ n``, the analytic linear acceleration is tangential plus centripetal,
    ``acc = θ̈ (n × pos) - θ̇² pos`` with ``θ̇ = 2πf A cos``, ``θ̈ = -(2πf)² A sin``.
    ``axis`` (n) must be horizontal: zero z component, in NED and ENU alike.
    """
    frame = check_frame(frame)
    unit = _unit_axis(axis)
    if abs(unit[2]) > 1e-12:
        raise ValueError(f"axis must be horizontal (zero z component), got {axis!r}")
    t = _time(duration_s, rate_hz)
    amplitude = np.radians(_number(amplitude_deg, "amplitude_deg"))
    if not 0.0 <= amplitude < np.pi:
        raise ValueError(f"amplitude_deg must be in [0, 180), got {amplitude_deg}")
    omega_swing = 2.0 * np.pi * _number(frequency_hz, "frequency_hz", 0.0)
    _check_step(amplitude * omega_swing, rate_hz, "amplitude_deg * 2π * frequency_hz")
    length = _number(length_m, "length_m", 0.0)
    phase = omega_swing * t
    theta = amplitude * np.sin(phase)
    theta_dot = amplitude * omega_swing * np.cos(phase)
    theta_ddot = -amplitude * omega_swing**2 * np.sin(phase)
    swing = qt.from_rotvec(unit * theta[:, None])
    pos = qt.rotate(swing, -length * up(frame))
    acc = theta_ddot[:, None] * np.cross(unit, pos) - (theta_dot**2)[:, None] * pos
    q = _start(q0)
    quat = qt.multiply(swing, q)
    meta = {"duration_s": duration_s, "rate_hz": rate_hz, "amplitude_deg": amplitude_deg,
            "frequency_hz": frequency_hz, "length_m": length_m, "axis": unit.tolist(),
            "q0": q.tolist(), "frame": frame}
    return Trajectory(t, quat, pos, acc, "limb_swing", meta)
