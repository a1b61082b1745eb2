"""Magnetic disturbances for simulation, as additive earth-frame fields over time.

Every disturbance has ``earth_field_ut(t_s, reference_ut, frame) -> (N, 3)``: the field,
in µT and in the earth frame ``frame``, that :func:`margtrack.sim.simulate` adds to the
undisturbed reference ``reference_ut`` (3,) before rotating into the body frame. Earth
frame means the disturbance is fixed in the room, like the ferrous objects of 002 III-C
and the magnet of 000's disturbance test, not carried by the sensor. Linear-acceleration
disturbances are trajectories (``random_motion(translation_m=...)``, ``limb_swing``).
A field carried by the sensor instead (:class:`BodyMagDisturbance`, a magnet attached to
it) is added in the body frame: :mod:`margtrack.sim.dipole`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as qt
from margtrack.frames import up
from margtrack.sim._validate import number as _number
from margtrack.sim._validate import unit_axis as _unit_axis

Array = NDArray[np.float64]

__all__ = [
    "BodyMagDisturbance",
    "MagDisturbance",
    "MagnetPass",
    "RotatingField",
    "VerticalTilt",
    "magnet_pass",
    "rotating_field",
    "vertical_tilt",
]


class MagDisturbance(Protocol):
    """Anything that gives an additive earth-frame magnetic field over time."""

    def earth_field_ut(self, t_s: Array, reference_ut: Array, frame: str) -> Array:
        """Additive field (N, 3), µT, earth frame, at times ``t_s`` (N,) s."""
        ...


@runtime_checkable
class BodyMagDisturbance(Protocol):
    """Anything that gives an additive body-frame magnetic field over time: a field carried
    by the sensor, such as a magnet attached to it (:mod:`margtrack.sim.dipole`)."""

    def body_field_ut(self, t_s: Array) -> Array:
        """Additive field (N, 3), µT, body frame, at times ``t_s`` (N,) s."""
        ...


def _unit(value: ArrayLike, name: str) -> tuple[float, float, float]:
    x, y, z = _unit_axis(value, name)
    return (float(x), float(y), float(z))


def _rise(x: Array) -> Array:
    """Raised-cosine step: 0 for x <= 0, ``(1 - cos(π x)) / 2`` on (0, 1), 1 for x >= 1."""
    return 0.5 * (1.0 - np.cos(np.pi * np.clip(x, 0.0, 1.0)))


@dataclass(frozen=True)
class MagnetPass:
    """A magnet passing the sensor: a smooth bump of field along a fixed earth direction.

    ``field(t) = peak_ut · h(t) · direction`` with the raised-cosine (Hann) bump
    ``h = (1 + cos(2π (t - t_center_s) / duration_s)) / 2`` for ``|t - t_center_s| <
    duration_s / 2`` and exactly 0 outside, so the field before and after is untouched
    (000's speaker-magnet test: orientation before vs after the exposure).
    """

    t_center_s: float
    duration_s: float
    peak_ut: float
    direction: tuple[float, float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "t_center_s", _number(self.t_center_s, "t_center_s"))
        object.__setattr__(self, "duration_s", _number(self.duration_s, "duration_s", 0.0))
        object.__setattr__(self, "peak_ut", _number(self.peak_ut, "peak_ut"))
        object.__setattr__(self, "direction", _unit(self.direction, "direction"))

    def profile(self, t_s: ArrayLike) -> Array:
        """The bump ``h(t)`` (N,) in [0, 1]."""
        x = (np.asarray(t_s, dtype=np.float64) - self.t_center_s) / self.duration_s
        return np.where(np.abs(x) < 0.5, 0.5 * (1.0 + np.cos(2.0 * np.pi * x)), 0.0)

    def earth_field_ut(self, t_s: Array, reference_ut: Array, frame: str) -> Array:
        """Additive field (N, 3), µT, earth frame; ``reference_ut`` and ``frame`` unused."""
        return self.peak_ut * self.profile(t_s)[:, None] * np.asarray(self.direction)


@dataclass(frozen=True)
class RotatingField:
    """The field direction turning about an earth axis, as a moving ferrous object does (002 III-C).

    From ``start_s`` the reference turns about ``axis`` at ``rate_deg_s`` (> 0) until it has
    turned ``angle_deg`` (signed; its sign is the sense about ``axis``), then stays there:
    ``φ(t) = sign(angle) · clip(rate · (t - start_s), 0, |angle|)`` and the disturbed field
    is ``rotate(exp(axis φ), reference)``, returned as the additive difference. About the
    vertical (``axis=(0, 0, 1)``, the default, up in ENU and down in NED) only the heading
    of the field changes, keeping its dip and norm: 002's test that FQA's pitch and roll
    are immune to magnetic variation.
    """

    start_s: float
    rate_deg_s: float
    angle_deg: float = 360.0
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "start_s", _number(self.start_s, "start_s"))
        object.__setattr__(self, "rate_deg_s", _number(self.rate_deg_s, "rate_deg_s", 0.0))
        angle = _number(self.angle_deg, "angle_deg")
        if angle == 0.0:
            raise ValueError("angle_deg must be non-zero")
        object.__setattr__(self, "angle_deg", angle)
        object.__setattr__(self, "axis", _unit(self.axis, "axis"))

    def angle_rad(self, t_s: ArrayLike) -> Array:
        """Turn ``φ(t)`` (N,), rad, of the field about ``axis``."""
        elapsed = np.asarray(t_s, dtype=np.float64) - self.start_s
        turned = np.clip(self.rate_deg_s * elapsed, 0.0, abs(self.angle_deg))
        return np.radians(math.copysign(1.0, self.angle_deg) * turned)

    def earth_field_ut(self, t_s: Array, reference_ut: Array, frame: str) -> Array:
        """``rotate(exp(axis φ(t)), reference) - reference`` (N, 3), µT, earth frame."""
        turn = qt.from_rotvec(np.asarray(self.axis) * self.angle_rad(t_s)[:, None])
        reference = np.asarray(reference_ut, dtype=np.float64)
        return qt.rotate(turn, reference) - reference


@dataclass(frozen=True)
class VerticalTilt:
    """A vertical field added to the reference, tilting it in its vertical plane (004's check).

    ``field(t) = down_ut · s(t) · down(frame)``, with ``s`` a raised-cosine step from 0 at
    ``start_s`` to 1 at ``start_s + ramp_s`` (``ramp_s = 0``: a jump). The horizontal part
    of the field is untouched, so a filter using only the magnetometer's forward
    (horizontal) component, like 004's vector rejection, keeps its heading.
    """

    start_s: float
    down_ut: float
    ramp_s: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "start_s", _number(self.start_s, "start_s"))
        object.__setattr__(self, "down_ut", _number(self.down_ut, "down_ut"))
        object.__setattr__(self, "ramp_s", _number(self.ramp_s, "ramp_s", 0.0, or_equal=True))

    def profile(self, t_s: ArrayLike) -> Array:
        """The step ``s(t)`` (N,) in [0, 1]."""
        elapsed = np.asarray(t_s, dtype=np.float64) - self.start_s
        if self.ramp_s == 0.0:
            return (elapsed >= 0.0).astype(np.float64)
        return _rise(elapsed / self.ramp_s)

    def earth_field_ut(self, t_s: Array, reference_ut: Array, frame: str) -> Array:
        """Additive field (N, 3), µT, earth frame ``frame`` (positive ``down_ut`` points down)."""
        return -self.down_ut * self.profile(t_s)[:, None] * up(frame)


def magnet_pass(
    t_center_s: float, duration_s: float, peak_ut: float, direction: ArrayLike
) -> MagnetPass:
    """A magnet passing at ``t_center_s`` along earth-frame ``direction``: :class:`MagnetPass`."""
    return MagnetPass(t_center_s, duration_s, peak_ut, tuple(np.ravel(direction).astype(float)))


def rotating_field(
    start_s: float,
    rate_deg_s: float,
    angle_deg: float = 360.0,
    axis: ArrayLike = (0.0, 0.0, 1.0),
) -> RotatingField:
    """Field turning ``angle_deg`` at ``rate_deg_s`` about an earth axis: :class:`RotatingField`."""
    return RotatingField(start_s, rate_deg_s, angle_deg, tuple(np.ravel(axis).astype(float)))


def vertical_tilt(start_s: float, down_ut: float, ramp_s: float = 1.0) -> VerticalTilt:
    """A vertical field ``down_ut`` µT (positive down) from ``start_s``: :class:`VerticalTilt`."""
    return VerticalTilt(start_s, down_ut, ramp_s)
