"""Forward kinematics of the body model: segment orientations and joint positions (000, eqs. 7, 11).

Arrays are frames first, then segments in the skeleton's order: ``q`` (N, S, 4) or (S, 4),
positions (N, S, 3) or (S, 3) in metres, earth frame ``skeleton.frame`` (the leading N may
as well be people of one frame: the live engine's avatars). Everything is vectorised over
N and the segments (one rotation call for all segments); the only Python loop is the
running sum down the (at most 15) segments of the tree, one addition each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.body._checks import UNIT_NORM_TOLERANCE, sensor_quaternions
from margtrack.body.offsets import Calibration
from margtrack.body.skeleton import Skeleton
from margtrack.estimator.sensor_threads import in_threads, thread_count

Array = NDArray[np.float64]

#: segments (people x K) from which :func:`people_pose` shares its passes among threads:
#: about 16 ns a segment on one thread (3 ms at 183,750 sensors), and starting a thread
#: costs tens of microseconds
THREADED_MIN_SEGMENTS = 30_000
_NO_COPY = np.empty((0, 4))  # first_non_unit's "no copy"

__all__ = ["BodyPose", "people_pose", "positions", "resample_orientations", "segment_orientations",
           "track"]


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
    n_seg = len(skeleton)
    joints = np.empty((*lead, n_seg, 3))
    joints[..., 0, :] = root
    if n_seg > 1:
        # every segment's offset rotated by its parent's orientation in one call (eq. 11)
        parents = np.asarray(skeleton.parents[1:], dtype=np.intp)
        steps = quat.rotate(q[..., parents, :], skeleton.offsets_m[1:])
        for i in range(1, n_seg):  # parents come first: a running sum down the tree
            joints[..., i, :] = joints[..., skeleton.parents[i], :] + steps[..., i - 1, :]
    ends = joints + quat.rotate(q, skeleton.ends_m)
    return joints, ends


def people_pose(
    skeleton: Skeleton, q_sensor: ArrayLike, index: ArrayLike, q_offset: ArrayLike,
    roots_m: ArrayLike, q_copy: Array | None = None,
) -> tuple[Array, Array, Array]:
    """One frame of A people wearing sensors on the K segments of ``skeleton`` (000, eqs. 7, 11).

    ``q_segment[a, k] = q_sensor[index[a, k]] ⊗ q_offset[a, k]`` with ``w >= 0``, then
    :func:`positions` of every person from its root: the same operations as
    :func:`segment_orientations` (without the time continuity) and :func:`positions`, to
    the last bit, in one compiled pass over people and segments
    (:mod:`margtrack.body.pose_kernel`), shared among threads from
    ``THREADED_MIN_SEGMENTS`` segments: the live engine's avatars.

    Parameters
    ----------
    skeleton : the body model (K segments), in the frame of ``q_sensor``.
    q_sensor : (S, 4) unit quaternions, sensor to earth.
    index : (A, K) int, the sensor of each person's segment (skeleton order).
    q_offset : (A, K, 4) each person's ``q_offset`` (:func:`margtrack.body.calibrate`).
    roots_m : (A, 3) m, each person's root joint.
    q_copy : (S, 4) float64 C-contiguous, or None: receives a copy of ``q_sensor``, made
        in the unit check's pass (one pass over the sensors instead of two).

    Returns
    -------
    q_segment (A, K, 4), joints_m (A, K, 3) m, ends_m (A, K, 3) m.
    """
    from margtrack.body.pose_kernel import first_non_unit
    from margtrack.body.pose_kernel import people_pose as kernel

    q = np.ascontiguousarray(q_sensor, dtype=np.float64)
    idx = np.ascontiguousarray(index, dtype=np.intp)
    off = np.ascontiguousarray(q_offset, dtype=np.float64)
    roots = np.ascontiguousarray(roots_m, dtype=np.float64)
    n_seg = len(skeleton)
    if q.ndim != 2 or q.shape[1] != 4:
        raise ValueError(f"q_sensor must have shape (S, 4), got {q.shape}")
    if idx.ndim != 2 or idx.shape[1] != n_seg or off.shape != (*idx.shape, 4) \
            or roots.shape != (idx.shape[0], 3):
        raise ValueError(f"need index (A, {n_seg}), q_offset (A, {n_seg}, 4) and roots_m (A, 3) "
                         f"for the {n_seg} segments; got {idx.shape}, {off.shape}, {roots.shape}")
    if idx.size and (idx.min() < 0 or idx.max() >= q.shape[0]):
        raise ValueError(f"index must name sensors 0..{q.shape[0] - 1}, got "
                         f"{int(idx.min())}..{int(idx.max())}")
    if q_copy is None:
        out = _NO_COPY
    elif (q_copy.shape != q.shape or q_copy.dtype != np.float64
          or not q_copy.flags.c_contiguous or not q_copy.flags.writeable):
        raise ValueError(f"q_copy must be a writeable C-contiguous float64 array of shape "
                         f"{q.shape}, got {q_copy.dtype} {q_copy.shape}")
    else:
        out = q_copy
    n_threads = thread_count() if idx.size >= THREADED_MIN_SEGMENTS else 1
    found: list[tuple[int, float]] = [(-1, 1.0)] * n_threads
    sensor_edges = [q.shape[0] * k // n_threads for k in range(n_threads + 1)]

    def check(k: int) -> None:
        found[k] = first_non_unit(q, UNIT_NORM_TOLERANCE, sensor_edges[k], sensor_edges[k + 1],
                                  out)

    in_threads(check, n_threads, "margtrack-pose")
    for s, norm in found:  # the first of the parts in sensor order
        if s >= 0:
            raise ValueError(f"q_sensor[{s}] is not a unit quaternion (norm {float(norm)!r}); "
                             "normalise it (margtrack.quaternion.normalize)")
    q_segment = np.empty(off.shape)
    joints = np.empty(roots.shape[:1] + (n_seg, 3))
    ends = np.empty_like(joints)
    parents = np.asarray(skeleton.parents, dtype=np.intp)
    offsets_m = np.ascontiguousarray(skeleton.offsets_m)
    ends_m = np.ascontiguousarray(skeleton.ends_m)
    people_edges = [idx.shape[0] * k // n_threads for k in range(n_threads + 1)]

    def pose(k: int) -> None:
        kernel(q, idx, off, parents, offsets_m, ends_m, roots, q_segment, joints, ends,
               people_edges[k], people_edges[k + 1])

    in_threads(pose, n_threads, "margtrack-pose")
    return q_segment, joints, ends


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
