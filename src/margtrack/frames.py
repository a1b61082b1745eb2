"""Earth frames (NED, ENU), their reference vectors, and conversion of orientations between them.

- ``NED``: x north, y east, z down (the seeds' choice, 000-002).
- ``ENU``: x east, y north, z up (BROAD, VQF, most robotics data).

An accelerometer at rest measures specific force, which points *up*: ``[0, 0, -g]`` in NED
and ``[0, 0, +g]`` in ENU. The geomagnetic field points north and, in the northern
hemisphere, down by the dip (inclination) angle.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat

Frame = Literal["NED", "ENU"]
FRAMES: tuple[Frame, ...] = ("NED", "ENU")

#: Standard gravity in m/s² (CGPM 1901), the default magnitude of the gravity reference.
STANDARD_GRAVITY_M_S2 = 9.80665

# Rotation taking ENU coordinates to NED coordinates: [n, e, d] = [y, x, -z]; a half turn
# about (x + y)/sqrt(2). It is its own inverse, so it also takes NED to ENU.
_ENU_TO_NED = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])

__all__ = [
    "FRAMES",
    "STANDARD_GRAVITY_M_S2",
    "Frame",
    "check_frame",
    "convert",
    "gravity_reference",
    "mag_reference",
    "up",
]


def check_frame(frame: str) -> Frame:
    """Return ``frame`` upper-cased if it names an earth frame, else raise ``ValueError``."""
    name = str(frame).upper()
    if name not in FRAMES:
        raise ValueError(f"frame must be 'NED' or 'ENU', got {frame!r}")
    return name  # type: ignore[return-value]


def up(frame: str) -> NDArray[np.float64]:
    """Unit vector pointing up in ``frame``: ``[0, 0, -1]`` in NED, ``[0, 0, 1]`` in ENU."""
    return np.array([0.0, 0.0, -1.0 if check_frame(frame) == "NED" else 1.0])


def gravity_reference(
    frame: str, gravity_m_s2: float = STANDARD_GRAVITY_M_S2
) -> NDArray[np.float64]:
    """What a level accelerometer at rest reads in ``frame`` (m/s²): ``gravity_m_s2 * up``."""
    if not (np.isfinite(gravity_m_s2) and gravity_m_s2 > 0):
        raise ValueError(f"gravity_m_s2 must be a finite number > 0, got {gravity_m_s2}")
    return gravity_m_s2 * up(frame)


def mag_reference(frame: str, dip_deg: float = 0.0, field_ut: float = 1.0) -> NDArray[np.float64]:
    """Earth magnetic field vector in ``frame``, pointing north and down by ``dip_deg``.

    ``dip_deg`` is the inclination (positive down, in [-90, 90]); ``field_ut`` the field
    strength in µT (or any unit: only the direction matters to most estimators).
    NED: ``F·[cos dip, 0, sin dip]``; ENU: ``F·[0, cos dip, -sin dip]``.
    """
    if not -90.0 <= dip_deg <= 90.0:
        raise ValueError(f"dip_deg must be in [-90, 90], got {dip_deg}")
    if not (np.isfinite(field_ut) and field_ut > 0):
        raise ValueError(f"field_ut must be a finite number > 0, got {field_ut}")
    c, s = np.cos(np.radians(dip_deg)), np.sin(np.radians(dip_deg))
    if check_frame(frame) == "NED":
        return field_ut * np.array([c, 0.0, s])
    return field_ut * np.array([0.0, c, -s])


def convert(q: ArrayLike, from_frame: str, to_frame: str) -> NDArray[np.float64]:
    """Re-express orientations ``q`` (..., 4) of a body relative to ``from_frame`` in ``to_frame``.

    ``q_to = c ⊗ q_from`` with ``c`` the fixed rotation between the two earth frames; the
    body frame is untouched, so ``rotate(q_to, v_body)`` is ``rotate(q_from, v_body)``
    written in the other earth frame's axes.
    """
    src = check_frame(from_frame)
    dst = check_frame(to_frame)
    q = np.asarray(q, dtype=np.float64)
    if q.ndim == 0 or q.shape[-1] != 4:
        raise ValueError(f"q must have shape (..., 4) in [w, x, y, z] order, got {q.shape}")
    if src == dst:
        return q.copy()
    return quat.multiply(_ENU_TO_NED, q)
