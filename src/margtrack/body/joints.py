"""Joint angles (hip, knee, ankle, shoulder, elbow) from relative segment orientations.

The relative orientation of a child segment in its parent's frame is
``q_rel = q_parent* ⊗ q_child``; it is the identity in the reference pose, where all segment
frames coincide. It is decomposed in the parent's anatomical axes (:func:`body_axes`):
``X`` medio-lateral (pointing right), ``Y`` antero-posterior (forward), ``Z`` longitudinal
(up), as the intrinsic Cardan sequence X-Y'-Z'' (flexion/extension about the medio-lateral
axis first, then ab/adduction about the floating forward axis, then axial rotation about the
child's long axis; the order of Grood & Suntay 1983 and the ISB hip/knee/ankle
recommendations, Wu et al. 2002):

    R_rel = Rx(α) · Ry(β) · Rz(γ),   α, γ in (-180, 180] deg, β in [-90, 90] deg

The reported components are signed so that the usual clinical sense is positive on both
sides (derived for a right-handed R-F-U axis set; L/R = left/right side):

=========  =================  ======================  ======================
joint      component 1        component 2             component 3
=========  =================  ======================  ======================
hip        flexion = α        abduction = -β R, +β L  internal rot. = γ R, -γ L
knee       flexion = -α       abduction = -β R, +β L  internal rot. = γ R, -γ L
ankle      dorsiflexion = α   inversion = β R, -β L   internal rot. = γ R, -γ L
shoulder   flexion = α        abduction = -β R, +β L  internal rot. = γ R, -γ L
elbow      flexion = α        abduction = -β R, +β L  pronation = γ R, -γ L
=========  =================  ======================  ======================

(Hip flexion swings the thigh's distal end forward: ``Rx(α) [0, 0, -1] = [0, sin α, -cos α]``;
knee flexion swings the shank back, hence ``-α``.) The X-Y-Z sequence is singular at
``β = ±90 deg`` (e.g. a shoulder abducted to the horizontal and flexed); there ``γ`` is set
to 0 and the combined rotation goes to ``α``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.body._checks import sensor_quaternions
from margtrack.body.skeleton import Skeleton, body_axes

Array = NDArray[np.float64]

__all__ = ["JOINTS", "JointAngles", "cardan_xyz", "joint_angles"]

#: joint kind: (parent kind, child kind, component names, signs of (α, β, γ) on the right).
JOINTS: Mapping[str, tuple[str, str, tuple[str, str, str], tuple[float, float, float]]] = (
    MappingProxyType({
        "hip": ("pelvis", "thigh", ("flexion", "abduction", "internal_rotation"), (1, -1, 1)),
        "knee": ("thigh", "shank", ("flexion", "abduction", "internal_rotation"), (-1, -1, 1)),
        "ankle": ("shank", "foot", ("dorsiflexion", "inversion", "internal_rotation"),
                  (1, 1, 1)),
        "shoulder": ("trunk", "upper_arm", ("flexion", "abduction", "internal_rotation"),
                     (1, -1, 1)),
        "elbow": ("upper_arm", "forearm", ("flexion", "abduction", "pronation"), (1, -1, 1)),
    })
)

_SIDES = {"right": np.array([1.0, 1.0, 1.0]), "left": np.array([1.0, -1.0, -1.0])}


def cardan_xyz(q: ArrayLike) -> Array:
    """Intrinsic X-Y'-Z'' angles ``[α, β, γ]`` (..., 3) in rad of rotations ``q`` (..., 4).

    ``to_matrix(q) = Rx(α) Ry(β) Rz(γ)``; scipy: ``Rotation.as_euler("XYZ")``. Computed from
    the matrix, so ``q`` and ``-q`` give the same angles. At ``cos β < 1e-9`` (gimbal lock)
    ``γ = 0`` and ``α`` carries the combined rotation.
    """
    r = quat.to_matrix(quat.normalize(q))
    # R = [[cβcγ, -cβsγ, sβ], [., ., -sαcβ], [., ., cαcβ]]
    cos_beta = np.hypot(r[..., 1, 2], r[..., 2, 2])
    beta = np.arctan2(r[..., 0, 2], cos_beta)
    locked = cos_beta < 1e-9
    alpha = np.where(
        locked, np.arctan2(r[..., 2, 1], r[..., 1, 1]), np.arctan2(-r[..., 1, 2], r[..., 2, 2])
    )
    gamma = np.where(locked, 0.0, np.arctan2(-r[..., 0, 1], r[..., 0, 0]))
    return np.stack([alpha, beta, gamma], axis=-1)


@dataclass(frozen=True, eq=False)
class JointAngles:
    """Joint angles of a skeleton over N frames.

    Attributes
    ----------
    names : (J,) joint names, e.g. ``"right_knee"``.
    components : per joint, the names of its three angles (see the module table).
    angles_rad : (N, J, 3) or (J, 3) rad.
    sequence : ``"XYZ"`` intrinsic Cardan in the parent's (right, forward, up) axes.
    """

    names: tuple[str, ...]
    components: tuple[tuple[str, str, str], ...]
    angles_rad: Array
    sequence: str = "XYZ"

    def degrees(self, joint: str) -> Array:
        """(N, 3) or (3,) angles of ``joint`` in deg; ``ValueError`` if it is not computed."""
        if joint not in self.names:
            raise ValueError(
                f"no joint {joint!r}; this skeleton's joints: {', '.join(self.names) or 'none'}"
            )
        return np.degrees(self.angles_rad[..., self.names.index(joint), :])

    def columns(self) -> list[str]:
        """Flat column names ``<joint>_<component>``, joints in order."""
        return [f"{j}_{c}" for j, comps in zip(self.names, self.components, strict=True)
                for c in comps]


def _joint_list(skeleton: Skeleton) -> list[tuple[str, int, int, tuple[str, str, str], Array]]:
    joints = []
    for kind, (parent_kind, child_kind, comps, signs) in JOINTS.items():
        for side, side_signs in _SIDES.items():
            parent = parent_kind if parent_kind in ("pelvis", "trunk") else f"{side}_{parent_kind}"
            child = f"{side}_{child_kind}"
            if parent in skeleton.names and child in skeleton.names:
                ip, ic = skeleton.names.index(parent), skeleton.names.index(child)
                if skeleton.parents[ic] == ip:
                    sign = np.asarray(signs, dtype=np.float64) * side_signs
                    joints.append((f"{side}_{kind}", ip, ic, comps, sign))
    return joints


def joint_angles(skeleton: Skeleton, q_segment: ArrayLike) -> JointAngles:
    """Angles of every hip, knee, ankle, shoulder and elbow whose two segments are present.

    Parameters
    ----------
    skeleton : the body model.
    q_segment : (N, S, 4) or (S, 4) segment orientations (:func:`segment_orientations`).

    Returns
    -------
    :class:`JointAngles` (rad), zero in the reference pose; ``q_segment`` and ``-q_segment``
    give identical angles.
    """
    q = sensor_quaternions(q_segment, skeleton, "q_segment")
    joints = _joint_list(skeleton)
    right, forward, upward = body_axes(skeleton.frame)
    # c maps anatomical (right, forward, up) coordinates to segment-frame coordinates, so
    # c* ⊗ q_rel ⊗ c is q_rel written in anatomical axes (c = 1 in ENU).
    c = quat.from_matrix(np.stack([right, forward, upward], axis=-1))
    lead = q.shape[:-2]
    angles = np.empty((*lead, len(joints), 3))
    for k, (_, ip, ic, _, sign) in enumerate(joints):
        q_rel = quat.multiply(quat.conjugate(q[..., ip, :]), q[..., ic, :])
        q_anat = quat.multiply(quat.multiply(quat.conjugate(c), q_rel), c)
        angles[..., k, :] = cardan_xyz(q_anat) * sign
    return JointAngles(
        tuple(j[0] for j in joints), tuple(j[3] for j in joints), angles
    )
