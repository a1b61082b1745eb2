"""Scalar quaternion and vector helpers for kernels: [w, x, y, z], Hamilton, body-to-earth.

Each helper works on components and returns tuples, so numba keeps them in registers.
They mirror :mod:`margtrack.quaternion`, which is the tested reference.
"""

from __future__ import annotations

import math

from margtrack.estimator.fastmath import sincos
from margtrack.estimator.jit import njit


@njit(cache=True, inline="always")
def mul(aw, ax, ay, az, bw, bx, by, bz):
    """Hamilton product a ⊗ b."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(cache=True, inline="always")
def exp_half(wx, wy, wz, dt):
    """exp(ω dt / 2): the rotation by the rotation vector ω·dt (rad)."""
    angle = math.sqrt(wx * wx + wy * wy + wz * wz) * dt
    half = 0.5 * angle
    # (sin and cos without a library call, so a loop over sensors vectorises: _fastmath)
    sin_half, cos_half = sincos(half)
    if angle < 1e-6:
        scale = (0.5 - angle * angle / 48.0) * dt
    else:
        scale = sin_half / angle * dt
    return cos_half, wx * scale, wy * scale, wz * scale


@njit(cache=True, inline="always")
def normalized(w, x, y, z):
    """q / |q| (the caller guarantees a non-zero norm)."""
    n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    return w * n, x * n, y * n, z * n


@njit(cache=True, inline="always")
def cross(ax, ay, az, bx, by, bz):
    """a × b."""
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@njit(cache=True, inline="always")
def from_matrix(r11, r12, r13, r21, r22, r23, r31, r32, r33):
    """Unit quaternion (w >= 0) of a rotation matrix by the largest of 004's four branches."""
    trace = r11 + r22 + r33
    if trace >= r11 and trace >= r22 and trace >= r33:
        n = 2.0 * math.sqrt(1.0 + trace)
        w, x, y, z = 0.25 * n, (r32 - r23) / n, (r13 - r31) / n, (r21 - r12) / n
    elif r11 >= r22 and r11 >= r33:
        n = 2.0 * math.sqrt(1.0 + r11 - r22 - r33)
        w, x, y, z = (r32 - r23) / n, 0.25 * n, (r12 + r21) / n, (r13 + r31) / n
    elif r22 >= r33:
        n = 2.0 * math.sqrt(1.0 + r22 - r11 - r33)
        w, x, y, z = (r13 - r31) / n, (r12 + r21) / n, 0.25 * n, (r23 + r32) / n
    else:
        n = 2.0 * math.sqrt(1.0 + r33 - r11 - r22)
        w, x, y, z = (r21 - r12) / n, (r13 + r31) / n, (r23 + r32) / n, 0.25 * n
    w, x, y, z = normalized(w, x, y, z)
    if w < 0.0:
        return -w, -x, -y, -z
    return w, x, y, z
