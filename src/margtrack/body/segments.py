"""Body segments: their names, the anatomical tree, body proportions and the body's axes.

The 15 segments of 000's full body model (:data:`SEGMENT_NAMES`), other accepted names
(:data:`ALIASES`), each segment's anatomical parent, the presets of
:class:`~margtrack.body.skeleton.Skeleton` (:data:`PRESETS`), and the axes of a person in
the reference pose (:func:`body_axes`, earth-frame coordinates: NED or ENU).

Body proportions, :data:`WINTER_FRACTIONS`, are the segment lengths as fractions of body
height H of Winter, D. A. (2009), *Biomechanics and Motor Control of Human Movement*, 4th ed.,
Wiley, Fig. 4.1 (after Drillis & Contini, 1966): heights above the floor of the greater
trochanter 0.530 H, knee 0.285 H, ankle 0.039 H, shoulder 0.818 H; shoulder width 0.259 H,
hip width 0.191 H, foot length 0.152 H, upper arm 0.186 H, forearm 0.146 H, hand 0.108 H.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

from margtrack.frames import mag_reference, up

Array = NDArray[np.float64]

__all__ = [
    "ALIASES",
    "PARENT",
    "PRESETS",
    "SEGMENT_NAMES",
    "WINTER_FRACTIONS",
    "body_axes",
    "canonical_name",
    "dimensions_from_height",
    "positive",
]

#: The 15 segments of the full body (000: "approximately fifteen nine-axis units").
SEGMENT_NAMES: tuple[str, ...] = (
    "pelvis", "trunk", "head",
    "left_upper_arm", "left_forearm", "left_hand",
    "right_upper_arm", "right_forearm", "right_hand",
    "left_thigh", "left_shank", "left_foot",
    "right_thigh", "right_shank", "right_foot",
)

#: Other accepted names of segments (the sensor folders of ../shared/data/xio_lower_body).
ALIASES: Mapping[str, str] = MappingProxyType({
    **{f"{side}_upper_leg": f"{side}_thigh" for side in ("left", "right")},
    **{f"{side}_lower_leg": f"{side}_shank" for side in ("left", "right")},
    "torso": "trunk",
})

#: Anatomical parent of each segment.
PARENT: Mapping[str, str | None] = MappingProxyType({
    "pelvis": None, "trunk": "pelvis", "head": "trunk",
    **{f"{s}_upper_arm": "trunk" for s in ("left", "right")},
    **{f"{s}_forearm": f"{s}_upper_arm" for s in ("left", "right")},
    **{f"{s}_hand": f"{s}_forearm" for s in ("left", "right")},
    **{f"{s}_thigh": "pelvis" for s in ("left", "right")},
    **{f"{s}_shank": f"{s}_thigh" for s in ("left", "right")},
    **{f"{s}_foot": f"{s}_shank" for s in ("left", "right")},
})

#: Presets: segment names in tree order (parents first).
PRESETS: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "full": SEGMENT_NAMES,
    "lower": ("pelvis", "left_thigh", "left_shank", "left_foot",
              "right_thigh", "right_shank", "right_foot"),
    **{f"{s}_arm": (f"{s}_upper_arm", f"{s}_forearm", f"{s}_hand") for s in ("left", "right")},
    **{f"{s}_leg": (f"{s}_thigh", f"{s}_shank", f"{s}_foot") for s in ("left", "right")},
})

#: Winter (2009) Fig. 4.1: lengths as fractions of body height H.
WINTER_FRACTIONS: Mapping[str, float] = MappingProxyType({
    "hip_height": 0.530,  # greater trochanter above the floor
    "knee_height": 0.285,
    "ankle_height": 0.039,
    "shoulder_height": 0.818,
    "shoulder_width": 0.259,
    "hip_width": 0.191,
    "foot_length": 0.152,
    "upper_arm": 0.186,
    "forearm": 0.146,
    "hand": 0.108,
})


def dimensions_from_height(height_m: float) -> dict[str, float]:
    """Body dimensions in metres from body height (Winter 2009, Fig. 4.1).

    Returns the keys accepted by ``Skeleton.from_height(dimensions_m=...)``: ``thigh``
    (hip to knee, (0.530 - 0.285) H), ``shank`` (knee to ankle, (0.285 - 0.039) H),
    ``ankle_height`` (0.039 H), ``foot_length`` (0.152 H), ``hip_width`` (0.191 H),
    ``trunk`` (hip to shoulder height, (0.818 - 0.530) H, Winter's trunk: greater trochanter
    to glenohumeral joint), ``head`` (shoulder height to the top of the head,
    (1 - 0.818) H), ``shoulder_width`` (0.259 H), ``upper_arm`` (0.186 H), ``forearm``
    (0.146 H), ``hand`` (0.108 H).
    """
    h = positive(height_m, "height_m")
    if not 0.5 <= h <= 2.8:
        raise ValueError(f"height_m must be a body height in metres in [0.5, 2.8], got {h}")
    f = WINTER_FRACTIONS
    return {
        "thigh": (f["hip_height"] - f["knee_height"]) * h,
        "shank": (f["knee_height"] - f["ankle_height"]) * h,
        "ankle_height": f["ankle_height"] * h,
        "foot_length": f["foot_length"] * h,
        "hip_width": f["hip_width"] * h,
        "trunk": (f["shoulder_height"] - f["hip_height"]) * h,
        "head": (1.0 - f["shoulder_height"]) * h,
        "shoulder_width": f["shoulder_width"] * h,
        "upper_arm": f["upper_arm"] * h,
        "forearm": f["forearm"] * h,
        "hand": f["hand"] * h,
    }


def positive(value: float, name: str) -> float:
    """``value`` as a finite float > 0, or ``ValueError`` naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not (np.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def body_axes(frame: str) -> tuple[Array, Array, Array]:
    """Unit vectors ``(right, forward, up)`` of a person in the reference pose facing north.

    In ``frame`` coordinates: NED ``([0,1,0], [1,0,0], [0,0,-1])``, ENU ``([1,0,0], [0,1,0],
    [0,0,1])``. ``forward`` is north (the horizontal field direction of
    :func:`margtrack.frames.mag_reference` with zero dip), ``right = forward × up``.
    These are also the anatomical axes (medio-lateral, antero-posterior, longitudinal) of
    every segment frame.
    """
    forward = mag_reference(frame, 0.0, 1.0)
    upward = up(frame)
    return np.cross(forward, upward), forward, upward


def canonical_name(name: str) -> str:
    """The segment name for ``name`` or one of its :data:`ALIASES`; ``ValueError`` if unknown."""
    key = str(name).strip().lower().replace(" ", "_").replace("-", "_")
    key = ALIASES.get(key, key)
    if key not in PARENT:
        raise ValueError(
            f"unknown segment name {name!r}; known segments: {', '.join(SEGMENT_NAMES)} "
            f"(also accepted: {', '.join(ALIASES)})"
        )
    return key
