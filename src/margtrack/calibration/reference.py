"""Gravity and magnetic reference vectors measured in the reference position (000, App. B step 18).

"Place the sensor in the reference position with the positive x-axis pointing toward
magnetic north, positive y-axis east, and the positive z-axis pointing down. While in this
stationary position record the reading produced by the magnetometers and accelerometers.
The six numbers produced correspond to the x, y, and z components of the two reference
vectors." In that pose body axes are NED axes, so the calibrated readings are the NED
reference vectors. From them: gravity magnitude, field strength, dip (inclination) angle
and how far the x axis was from magnetic north (which the step requires to be ~0).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

__all__ = ["ReferenceVectors", "reference_vectors"]


def _vector(value: ArrayLike, name: str) -> tuple[float, float, float]:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass(frozen=True)
class ReferenceVectors:
    """Local gravity and magnetic field measured at rest in the reference position.

    Attributes
    ----------
    acc_m_s2 : (3,) mean calibrated specific force in body axes, m/s² (points up: in the
        NED reference pose about ``[0, 0, -g]``).
    mag_ut : (3,) mean calibrated magnetic field in body axes, µT.
    gravity_m_s2 : ``|acc|``, m/s², in [9.7, 9.9] (Earth's surface gravity is 9.76-9.84).
    field_ut : ``|mag|``, µT, > 0.
    dip_deg : inclination of the field below the horizontal, deg in [-90, 90] (positive
        down): ``asin(-(mag · up) / |mag|)`` with ``up = acc / |acc|``.
    heading_offset_deg : angle from magnetic north to the body x axis projected on the
        horizontal, deg in (-180, 180], positive towards east; 0 in a correct reference pose.
    """

    acc_m_s2: tuple[float, float, float]
    mag_ut: tuple[float, float, float]
    gravity_m_s2: float
    field_ut: float
    dip_deg: float
    heading_offset_deg: float

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "acc_m_s2", _vector(self.acc_m_s2, "acc_m_s2"))
        set_(self, "mag_ut", _vector(self.mag_ut, "mag_ut"))
        for name in ("gravity_m_s2", "field_ut", "dip_deg", "heading_offset_deg"):
            set_(self, name, float(getattr(self, name)))
        if not 9.7 <= self.gravity_m_s2 <= 9.9:
            raise ValueError(
                f"gravity_m_s2 must be in [9.7, 9.9] (Earth's surface), got {self.gravity_m_s2}; "
                "is the accelerometer in g or uncalibrated?"
            )
        if not (np.isfinite(self.field_ut) and 0.0 < self.field_ut <= 1000.0):
            raise ValueError(
                f"field_ut must be in (0, 1000] µT (Earth: 22-67 µT), got {self.field_ut}"
            )
        if not -90.0 <= self.dip_deg <= 90.0:
            raise ValueError(f"dip_deg must be in [-90, 90], got {self.dip_deg}")
        if not -180.0 < self.heading_offset_deg <= 180.0:
            raise ValueError(
                f"heading_offset_deg must be in (-180, 180], got {self.heading_offset_deg}"
            )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (units in the keys)."""
        return {
            "acc_m_s2": list(self.acc_m_s2),
            "mag_ut": list(self.mag_ut),
            "gravity_m_s2": self.gravity_m_s2,
            "field_ut": self.field_ut,
            "dip_deg": self.dip_deg,
            "heading_offset_deg": self.heading_offset_deg,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ReferenceVectors:
        """Inverse of :meth:`to_dict`; unknown or missing keys raise ``ValueError``."""
        keys = {"acc_m_s2", "mag_ut", "gravity_m_s2", "field_ut", "dip_deg", "heading_offset_deg"}
        if set(d) != keys:
            raise ValueError(
                f"reference needs exactly the keys {sorted(keys)}, got {sorted(d)}"
            )
        return cls(**d)


def reference_vectors(acc: ArrayLike, mag: ArrayLike) -> ReferenceVectors:
    """Reference vectors from calibrated still samples in the reference pose (000, step 18).

    Parameters
    ----------
    acc : (N, 3) or (3,) calibrated specific force at rest, body axes, m/s².
    mag : (N, 3) or (3,) calibrated magnetic field, body axes, µT.

    Returns
    -------
    :class:`ReferenceVectors` from the means. The dip uses the measured vertical (the
    accelerometer), so it is right even if the surface is not quite level; the heading
    offset tells how far the x axis was from magnetic north.
    """
    a = np.asarray(acc, dtype=np.float64).reshape(-1, 3).mean(axis=0)
    m = np.asarray(mag, dtype=np.float64).reshape(-1, 3).mean(axis=0)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(m))):
        raise ValueError("acc and mag must be finite (N, 3) arrays")
    g = float(np.linalg.norm(a))
    f = float(np.linalg.norm(m))
    if g == 0.0 or f == 0.0:
        raise ValueError("the mean accelerometer or magnetometer vector is zero")
    up = a / g
    dip = float(np.degrees(np.arcsin(np.clip(-(m @ up) / f, -1.0, 1.0))))
    down = -up
    east = np.cross(down, m)
    if np.linalg.norm(east) < 1e-9 * f:
        raise ValueError("the field is vertical: no magnetic north to refer to")
    east /= np.linalg.norm(east)
    north = np.cross(east, down)
    heading = float(np.degrees(np.arctan2(east[0], north[0])))
    if heading <= -180.0:
        heading = 180.0
    return ReferenceVectors(tuple(a), tuple(m), g, f, dip, heading)
