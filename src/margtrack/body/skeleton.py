"""Skeleton: body segments as a tree rooted at the pelvis, with segment vectors in metres.

Segment frame (000, "Quaternion Based Human Body Model"): in the reference pose (standing
upright, arms hanging down, facing the heading reference) every segment's axes coincide with
the earth frame's axes. With the paper's heading reference, magnetic north, that makes the
segment frame the earth frame itself: NED ``x`` forward (north), ``y`` right (east), ``z``
down; ENU ``x`` right (east), ``y`` forward (north), ``z`` up. Every vector of a skeleton is
written in these coordinates, so a skeleton belongs to one earth frame (``frame``).

Each :class:`Segment` carries two vectors (000's translation vector ``p``, generalised to
a tree):

- ``offset_m``: from the parent's joint to this segment's joint (its inboard end), in the
  parent's segment frame; zero for the root;
- ``end_m``: from this segment's joint to its distal end, in its own segment frame (the
  chain's end for leaves, drawn as a bone, and the BVH "End Site").

For a chain, a child's ``offset_m`` is its parent's ``end_m`` (000: "the outboard end point
can be used as the origin location for the coordinate system of more distal segments").

Body proportions and segment names are in :mod:`margtrack.body.segments`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.body.segments import (
    ALIASES,
    PARENT,
    PRESETS,
    SEGMENT_NAMES,
    WINTER_FRACTIONS,
    body_axes,
    canonical_name,
    dimensions_from_height,
    positive,
)
from margtrack.frames import Frame, check_frame

Array = NDArray[np.float64]

__all__ = [
    "ALIASES",
    "PRESETS",
    "SEGMENT_NAMES",
    "WINTER_FRACTIONS",
    "Segment",
    "Skeleton",
    "body_axes",
    "canonical_name",
    "dimensions_from_height",
]


def _vector(value: ArrayLike, name: str) -> Array:
    try:
        v = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a 3-vector in metres, got {value!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be a finite 3-vector in metres, got {value!r}")
    v.setflags(write=False)
    return v


@dataclass(frozen=True, eq=False)
class Segment:
    """One body segment: its name, its parent, and its two vectors (see the module docstring).

    Parameters
    ----------
    name : one of :data:`SEGMENT_NAMES` (or an alias, stored canonical).
    parent : the parent segment's name, ``None`` for the root.
    offset_m : (3,) m, parent's joint to this joint in the parent's segment frame; zero for
        the root.
    end_m : (3,) m, this joint to the segment's distal end, in its own segment frame.
    """

    name: str
    parent: str | None
    offset_m: Array
    end_m: Array

    def __post_init__(self) -> None:
        object.__setattr__(self, "name", canonical_name(self.name))
        if self.parent is not None:
            object.__setattr__(self, "parent", canonical_name(self.parent))
        object.__setattr__(self, "offset_m", _vector(self.offset_m, f"{self.name}.offset_m"))
        object.__setattr__(self, "end_m", _vector(self.end_m, f"{self.name}.end_m"))
        if self.parent is None and np.any(self.offset_m != 0.0):
            raise ValueError(
                f"root segment {self.name!r} must have offset_m = 0 (its position is "
                f"Skeleton.root_position_m), got {self.offset_m}"
            )


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A tree of segments rooted at one segment, in one earth frame.

    Parameters
    ----------
    segments : segments in tree order (each parent before its children), one root.
    frame : ``"ENU"`` (default) or ``"NED"``: the coordinates of every vector.
    root_position_m : (3,) m, the root joint's position in the reference pose (floor at 0),
        used when no root trajectory is given.

    Attributes
    ----------
    names : segment names in order; the sensor axis of every (..., S, 4) array follows it.
    parents : (S,) int, index of each segment's parent, -1 for the root.
    """

    segments: tuple[Segment, ...]
    frame: Frame = "ENU"
    root_position_m: Array = field(default_factory=lambda: np.zeros(3))
    names: tuple[str, ...] = field(init=False)
    parents: NDArray[np.intp] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "frame", check_frame(self.frame))
        segments = tuple(self.segments)
        if not segments or not all(isinstance(s, Segment) for s in segments):
            raise ValueError("segments must be a non-empty sequence of Segment")
        object.__setattr__(self, "segments", segments)
        names = tuple(s.name for s in segments)
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"segment names must be unique; repeated: {', '.join(dup)}")
        roots = [s.name for s in segments if s.parent is None]
        if len(roots) != 1 or segments[0].parent is not None:
            raise ValueError(
                f"a skeleton needs exactly one root segment (parent None), listed first; "
                f"got roots {roots}"
            )
        parents = np.full(len(segments), -1, dtype=np.intp)
        for i, s in enumerate(segments[1:], start=1):
            if s.parent not in names[:i]:
                raise ValueError(
                    f"segment {s.name!r} has parent {s.parent!r}, which is not listed before it; "
                    "list segments parents first"
                )
            parents[i] = names.index(s.parent)
        parents.setflags(write=False)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "parents", parents)
        object.__setattr__(
            self, "root_position_m", _vector(self.root_position_m, "root_position_m")
        )

    def __len__(self) -> int:
        return len(self.segments)

    @property
    def root(self) -> str:
        """Name of the root segment."""
        return self.names[0]

    @property
    def offsets_m(self) -> Array:
        """(S, 3) m: every segment's ``offset_m``."""
        return np.stack([s.offset_m for s in self.segments])

    @property
    def ends_m(self) -> Array:
        """(S, 3) m: every segment's ``end_m``."""
        return np.stack([s.end_m for s in self.segments])

    def index(self, name: str) -> int:
        """Position of segment ``name`` (or an alias) in :attr:`names`; ``ValueError`` if absent."""
        key = canonical_name(name)
        if key not in self.names:
            raise ValueError(
                f"segment {name!r} is not in this skeleton; its segments: {', '.join(self.names)}"
            )
        return self.names.index(key)

    def order(self, names: Sequence[str]) -> NDArray[np.intp]:
        """Indices ``idx`` that put data listed as ``names`` in skeleton order (``data[idx]``).

        ``names`` (sensor or segment names, aliases allowed) must name every segment exactly
        once; a missing, extra, unknown or repeated name raises ``ValueError``.
        """
        keys = [canonical_name(n) for n in names]
        extra = [n for n, k in zip(names, keys, strict=True) if k not in self.names]
        missing = [n for n in self.names if n not in keys]
        repeated = sorted({k for k in keys if keys.count(k) > 1})
        if extra or missing or repeated:
            raise ValueError(
                f"expected one sensor per segment ({', '.join(self.names)}); "
                f"missing: {missing}, not in this skeleton: {extra}, repeated: {repeated}"
            )
        return np.array([keys.index(n) for n in self.names], dtype=np.intp)

    @classmethod
    def from_height(
        cls,
        height_m: float,
        preset: str = "full",
        frame: str = "ENU",
        dimensions_m: Mapping[str, float] | None = None,
    ) -> Skeleton:
        """Skeleton of a preset with dimensions scaled from body height (Winter 2009, Fig. 4.1).

        Parameters
        ----------
        height_m : body height in m, in [0.5, 2.8].
        preset : ``"full"`` (15 segments), ``"lower"`` (pelvis, thighs, shanks, feet: 7),
            ``"left_arm"``/``"right_arm"`` (upper arm, forearm, hand: 000's 3-sensor arm),
            ``"left_leg"``/``"right_leg"`` (thigh, shank, foot).
        frame : ``"ENU"`` or ``"NED"``.
        dimensions_m : overrides of :func:`dimensions_from_height`'s keys, in m (measured
            lengths of this subject).

        Geometry (reference pose, R right, F forward, U up; :func:`body_axes`): pelvis joint at
        the mid-hip point, hips at ``±hip_width/2 R``; thigh ``-thigh U``; shank ``-shank U``;
        foot ``foot_length F - ankle_height U`` (ankle taken above the heel, a simplification:
        Fig. 4.1 gives no heel-to-ankle distance); trunk joint at the mid-hip point (Winter's
        trunk starts at the greater trochanter), trunk ``trunk U``; head ``head U`` from the
        top of the trunk; shoulders at ``trunk U ± shoulder_width/2 R``; arms ``-length U``.
        The root stands at hip height (shoulder height for an arm) above the floor.
        """
        dims = dimensions_from_height(height_m)
        for key, value in dict(dimensions_m or {}).items():
            if key not in dims:
                raise ValueError(
                    f"unknown dimension {key!r} in dimensions_m; known: {', '.join(dims)}"
                )
            dims[key] = positive(value, f"dimensions_m[{key!r}]")
        if preset not in PRESETS:
            raise ValueError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
        frame = check_frame(frame)
        right, forward, upward = body_axes(frame)
        side = {"left": -1.0, "right": 1.0}
        geometry: dict[str, tuple[Array, Array]] = {
            "pelvis": (np.zeros(3), np.zeros(3)),
            "trunk": (np.zeros(3), dims["trunk"] * upward),
            "head": (dims["trunk"] * upward, dims["head"] * upward),
        }
        for s, sign in side.items():
            geometry[f"{s}_upper_arm"] = (
                dims["trunk"] * upward + sign * 0.5 * dims["shoulder_width"] * right,
                -dims["upper_arm"] * upward,
            )
            geometry[f"{s}_forearm"] = (-dims["upper_arm"] * upward, -dims["forearm"] * upward)
            geometry[f"{s}_hand"] = (-dims["forearm"] * upward, -dims["hand"] * upward)
            geometry[f"{s}_thigh"] = (sign * 0.5 * dims["hip_width"] * right,
                                      -dims["thigh"] * upward)
            geometry[f"{s}_shank"] = (-dims["thigh"] * upward, -dims["shank"] * upward)
            geometry[f"{s}_foot"] = (
                -dims["shank"] * upward,
                dims["foot_length"] * forward - dims["ankle_height"] * upward,
            )
        names = PRESETS[preset]
        segments = []
        for name in names:
            parent = PARENT[name]
            offset, end = geometry[name]
            if parent not in names:
                parent, offset = None, np.zeros(3)
            segments.append(Segment(name, parent, offset, end))
        hip_height = dims["thigh"] + dims["shank"] + dims["ankle_height"]
        root_height = hip_height + (dims["trunk"] if preset.endswith("_arm") else 0.0)
        if preset.endswith("_arm") or preset.endswith("_leg"):
            s = preset.split("_")[0]
            root_offset = geometry[f"{s}_upper_arm" if preset.endswith("_arm") else f"{s}_thigh"][0]
            root_lateral = root_offset - np.dot(root_offset, upward) * upward
        else:
            root_lateral = np.zeros(3)
        return cls(tuple(segments), frame, root_height * upward + root_lateral)

    @classmethod
    def from_segments(
        cls,
        segments: Sequence[str],
        height_m: float = 1.75,
        frame: str = "ENU",
        dimensions_m: Mapping[str, float] | None = None,
    ) -> Skeleton:
        """Skeleton of any set of segments (the sensors a recording has), scaled from height.

        Parameters
        ----------
        segments : segment names or aliases, any order; each chain must be complete up to
            one root: every segment's parent is in the set, except for the one root (the
            first of the set in :data:`SEGMENT_NAMES` order). A leg without its thigh, or
            two separate chains (two arms without the trunk), raise ``ValueError`` naming
            the segments that would be needed.
        height_m, frame, dimensions_m : as :meth:`from_height`.

        Returns
        -------
        The skeleton with the segments in tree order; the geometry of :meth:`from_height`'s
        ``"full"`` preset, with the root placed where that preset puts its joint (equal to
        the presets ``lower``, ``left_arm``... for their segment sets).
        """
        keys = [canonical_name(s) for s in segments]
        repeated = sorted({k for k in keys if keys.count(k) > 1})
        if repeated:
            raise ValueError(f"segments must be distinct; repeated: {', '.join(repeated)}")
        if not keys:
            raise ValueError("segments is empty; name at least one segment")
        names = tuple(n for n in SEGMENT_NAMES if n in keys)
        orphans = [n for n in names[1:] if PARENT[n] not in names]
        if orphans:
            needed = []
            for n in orphans:
                chain, p = [], PARENT[n]
                while p is not None and p not in names:
                    chain.append(p)
                    p = PARENT[p]
                needed.append(f"{n} needs {' and '.join(chain)}")
            raise ValueError(
                f"the segments {', '.join(names)} do not form one chain from {names[0]}: "
                f"{'; '.join(needed)} (a sensor on each segment between it and {names[0]}); "
                "add those sensors or leave the disconnected ones out"
            )
        full = cls.from_height(height_m, "full", frame, dimensions_m)
        joints = {full.names[0]: full.root_position_m}
        for i, seg in enumerate(full.segments[1:], start=1):
            joints[seg.name] = joints[full.names[full.parents[i]]] + seg.offset_m
        picked = []
        for seg in full.segments:
            if seg.name in names:
                root = seg.name == names[0]
                picked.append(Segment(seg.name, None if root else seg.parent,
                                      np.zeros(3) if root else seg.offset_m, seg.end_m))
        return cls(tuple(picked), full.frame, joints[names[0]])
