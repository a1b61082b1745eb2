"""Segment orientations without magnetometers: the joint constraint down the chain.

With ``--no-mag`` (``process_body(..., no_mag=True)``) no sensor's heading comes from a
magnetometer. :func:`chain_orientations`

1. estimates the root (pelvis) sensor with the chosen method and its magnetometer dropped
   (a 6-D estimate: inclination from gravity, heading the gyroscope's, free); the body's
   heading is then fixed on the reference pose by the pelvis sensor's forward axis
   (heading ``"pelvis"``), as without ``--no-mag``;
2. walks the skeleton parents first and, for every segment, estimates the relative
   orientation of its sensor w.r.t. its parent's sensor across the joint between them from
   both gyroscopes and accelerometers (:func:`margtrack.joint.relative_orientation`:
   ``q_rel = conj(q_parent) ⊗ q_child``, online or offline, the lever arms estimated from
   the same data), and chains it: ``q_child = q_parent ⊗ q_rel`` on the common time base.

So every segment's heading follows its parent's instead of drifting on its own gyroscope,
and the joint angles (which depend only on relative orientations) are drift-free. The
online joint filter cannot see the relative heading while the body stands still (gravity
alone does not fix a rotation about the vertical); it finds it once the joint moves.
:attr:`ChainOrientations.settled_s` says from when on every joint has moved for
:data:`SETTLE_S` (the child sensor turning faster than :data:`MOVING_RAD_S`): a reference
pose before that would calibrate with relative headings not yet found, so the workflow
looks for one after it. The offline estimate (``--offline``) uses the whole recording for
every sample and serves a reference pose at the start.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from margtrack import quaternion as qt
from margtrack.body.joints import JOINTS
from margtrack.body.kinematics import resample_orientations
from margtrack.recording import Recording
from margtrack.units import UnitError

if TYPE_CHECKING:
    from margtrack.body.skeleton import Skeleton
    from margtrack.joint.lever_arms import LeverArms

Array = NDArray[np.float64]

__all__ = ["MOVING_RAD_S", "SETTLE_S", "ChainOrientations", "ConstrainedJoint",
           "chain_orientations", "joint_name"]

#: A child sensor turning faster than this (rad/s) moves its joint (the online filter starts
#: to see the joint's relative heading).
MOVING_RAD_S = 0.5
#: Motion the online filter is given to find a joint's relative heading, s (a simulated
#: walk's knees: within 2 deg one second into the motion).
SETTLE_S = 1.0


@dataclass(frozen=True)
class ConstrainedJoint:
    """One joint whose constraint tied a segment's orientation to its parent's.

    joint : the joint's name (``left_knee``; ``<parent>-<child>`` for a pair of segments
        with no clinical joint angles, e.g. ``pelvis-trunk``).
    parent, child : the two segments; parent_sensor, child_sensor : their sensors.
    lever_arms : joint centre to each sensor (m, each sensor's frame; parent's row 0,
        child's row 1) with their standard deviations
        (:class:`~margtrack.joint.lever_arms.LeverArms`).
    method : ``"joint_online"`` or ``"joint_offline"``.
    notes : the joint estimate's notes (cropping, resampling, solver iterations).
    """

    joint: str
    parent: str
    child: str
    parent_sensor: str
    child_sensor: str
    lever_arms: LeverArms
    method: str
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class ChainOrientations:
    """What :func:`chain_orientations` returns, skeleton order throughout.

    q : (N, S, 4) sensor to earth on the common time base ``t``.
    sensor_flags : per sensor, (M,) uint16 flags on ``flag_times`` (the root's estimator
        flags on its own clock; a child's joint-estimate flags on the pair's time base).
    flag_times : per sensor, (M,) s.
    joints : the constrained joints, parents first.
    method, params : the root's estimation method and the parameters it used.
    settled_s : time on ``t``'s clock from which every joint's relative heading is found:
        ``t[0]`` offline, else :data:`SETTLE_S` after the last joint started to move
        (``inf`` when one never moves).
    """

    q: Array
    sensor_flags: tuple[NDArray[np.uint16], ...]
    flag_times: tuple[Array, ...]
    joints: tuple[ConstrainedJoint, ...]
    method: str
    params: Mapping[str, Any]
    settled_s: float


def joint_name(skeleton: Skeleton, child: int) -> str:
    """Name of the joint between segment ``child`` (index) and its parent (class docstring)."""
    parent = skeleton.names[skeleton.parents[child]]
    name = skeleton.names[child]
    side, _, kind = name.partition("_")
    for joint, (parent_kind, child_kind, _, _) in JOINTS.items():
        if kind == child_kind and parent in (parent_kind, f"{side}_{parent_kind}"):
            return f"{side}_{joint}"
    return f"{parent}-{name}"


def chain_orientations(
    skeleton: Skeleton,
    sensors: list[str],
    recs: Mapping[str, Recording],
    t: Array,
    method: str,
    param_values: Mapping[str, Any],
    frame: str,
    offline: bool = False,
) -> ChainOrientations:
    """Sensor orientations on ``t`` with the root 6-D and every other segment chained across
    its joint (module docstring).

    Parameters
    ----------
    skeleton : the body model; ``sensors[i]`` is the sensor on ``skeleton.names[i]``.
    recs : sensor name -> Recording (SI units; own clocks, already re-timed if asked).
    t : (N,) s, the common time base (inside every sensor's span).
    method, param_values : the root's estimation method and parameters (``-m``, ``-p``).
    frame : earth frame of the result, ``"ENU"`` or ``"NED"``.
    offline : the joints' offline (MAP) estimate instead of the online filter.

    Raises
    ------
    ValueError : the root's method cannot run without a magnetometer, or a joint cannot be
        estimated (too little motion for its lever arms...); the message names the sensor
        or joint and the fix.
    """
    from margtrack import methods
    from margtrack.joint import relative_orientation

    root = sensors[0]
    rec = recs[root]
    try:
        est = methods.create(method, param_values).run(replace(rec, mag=None)).in_frame(frame)
    except UnitError as exc:
        raise exc.prefixed(f"sensor {root}: ") from None
    except ValueError as exc:
        raise ValueError(f"sensor {root} (--no-mag, no magnetometer): {exc}") from None
    q = np.empty((t.size, len(sensors), 4))
    q[:, 0] = resample_orientations(rec.t, est.quat, t)
    zero = np.zeros(rec.n_samples, np.uint16)
    flags = [est.flags if est.flags is not None else zero]
    times = [rec.t]
    joints = []
    for i in range(1, len(sensors)):
        p = int(skeleton.parents[i])
        name = joint_name(skeleton, i)
        try:
            rel = relative_orientation(recs[sensors[p]], recs[sensors[i]], offline=offline)
        except UnitError as exc:
            raise exc.prefixed(f"joint {name} ({sensors[p]} -> {sensors[i]}): ") from None
        except ValueError as exc:
            raise ValueError(f"--no-mag: joint {name} ({sensors[p]} -> {sensors[i]}): "
                             f"{exc}") from None
        # the pair's time base covers the body's span up to its own grid's last step
        q_rel = resample_orientations(rel.t, rel.quat, np.clip(t, rel.t[0], rel.t[-1]))
        q[:, i] = qt.normalize(qt.multiply(q[:, p], q_rel))
        flags.append(rel.flags)
        times.append(rel.t)
        joints.append(ConstrainedJoint(name, skeleton.names[p], skeleton.names[i], sensors[p],
                                       sensors[i], rel.lever_arms, rel.method, rel.notes))
    settled = float(t[0])
    if not offline:
        for sensor in sensors[1:]:
            r = recs[sensor]
            moving = np.flatnonzero(np.linalg.norm(r.gyr, axis=1) > MOVING_RAD_S)
            settled = max(settled, float(r.t[moving[0]]) + SETTLE_S if moving.size else np.inf)
    return ChainOrientations(q, tuple(flags), tuple(times), tuple(joints), est.method,
                             dict(est.params), settled)
