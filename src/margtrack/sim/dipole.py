"""A magnet carried by the sensor: a point dipole fixed in the body frame.

A magnet attached to the sensor board moves with it, so in the body frame its field is a
constant offset added to every magnetometer sample (a hard-iron offset), unlike the
earth-frame disturbances of :mod:`margtrack.sim.disturbances`, which are fixed in the room.
The field of a point dipole of moment ``m`` (A·m²) seen at the sensor, the dipole being at
``r`` (m) from it in the body frame, is the textbook one

    b = (μ0 / 4π) · (3 (m·r̂) r̂ − m) / |r|³        (T; ×1e6 for µT)

(on the dipole's axis ``2 (μ0/4π) |m| / r³`` along ``m``; in its equatorial plane
``(μ0/4π) |m| / r³`` against ``m``). The field is the same whether the sensor is at ``r``
from the dipole or the dipole at ``r`` from the sensor (``b`` is even in ``r``).

A small neodymium magnet has a moment of about 0.1-1 A·m²; 0.1 A·m² gives 20 µT on axis
at 10 cm and 20 mT at 1 cm. The magnetometer's range is not modelled: a real one clips
near the magnet, and the clipped samples are what the input policy then flags.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.sim._validate import number as _number
from margtrack.sim._validate import unit_axis as _unit_axis

Array = NDArray[np.float64]

__all__ = ["MU0_OVER_4PI", "AttachedDipole", "attached_dipole", "dipole_field_ut"]

#: μ0 / 4π, T·m/A (SI, the pre-2019 exact value; the 2019 one differs by 1e-10)
MU0_OVER_4PI = 1e-7


def _vector(value: ArrayLike, name: str) -> tuple[float, float, float]:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    return (float(v[0]), float(v[1]), float(v[2]))


def dipole_field_ut(moment_am2: ArrayLike, position_m: ArrayLike) -> Array:
    """Field (3,), µT, of a point dipole ``moment_am2`` (3,), A·m², at offset ``position_m``.

    ``position_m`` (3,), m, is the vector between the dipole and the point where the field
    is seen (either sense: the field is even in it), in the frame ``moment_am2`` is given
    in. Raises ``ValueError`` for a zero offset (the field of a point dipole is infinite
    there).
    """
    m = np.asarray(_vector(moment_am2, "moment_am2"))
    r = np.asarray(_vector(position_m, "position_m"))
    dist = float(np.linalg.norm(r))
    if dist == 0.0:
        raise ValueError("position_m must not be zero: the dipole cannot sit on the sensor")
    r_hat = r / dist
    tesla = MU0_OVER_4PI * (3.0 * np.dot(m, r_hat) * r_hat - m) / dist**3
    return tesla * 1e6


@dataclass(frozen=True)
class AttachedDipole:
    """A magnet fixed to the sensor: a constant body-frame field, optionally from ``start_s``.

    moment_am2 : the dipole moment (3,), A·m², in the body frame.
    position_m : where the magnet is (3,), m, relative to the magnetometer, body frame.
    start_s : time (s) the magnet appears (a step: attached at that instant); None: always.

    :func:`margtrack.sim.simulate` adds :meth:`body_field_ut` to the magnetometer's
    body-frame signal after rotating the earth's field into the body frame, so the offset
    turns with the sensor.
    """

    moment_am2: tuple[float, float, float]
    position_m: tuple[float, float, float]
    start_s: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "moment_am2", _vector(self.moment_am2, "moment_am2"))
        object.__setattr__(self, "position_m", _vector(self.position_m, "position_m"))
        if self.start_s is not None:
            object.__setattr__(self, "start_s", _number(self.start_s, "start_s"))
        dipole_field_ut(self.moment_am2, self.position_m)  # a zero offset fails here

    @property
    def offset_ut(self) -> Array:
        """The body-frame field (3,), µT, while the magnet is on."""
        return dipole_field_ut(self.moment_am2, self.position_m)

    def body_field_ut(self, t_s: Array) -> Array:
        """Additive field (N, 3), µT, body frame, at times ``t_s`` (N,) s."""
        t = np.asarray(t_s, dtype=np.float64)
        on = np.ones(t.shape[0]) if self.start_s is None else (t >= self.start_s).astype(float)
        return on[:, None] * self.offset_ut


def attached_dipole(
    distance_m: float,
    moment_am2: float = 0.1,
    direction: ArrayLike = (1.0, 0.0, 0.0),
    moment_direction: ArrayLike | None = None,
    start_s: float | None = None,
) -> AttachedDipole:
    """A magnet ``distance_m`` from the sensor along body ``direction``: :class:`AttachedDipole`.

    ``moment_am2`` is the moment's magnitude, A·m²; ``moment_direction`` its body-frame
    direction (None: along ``direction``, the magnet's axis pointing at the sensor, which
    gives the on-axis field ``2 (μ0/4π) m / r³``).
    """
    distance = _number(distance_m, "distance_m", 0.0)
    size = _number(moment_am2, "moment_am2", 0.0)
    where = _unit_axis(direction, "direction")
    along = where if moment_direction is None else _unit_axis(moment_direction, "moment_direction")
    position = distance * where
    moment = size * along
    return AttachedDipole(tuple(moment), tuple(position), start_s)  # type: ignore[arg-type]
