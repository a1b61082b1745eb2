"""Quaternion algebra and conversions over plain float64 arrays.

Conventions (see ``docs/conventions.md``):

- a quaternion is an array of shape ``(..., 4)`` in the order ``[w, x, y, z]``;
- the product is Hamilton's (``i*j = k``);
- ``q`` is the orientation of the sensor (body) frame relative to the earth frame, so
  ``v_earth = q ⊗ v_body ⊗ q*`` (:func:`rotate`) and ``v_body = q* ⊗ v_earth ⊗ q``
  (:func:`rotate_inverse`);
- every function broadcasts over leading axes like numpy, and angles are in radians.

Functions that need a unit quaternion assume one; :func:`normalize` makes it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

__all__ = [
    "angle_between",
    "canonical",
    "conjugate",
    "continuous",
    "from_axis_angle",
    "from_euler",
    "from_matrix",
    "from_rotvec",
    "identity",
    "integrate",
    "inverse",
    "multiply",
    "normalize",
    "rate",
    "rotate",
    "rotate_inverse",
    "shortest_arc",
    "slerp",
    "to_axis_angle",
    "to_euler",
    "to_matrix",
    "to_rotvec",
]


def _quat(q: ArrayLike, name: str = "q") -> Array:
    arr = np.asarray(q, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 4:
        raise ValueError(f"{name} must have shape (..., 4) in [w, x, y, z] order, got {arr.shape}")
    return arr


def _vec(v: ArrayLike, name: str = "v") -> Array:
    arr = np.asarray(v, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3), got {arr.shape}")
    return arr


def identity(shape: int | tuple[int, ...] = ()) -> Array:
    """Identity quaternion(s) ``[1, 0, 0, 0]`` of the given leading shape."""
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    q = np.zeros((*shape, 4))
    q[..., 0] = 1.0
    return q


def multiply(p: ArrayLike, q: ArrayLike) -> Array:
    """Hamilton product ``p ⊗ q`` of quaternions of shape ``(..., 4)`` (004, Definitions)."""
    p = _quat(p, "p")
    q = _quat(q, "q")
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def conjugate(q: ArrayLike) -> Array:
    """Conjugate ``q* = [w, -x, -y, -z]``; the inverse of a unit quaternion."""
    q = _quat(q)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def inverse(q: ArrayLike) -> Array:
    """Inverse ``q* / |q|²`` of any non-zero quaternion; raises ``ValueError`` on zero norm."""
    q = _quat(q)
    norm2 = np.sum(q * q, axis=-1, keepdims=True)
    _check_nonzero(norm2[..., 0], "inverse")
    return conjugate(q) / norm2


def _check_nonzero(norm: Array, what: str) -> None:
    bad = ~(norm > 0.0) | ~np.isfinite(norm)
    if np.any(bad):
        index = tuple(int(i) for i in np.argwhere(bad)[0]) if np.ndim(norm) else ()
        raise ValueError(
            f"cannot {what} a quaternion of zero or non-finite norm (first at index {index})"
        )


def normalize(q: ArrayLike) -> Array:
    """Scale ``q`` to unit norm; raises ``ValueError`` naming the first zero-norm entry."""
    q = _quat(q)
    norm = np.linalg.norm(q, axis=-1)
    _check_nonzero(norm, "normalize")
    return q / norm[..., None]


def canonical(q: ArrayLike) -> Array:
    """The same rotation with ``w >= 0`` (``q`` and ``-q`` are one rotation)."""
    q = _quat(q)
    return np.where(q[..., :1] < 0.0, -q, q)


def continuous(q: ArrayLike) -> Array:
    """Flip signs along axis -2 so consecutive quaternions of a series have a positive dot product.

    Shape ``(..., N, 4)``. Useful before averaging, interpolating or plotting a series
    (002's closing remark on choosing between ``q`` and ``-q``).
    """
    q = _quat(q)
    if q.ndim < 2:
        return q.copy()
    dots = np.sum(q[..., 1:, :] * q[..., :-1, :], axis=-1)
    flips = np.cumsum(dots < 0.0, axis=-1) % 2
    sign = np.concatenate([np.ones((*q.shape[:-2], 1)), 1.0 - 2.0 * flips], axis=-1)
    return q * sign[..., None]


def rotate(q: ArrayLike, v: ArrayLike) -> Array:
    """Rotate body-frame vectors into the earth frame: ``q ⊗ v ⊗ q*``.

    ``q`` (..., 4) unit, ``v`` (..., 3); leading axes broadcast.
    """
    q = _quat(q)
    v = _vec(v)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def rotate_inverse(q: ArrayLike, v: ArrayLike) -> Array:
    """Rotate earth-frame vectors into the body frame: ``q* ⊗ v ⊗ q`` (000 eq. 13)."""
    return rotate(conjugate(q), v)


def to_matrix(q: ArrayLike) -> Array:
    """Rotation matrix ``R`` (..., 3, 3) with ``v_earth = R @ v_body`` for unit ``q``."""
    q = _quat(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def from_matrix(matrix: ArrayLike) -> Array:
    """Unit quaternion (w >= 0) of rotation matrices ``(..., 3, 3)``.

    Uses the four branches of 004 ("To convert from a rotation matrix into a quaternion"):
    the branch is chosen by the largest of ``trace, R11, R22, R33`` so the divisor ``n`` is
    never small. The extracted text of 004 has sign/index slips in branches two to four
    (for example ``y = (R12 - R21)/n`` instead of ``(R12 + R21)/n``); the sums used here
    are derived from ``to_matrix`` and tested by round trip.
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.ndim < 2 or m.shape[-2:] != (3, 3):
        raise ValueError(f"matrix must have shape (..., 3, 3), got {m.shape}")
    r11, r12, r13 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    r21, r22, r23 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    r31, r32, r33 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    trace = r11 + r22 + r33
    branch = np.argmax(np.stack([trace, r11, r22, r33], axis=-1), axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        n0 = 2.0 * np.sqrt(np.maximum(1.0 + trace, 0.0))
        n1 = 2.0 * np.sqrt(np.maximum(1.0 + r11 - r22 - r33, 0.0))
        n2 = 2.0 * np.sqrt(np.maximum(1.0 + r22 - r11 - r33, 0.0))
        n3 = 2.0 * np.sqrt(np.maximum(1.0 + r33 - r11 - r22, 0.0))
        candidates = np.stack(
            [
                np.stack([n0 / 4, (r32 - r23) / n0, (r13 - r31) / n0, (r21 - r12) / n0], -1),
                np.stack([(r32 - r23) / n1, n1 / 4, (r12 + r21) / n1, (r13 + r31) / n1], -1),
                np.stack([(r13 - r31) / n2, (r12 + r21) / n2, n2 / 4, (r23 + r32) / n2], -1),
                np.stack([(r21 - r12) / n3, (r13 + r31) / n3, (r23 + r32) / n3, n3 / 4], -1),
            ],
            axis=-2,
        )
    q = np.take_along_axis(candidates, branch[..., None, None], axis=-2)[..., 0, :]
    return canonical(normalize(q))


def to_euler(q: ArrayLike) -> Array:
    """Aerospace ZYX Euler angles ``[yaw, pitch, roll]`` (..., 3) in rad (002's sequence).

    ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``; yaw and roll in (-pi, pi], pitch in [-pi/2, pi/2].
    At gimbal lock (``|pitch| = pi/2``) only yaw -/+ roll is defined; roll is set to 0 there.
    """
    q = normalize(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    # With c, s = cos(pitch/2), sin(pitch/2) and q = q_z(yaw) ⊗ q_y(pitch) ⊗ q_x(roll):
    #   w + y = (c + s) cos((yaw - roll)/2),  z - x = (c + s) sin((yaw - roll)/2),
    #   w - y = (c - s) cos((yaw + roll)/2),  z + x = (c - s) sin((yaw + roll)/2).
    # These half-angle sums keep full precision up to and at gimbal lock, where the usual
    # atan2 of matrix entries divides two vanishing numbers.
    a_plus = np.hypot(w + y, z - x)  # sqrt(2) sin(pitch/2 + pi/4)
    a_minus = np.hypot(w - y, z + x)  # sqrt(2) cos(pitch/2 + pi/4)
    pitch = 2.0 * np.arctan2(a_plus, a_minus) - 0.5 * np.pi
    diff = 2.0 * np.arctan2(z - x, w + y)  # yaw - roll
    total = 2.0 * np.arctan2(z + x, w - y)  # yaw + roll
    yaw = 0.5 * (total + diff)
    roll = 0.5 * (total - diff)
    locked = a_plus * a_minus < 1e-12  # = cos(pitch)
    yaw = np.where(locked, np.where(a_minus < a_plus, diff, total), yaw)
    roll = np.where(locked, 0.0, roll)
    return np.stack([_wrap(_wrap(yaw)), pitch, _wrap(roll)], axis=-1)


def _wrap(angle: Array) -> Array:
    """Angles into (-pi, pi] (one turn of correction)."""
    return np.where(
        angle <= -np.pi, angle + 2 * np.pi, np.where(angle > np.pi, angle - 2 * np.pi, angle)
    )


def from_euler(angles: ArrayLike) -> Array:
    """Unit quaternion from ZYX Euler angles ``[yaw, pitch, roll]`` (..., 3) in rad.

    ``q = q_z(yaw) ⊗ q_y(pitch) ⊗ q_x(roll)`` (aerospace sequence, 002).
    """
    a = _vec(angles, "angles")
    half = 0.5 * a
    cy, cp, cr = np.cos(half[..., 0]), np.cos(half[..., 1]), np.cos(half[..., 2])
    sy, sp, sr = np.sin(half[..., 0]), np.sin(half[..., 1]), np.sin(half[..., 2])
    return np.stack(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ],
        axis=-1,
    )


def from_rotvec(rotvec: ArrayLike) -> Array:
    """Quaternion exponential: rotation vector ``angle * axis`` (..., 3) rad to unit quaternion."""
    r = _vec(rotvec, "rotvec")
    angle = np.linalg.norm(r, axis=-1)
    half = 0.5 * angle
    # sin(half)/angle with its Taylor series near zero, where the quotient is 0/0
    small = angle < 1e-6
    safe = np.where(small, 1.0, angle)
    scale = np.where(small, 0.5 - angle * angle / 48.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half)[..., None], r * scale[..., None]], axis=-1)


def to_rotvec(q: ArrayLike) -> Array:
    """Quaternion logarithm: rotation vector (..., 3) in rad with angle in [0, pi]."""
    q = canonical(normalize(q))
    v = q[..., 1:]
    sin_half = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(sin_half, q[..., 0])
    small = sin_half < 1e-9
    safe = np.where(small, 1.0, sin_half)
    scale = np.where(small, 2.0 / np.maximum(q[..., 0], 1e-300), angle / safe)
    return v * scale[..., None]


def from_axis_angle(axis: ArrayLike, angle: ArrayLike) -> Array:
    """Unit quaternion rotating by ``angle`` (rad) about ``axis`` (..., 3, any non-zero length)."""
    axis = _vec(axis, "axis")
    norm = np.linalg.norm(axis, axis=-1)
    if np.any(~(norm > 0.0)):
        raise ValueError("axis must be a non-zero vector")
    unit = axis / norm[..., None]
    return from_rotvec(unit * np.asarray(angle, dtype=np.float64)[..., None])


def to_axis_angle(q: ArrayLike) -> tuple[Array, Array]:
    """Unit axis (..., 3) and angle (...) in [0, pi] rad; axis ``[1, 0, 0]`` for no rotation."""
    r = to_rotvec(q)
    angle = np.linalg.norm(r, axis=-1)
    small = angle < 1e-15
    axis = np.where(
        small[..., None], np.array([1.0, 0.0, 0.0]), r / np.where(small, 1.0, angle)[..., None]
    )
    return axis, angle


def shortest_arc(u: ArrayLike, v: ArrayLike) -> Array:
    """Smallest rotation ``q`` with ``rotate(q, û) = v̂`` (004, "shortest arc").

    ``u`` and ``v`` (..., 3) need not be unit length but must be non-zero. For parallel
    vectors this is the identity; for antiparallel vectors (where 004's cross-product
    formula is undefined) it is a half turn about an axis perpendicular to ``u``.
    """
    u = _vec(u, "u")
    v = _vec(v, "v")
    nu = np.linalg.norm(u, axis=-1)
    nv = np.linalg.norm(v, axis=-1)
    if np.any(~(nu > 0.0)) or np.any(~(nv > 0.0)):
        raise ValueError("shortest_arc needs non-zero vectors u and v")
    u, v = np.broadcast_arrays(u / nu[..., None], v / nv[..., None])
    dot = np.sum(u * v, axis=-1)
    # w = s/2 and xyz = u×v/s with s = sqrt(2(1 + u·v)) is 004's form; scaling by s gives
    # [1 + u·v, u×v], whose normalisation stays accurate until u·v reaches -1.
    cross = np.cross(u, v)
    q = np.concatenate([(1.0 + dot)[..., None], cross], axis=-1)
    obtuse = dot < 0.0
    if np.any(obtuse):
        # [1 + u·v, u×v] loses digits as u·v -> -1; the same quaternion scaled by
        # (1 - u·v)/|u×v| is [|u×v|, (1 - u·v) axis], with the axis made exactly
        # perpendicular to u (any perpendicular axis when u×v vanishes: antiparallel).
        perp = cross - np.sum(cross * u, axis=-1, keepdims=True) * u
        n = np.linalg.norm(perp, axis=-1, keepdims=True)
        fallback = np.cross(u, np.eye(3)[np.argmin(np.abs(u), axis=-1)])
        axis = np.where(n > 0.0, perp, fallback)
        axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
        q_obtuse = np.concatenate([n, (1.0 - dot)[..., None] * axis], axis=-1)
        q = np.where(obtuse[..., None], q_obtuse, q)
    return normalize(q)


def slerp(p: ArrayLike, q: ArrayLike, fraction: ArrayLike) -> Array:
    """Spherical linear interpolation from ``p`` (fraction 0) to ``q`` (fraction 1), short way."""
    p = _quat(p, "p")
    q = _quat(q, "q")
    f = np.asarray(fraction, dtype=np.float64)[..., None]
    dot = np.sum(p * q, axis=-1, keepdims=True)
    q = np.where(dot < 0.0, -q, q)
    delta = multiply(conjugate(p), q)
    return normalize(multiply(p, from_rotvec(to_rotvec(delta) * f)))


def angle_between(p: ArrayLike, q: ArrayLike) -> Array:
    """Rotation angle (rad, in [0, pi]) of ``p* ⊗ q``; ``q`` and ``-q`` give the same angle."""
    d = multiply(conjugate(p), q)
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))


def rate(q: ArrayLike, gyr_rad_s: ArrayLike) -> Array:
    """Time derivative ``q̇ = ½ q ⊗ (0, ω)`` for body angular rate ``ω`` (..., 3) rad/s (004)."""
    w = _vec(gyr_rad_s, "gyr_rad_s")
    omega = np.concatenate([np.zeros((*w.shape[:-1], 1)), w], axis=-1)
    return 0.5 * multiply(q, omega)


def integrate(q: ArrayLike, gyr_rad_s: ArrayLike, dt_s: ArrayLike) -> Array:
    """Exact integration of ``q̇ = ½ q ⊗ (0, ω)`` for constant body rate ``ω`` over ``dt_s``.

    ``q(t + dt) = q(t) ⊗ exp(ω dt / 2)``, the closed form of the linear ODE; unlike the
    Euler step of 004 it keeps unit norm and has no truncation error.
    """
    w = _vec(gyr_rad_s, "gyr_rad_s")
    dt = np.asarray(dt_s, dtype=np.float64)[..., None]
    return multiply(q, from_rotvec(w * dt))
