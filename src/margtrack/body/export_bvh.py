"""BVH (Biovision Hierarchy) export of a body-model motion.

Layout written:

- Axes: BVH's usual Y-up right-handed world, fixed to the earth: ``X`` west, ``Y`` up,
  ``Z`` north (:func:`bvh_axes`). In the rest pose (all channels zero) the skeleton is in the
  reference pose facing north (+Z, the usual BVH facing direction).
- Hierarchy: one ``JOINT`` per segment, named after it, ``ROOT`` for the skeleton's root;
  ``OFFSET`` = the segment's ``offset_m`` (parent's joint to this joint), the root's is
  ``0 0 0`` so readers that add the root offset to the position channels and readers that
  replace it agree; leaves get an ``End Site`` at their ``end_m``. Lengths in ``unit``
  (``"cm"``, default, or ``"m"``).
- Channels: root ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``, every
  other joint ``Zrotation Xrotation Yrotation``, in degrees. The rotation is intrinsic in the
  listed order, ``R = Rz(z) · Rx(x) · Ry(y)`` (the common reading, e.g. the CMU files and
  Blender's importer), and is the joint's rotation relative to its parent:
  ``q_local = q_parent* ⊗ q_segment`` (the root's relative to the world), expressed in the BVH
  axes.

Forward kinematics of the file, ``p_child = p_parent + R_world(parent) · OFFSET_child`` and
``R_world(child) = R_world(parent) · R_local(child)``, reproduces
:func:`margtrack.body.positions` (000, eq. 11) in the BVH axes.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.body._checks import sensor_quaternions
from margtrack.body.kinematics import positions
from margtrack.body.skeleton import Skeleton, body_axes
from margtrack.frames import check_frame

Array = NDArray[np.float64]

__all__ = ["BVH_UNITS", "bvh_axes", "write_bvh"]

#: Length units of BVH files: metres per unit.
BVH_UNITS = {"cm": 0.01, "m": 1.0}


def bvh_axes(frame: str) -> Array:
    """(3, 3) matrix ``M`` with ``v_bvh = M @ v_frame``: rows west (X), up (Y), north (Z)."""
    right, forward, upward = body_axes(check_frame(frame))
    return np.stack([-right, upward, forward])


def _scale(unit: str) -> float:
    if unit not in BVH_UNITS:
        raise ValueError(f"unit must be one of {', '.join(BVH_UNITS)}, got {unit!r}")
    return 1.0 / BVH_UNITS[unit]


def _hierarchy(skeleton: Skeleton, m: Array, scale: float) -> list[str]:
    children: dict[int, list[int]] = {i: [] for i in range(len(skeleton))}
    for i in range(1, len(skeleton)):
        children[int(skeleton.parents[i])].append(i)
    lines = ["HIERARCHY"]

    def vec(v: Array) -> str:
        return " ".join(f"{x:.8f}" for x in m @ v * scale)

    def joint(i: int, depth: int) -> None:
        pad = "  " * depth
        seg = skeleton.segments[i]
        lines.append(f"{pad}{'ROOT' if i == 0 else 'JOINT'} {seg.name}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {vec(seg.offset_m)}")
        if i == 0:
            lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition "
                         "Zrotation Xrotation Yrotation")
        else:
            lines.append(f"{pad}  CHANNELS 3 Zrotation Xrotation Yrotation")
        for c in children[i]:
            joint(c, depth + 1)
        if not children[i]:
            lines.extend([f"{pad}  End Site", f"{pad}  {{",
                          f"{pad}    OFFSET {vec(seg.end_m)}", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    joint(0, 0)
    return lines


def _depth_first(skeleton: Skeleton) -> list[int]:
    """Segment indices in the order their channels appear in a MOTION line."""
    order: list[int] = []

    def visit(i: int) -> None:
        order.append(i)
        for c in range(1, len(skeleton)):
            if skeleton.parents[c] == i:
                visit(c)

    visit(0)
    return order


def write_bvh(
    path: str | Path,
    skeleton: Skeleton,
    q_segment: ArrayLike,
    frame_time_s: float,
    root_position_m: ArrayLike | None = None,
    unit: str = "cm",
) -> None:
    """Write a motion of the body model as a BVH file (layout in the module docstring).

    Parameters
    ----------
    path : the file to create or overwrite.
    skeleton : the body model; its hierarchy and reference pose become the BVH rest pose.
    q_segment : (N, S, 4) segment to earth orientations (:func:`segment_orientations`).
    frame_time_s : time between frames, s (the BVH ``Frame Time``); no default: say the rate.
    root_position_m : (3,) or (N, 3) m, the root joint's position in ``skeleton.frame``;
        default ``skeleton.root_position_m``.
    unit : ``"cm"`` or ``"m"``, the length unit of offsets and positions in the file.
    """
    from scipy.spatial.transform import Rotation

    q = sensor_quaternions(q_segment, skeleton, "q_segment")
    if q.ndim != 3:
        raise ValueError(f"q_segment must have shape (N, S, 4) for a motion, got {q.shape}")
    if not (np.isfinite(frame_time_s) and frame_time_s > 0):
        raise ValueError(f"frame_time_s must be a finite number of seconds > 0, got {frame_time_s}")
    scale = _scale(unit)
    m = bvh_axes(skeleton.frame)
    qm = quat.from_matrix(m)
    joints, _ = positions(skeleton, q, root_position_m)
    parents = skeleton.parents
    q_parent = np.concatenate([quat.identity((q.shape[0], 1)), q[:, parents[1:], :]], axis=1)
    q_local = quat.multiply(quat.conjugate(q_parent), q)
    q_bvh = quat.multiply(quat.multiply(qm, q_local), quat.conjugate(qm))
    with warnings.catch_warnings():
        # at gimbal lock scipy still returns angles that reproduce the rotation
        warnings.simplefilter("ignore", UserWarning)
        zxy = Rotation.from_quat(q_bvh[..., [1, 2, 3, 0]].reshape(-1, 4)).as_euler(
            "ZXY", degrees=True
        ).reshape(q.shape[0], len(skeleton), 3)
    columns = [joints[:, 0, :] @ m.T * scale]
    for i in _depth_first(skeleton):
        columns.append(zxy[:, i, :])
    motion = np.concatenate(columns, axis=1)
    lines = _hierarchy(skeleton, m, scale)
    lines += ["MOTION", f"Frames: {q.shape[0]}", f"Frame Time: {float(frame_time_s):.8f}"]
    with open(path, "w", encoding="ascii", newline="\n") as f:
        f.write("\n".join(lines) + "\n")
        np.savetxt(f, motion, fmt="%.8f")
