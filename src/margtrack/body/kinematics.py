"""Forward kinematics of the body model: segment orientations and joint positions (000, eqs. 7, 11).

Arrays are frames first, then segments in the skeleton's order: ``q`` (N, S, 4) or (S, 4),
positions (N, S, 3) or (S, 3) in metres, earth frame ``skeleton.frame``. Everything is
vectorised over frames; the only Python loop runs over the (at most 15) segments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.body._checks import sensor_quaternions
from margtrack.body.offsets import Calibration
from margtrack.body.skeleton import Skeleton

Array = NDArray[np.float64]

__all__ = ["BodyPose", "positions", "resample_orientations", "segment_orientations", "track"]


def _hemisphere(q: Array) -> Array:
    """``q`` with frame 0 at ``w >= 0`` and consecutive frames at positive dot products.

    Makes outputs independent of the signs of the inputs (``q`` and ``-q`` are one rotation).
    """
    q = quat.canonical(q) if q.ndim == 2 else q
    if q.ndim == 3:
        first = quat.canonical(q[:1])
        q = np.concatenate([first, q[1:]], axis=0)
        q = np.moveaxis(quat.continuous(np.moveaxis(q, 0, -2)), -2, 0)
    return q


def segment_orientations(
    skeleton: Skeleton, calibration: Calibration, q_sensor: ArrayLike
) -> Array:
    """Segment orientations ``q_segment = q_sensor ⊗ q_offset`` (000, eq. 7).

    Parameters
    ----------
    skeleton : the body model (its frame is that of ``q_sensor``).
    calibration : offsets from :func:`margtrack.body.calibrate` with this skeleton.
    q_sensor : (N, S, 4) or (S, 4) unit quaternions, sensor to earth, skeleton order.

    Returns
    -------
    (N, S, 4) or (S, 4) segment to earth, frame 0 with ``w >= 0`` and continuous in time, so
    ``q_sensor`` and ``-q_sensor`` give identical output.
    """
    calibration.check(skeleton)
    q = sensor_quaternions(q_sensor, skeleton, "q_sensor")
    return _hemisphere(quat.multiply(q, calibration.offsets))  # 000 eq. 7


def positions(
    skeleton: Skeleton, q_segment: ArrayLike, root_position_m: ArrayLike | None = None
) -> tuple[Array, Array]:
    """Joint and distal-end positions: sums of rotated segment vectors from the root (000, eq. 11).

    ``joint[i] = joint[parent] + rotate(q[parent], offset_i)`` and
    ``end[i] = joint[i] + rotate(q[i], end_i)``: 000's ``p_trans`` is the sum of the rotated
    translation vectors between the body origin and the segment.

    Parameters
    ----------
    skeleton : the body model.
    q_segment : (N, S, 4) or (S, 4) segment orientations (:func:`segment_orientations`).
    root_position_m : (3,) or (N, 3) m, the root joint's position; default
        ``skeleton.root_position_m`` (standing on the floor at the origin).

    Returns
    -------
    joints : (N, S, 3) or (S, 3) m, each segment's joint (inboard end).
    ends : (N, S, 3) or (S, 3) m, each segment's distal end.
    """
    q = sensor_quaternions(q_segment, skeleton, "q_segment")
    lead = q.shape[:-2]
    root = skeleton.root_position_m if root_position_m is None else root_position_m
    root = np.asarray(root, dtype=np.float64)
    if root.shape not in ((3,), (*lead, 3)) or not np.all(np.isfinite(root)):
        raise ValueError(
            f"root_position_m must be finite with shape (3,) or {(*lead, 3)}, got {root.shape}"
        )
    joints = np.empty((*lead, len(skeleton), 3))
    joints[..., 0, :] = root
    offsets, ends_body = skeleton.offsets_m, skeleton.ends_m
    for i in range(1, len(skeleton)):
        p = skeleton.parents[i]
        joints[..., i, :] = joints[..., p, :] + quat.rotate(q[..., p, :], offsets[i])  # eq. 11
    ends = joints + quat.rotate(q, ends_body)
    return joints, ends


@dataclass(frozen=True, eq=False)
class BodyPose:
    """Posture of the body model over N frames.

    Attributes
    ----------
    names : segment names (the S axis).
    frame : earth frame of every array.
    q_segment : (N, S, 4) segment to earth.
    joints_m : (N, S, 3) m, each segment's joint; ``ends_m`` (N, S, 3) m, distal ends.
    """

    names: tuple[str, ...]
    frame: str
    q_segment: Array
    joints_m: Array
    ends_m: Array


def track(
    skeleton: Skeleton,
    calibration: Calibration,
    q_sensor: ArrayLike,
    root_position_m: ArrayLike | None = None,
) -> BodyPose:
    """Orientations and positions of every segment from sensor orientations (000, eqs. 7, 11).

    ``q_sensor`` (N, S, 4) or (S, 4) in the skeleton's order and frame; see
    :func:`segment_orientations` and :func:`positions`. A single frame gives N = 1.
    """
    q = segment_orientations(skeleton, calibration, q_sensor)
    if q.ndim == 2:
        q = q[None]
    joints, ends = positions(skeleton, q, root_position_m)
    return BodyPose(skeleton.names, skeleton.frame, q, joints, ends)


def resample_orientations(t_s: ArrayLike, q: ArrayLike, t_new_s: ArrayLike) -> Array:
    """Orientations at new times by slerp between the neighbouring samples.

    Parameters
    ----------
    t_s : (M,) s, strictly increasing sample times of ``q``.
    q : (M, 4) unit quaternions.
    t_new_s : (K,) s, inside ``[t_s[0], t_s[-1]]`` (sensors of one body sampled on their own
        clocks are brought onto one time base this way).

    Returns
    -------
    (K, 4) unit quaternions; the short way between neighbours.
    """
    t = np.asarray(t_s, dtype=np.float64)
    qa = np.asarray(q, dtype=np.float64)
    tn = np.asarray(t_new_s, dtype=np.float64)
    if t.ndim != 1 or qa.shape != (t.size, 4) or t.size < 2 or tn.ndim != 1:
        raise ValueError(
            f"need t_s (M,) with M >= 2, q (M, 4) and t_new_s (K,); got {t.shape}, {qa.shape}, "
            f"{tn.shape}"
        )
    if np.any(np.diff(t) <= 0):
        raise ValueError("t_s must be strictly increasing")
    if tn.size and (tn.min() < t[0] or tn.max() > t[-1]):
        raise ValueError(
            f"t_new_s spans [{tn.min()}, {tn.max()}] s, outside the samples' "
            f"[{t[0]}, {t[-1]}] s; orientations are interpolated, never extrapolated"
        )
    i = np.clip(np.searchsorted(t, tn, side="right") - 1, 0, t.size - 2)
    fraction = (tn - t[i]) / (t[i + 1] - t[i])
    return quat.slerp(qa[i], qa[i + 1], fraction)
