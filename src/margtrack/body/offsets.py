"""Sensor-to-segment offsets from a still reference pose (000, eqs. 8-10).

In the reference pose every segment frame is aligned with the heading reference (module
docstring of :mod:`margtrack.body.skeleton`). The paper's reference is magnetic north: the
segment frames equal the earth frame, so ``q_sensor ⊗ q_offset = 1`` (000, eq. 9) and

    q_offset = q_sensor*                                         (000, eq. 10)

With ``heading="pelvis"`` the person may face any direction: the facing direction is read
from the pelvis sensor (a sensor axis the user names as pointing forward), ``q_h`` is the
rotation about the vertical from north to that direction, and eq. 9 becomes
``q_sensor ⊗ q_offset = q_h``, so ``q_offset = q_sensor* ⊗ q_h``. Either way
``q_segment = q_sensor ⊗ q_offset`` (000, eq. 7) is ``q_h`` in the reference pose, and a
mounting rotation ``q_m`` (``q_sensor = q_segment ⊗ q_m``) cancels: ``q_offset = q_m*``.

``q_sensor`` is averaged over the still window rather than taken from one sample: the
eigenvector method of Markley, Cheng, Crassidis & Oshman (2007), "Averaging Quaternions",
J. Guidance, Control, and Dynamics 30(4): the mean is the unit eigenvector of the largest
eigenvalue of ``M = Σ q qᵀ``. It minimises the summed squared chordal (Frobenius) distances
of the rotation matrices, and ``q qᵀ = (-q)(-q)ᵀ`` makes it blind to the signs of the
samples, so no sign alignment is needed (it equals scipy's ``Rotation.mean``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.body._checks import frame_times, sensor_quaternions
from margtrack.body.skeleton import Skeleton, body_axes
from margtrack.frames import Frame

Array = NDArray[np.float64]

__all__ = ["Calibration", "average_quaternions", "calibrate", "still_window"]

Heading = Literal["north", "pelvis"]

# Below this horizontal fraction of the forward axis (tilt above ~78 deg) its heading is noise.
_MIN_HORIZONTAL = 0.2


def average_quaternions(q: ArrayLike) -> Array:
    """Mean orientation of each sensor over a window (Markley et al. 2007 eigenvector method).

    Parameters
    ----------
    q : (N, S, 4) or (N, 4) unit quaternions, samples first; signs may be mixed.

    Returns
    -------
    (S, 4) or (4,) unit quaternions with ``w >= 0``.
    """
    arr = np.asarray(q, dtype=np.float64)
    if arr.ndim not in (2, 3) or arr.shape[-1] != 4 or arr.shape[0] == 0:
        raise ValueError(f"q must have shape (N, 4) or (N, S, 4) with N >= 1, got {arr.shape}")
    single = arr.ndim == 2
    if single:
        arr = arr[:, None, :]
    m = np.einsum("nsi,nsj->sij", arr, arr)  # M = Σ q qᵀ per sensor
    _, vectors = np.linalg.eigh(m)  # eigenvalues ascending
    mean = quat.canonical(quat.normalize(vectors[:, :, -1]))
    return mean[0] if single else mean


def still_window(
    t_s: ArrayLike,
    q: ArrayLike,
    duration_s: float = 1.0,
    max_motion_deg: float = 2.0,
) -> slice:
    """The first window of ``duration_s`` in which no sensor turns by more than ``max_motion_deg``.

    Parameters
    ----------
    t_s : (N,) s, strictly increasing.
    q : (N, S, 4) orientations of S sensors (e.g. the device's own estimate).
    duration_s : length of the window, s (000 holds the reference pose; a second is enough
        to average out sensor noise).
    max_motion_deg : largest rotation, deg, of any sample from the window's first sample.

    Returns
    -------
    ``slice(i, j)`` of the samples in the window; ``ValueError`` if there is none.
    """
    arr = np.asarray(q, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[-1] != 4:
        raise ValueError(f"q must have shape (N, S, 4), got {arr.shape}")
    t = frame_times(t_s, arr.shape[0])
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s must be a finite number of seconds > 0, got {duration_s}")
    if not (np.isfinite(max_motion_deg) and max_motion_deg > 0):
        raise ValueError(f"max_motion_deg must be > 0, got {max_motion_deg}")
    limit = np.radians(max_motion_deg)
    ends = np.searchsorted(t, t + duration_s, side="left")  # first sample past each window
    n_window = max(int(np.median(ends - np.arange(t.size))), 1)
    step = max(n_window // 10, 1)
    for i in range(0, t.size, step):  # a coarse scan over windows, not over frames
        if t[-1] - t[i] < duration_s:
            break
        j = int(ends[i])
        angles = quat.angle_between(arr[i][None], arr[i:j])
        if np.max(angles) <= limit:
            return slice(i, j)
    raise ValueError(
        f"no still window of {duration_s} s found (every sensor within {max_motion_deg} deg); "
        "record the reference pose standing still, or raise max_motion_deg"
    )


@dataclass(frozen=True, eq=False)
class Calibration:
    """Sensor-to-segment offsets of one skeleton, from a reference pose.

    Attributes
    ----------
    names : segment names, the skeleton's order.
    frame : earth frame of the sensor orientations.
    offsets : (S, 4) ``q_offset`` per segment (000, eq. 10).
    heading : ``"north"`` or ``"pelvis"``.
    heading_quat : (4,) ``q_h``, rotation about the vertical from north to the facing
        direction (identity for ``"north"``).
    facing_deg : compass heading of the facing direction, deg clockwise from north.
    spread_deg : (S,) largest angle, deg, of a window sample from its sensor's mean: how still
        the pose was held.
    """

    names: tuple[str, ...]
    frame: Frame
    offsets: Array
    heading: Heading
    heading_quat: Array
    facing_deg: float
    spread_deg: Array

    def check(self, skeleton: Skeleton) -> None:
        """Raise ``ValueError`` unless this calibration was made for ``skeleton``."""
        if self.names != skeleton.names or self.frame != skeleton.frame:
            raise ValueError(
                f"calibration is for segments {self.names} in {self.frame}, but the skeleton "
                f"has {skeleton.names} in {skeleton.frame}; calibrate with this skeleton"
            )


def calibrate(
    skeleton: Skeleton,
    q_sensor: ArrayLike,
    heading: Heading = "north",
    forward_axis: ArrayLike | None = None,
    max_spread_deg: float = 5.0,
) -> Calibration:
    """Offsets ``q_offset`` from sensor orientations recorded in the reference pose.

    Parameters
    ----------
    skeleton : the body model; its ``frame`` is the earth frame of ``q_sensor``.
    q_sensor : (N, S, 4) orientations over a still window (e.g. :func:`still_window`), or
        (S, 4) for one sample; segment order of ``skeleton``.
    heading : ``"north"``: the subject faces magnetic north in the reference pose (000);
        ``"pelvis"``: the subject faces the horizontal direction of ``forward_axis`` of the
        pelvis sensor (the root's sensor if the skeleton has no pelvis, e.g. an arm).
    forward_axis : (3,) the pelvis sensor's axis, in its own frame, that points forward out
        of the body (e.g. ``[0, 0, -1]`` for a sensor on the sacrum with z pointing back).
        Required with ``heading="pelvis"``; any length.
    max_spread_deg : largest accepted angle, deg, of a window sample from its mean; a sensor
        that moved more raises ``ValueError``.

    Returns
    -------
    :class:`Calibration` with ``q_offset = q̄_sensor* ⊗ q_h`` (000, eq. 10 for ``q_h = 1``).
    """
    q = sensor_quaternions(q_sensor, skeleton, "q_sensor")
    if q.ndim == 2:
        q = q[None]
    if heading not in ("north", "pelvis"):
        raise ValueError(f"heading must be 'north' or 'pelvis', got {heading!r}")
    if not (np.isfinite(max_spread_deg) and max_spread_deg > 0):
        raise ValueError(f"max_spread_deg must be > 0, got {max_spread_deg}")
    mean = average_quaternions(q)
    spread = np.degrees(quat.angle_between(mean[None], q).max(axis=0))
    moved = np.flatnonzero(spread > max_spread_deg)
    if moved.size:
        i = int(moved[0])
        raise ValueError(
            f"sensor {skeleton.names[i]} turned {spread[i]:.1f} deg from its mean during the "
            f"reference pose (max_spread_deg = {max_spread_deg}); hold still in the pose or "
            "pick a still window (still_window)"
        )
    right, north, upward = body_axes(skeleton.frame)
    if heading == "north":
        if forward_axis is not None:
            raise ValueError("forward_axis is only used with heading='pelvis'")
        q_h = quat.identity()
        facing = north
    else:
        if forward_axis is None:
            raise ValueError(
                "heading='pelvis' needs forward_axis: the pelvis sensor's axis (in its own "
                "frame) that points forward, e.g. [0, 0, -1]"
            )
        axis = np.asarray(forward_axis, dtype=np.float64)
        if axis.shape != (3,) or not np.all(np.isfinite(axis)) or not np.linalg.norm(axis) > 0:
            raise ValueError(f"forward_axis must be a non-zero 3-vector, got {forward_axis!r}")
        ref = skeleton.index("pelvis") if "pelvis" in skeleton.names else 0
        f = quat.rotate(mean[ref], axis / np.linalg.norm(axis))
        facing = f - np.dot(f, upward) * upward
        if np.linalg.norm(facing) < _MIN_HORIZONTAL:
            raise ValueError(
                f"forward_axis {axis.tolist()} of the {skeleton.names[ref]} sensor points within "
                f"{np.degrees(np.arccos(_MIN_HORIZONTAL)):.0f} deg of the vertical in the "
                "reference pose, so it gives no heading; name an axis that points forward"
            )
        facing = facing / np.linalg.norm(facing)
        psi = np.arctan2(np.dot(np.cross(north, facing), upward), np.dot(north, facing))
        q_h = quat.from_axis_angle(upward, psi)
    offsets = quat.multiply(quat.conjugate(mean), q_h)  # 000 eq. 10 (times q_h)
    facing_deg = float(np.degrees(np.arctan2(np.dot(facing, right), np.dot(facing, north))))
    for arr in (offsets, q_h, spread):
        arr.setflags(write=False)
    return Calibration(
        skeleton.names, skeleton.frame, offsets, heading, q_h, facing_deg, spread
    )
