"""The gradient filter's objective (004 "General Optimization Algorithm", after Madgwick):
f(q, d, s) = q* ⊗ d ⊗ q - s, its Jacobian, the gradient Jᵀ f, and the rotations they use.

Quaternions are body-to-earth ``[w, x, y, z]`` (004's ``q1..q4``); 004's ``q* ⊗ d ⊗ q``
is our ``rotate_inverse(q, d)``. Inline helpers of :mod:`margtrack.methods.gradient.kernel`.
"""

from __future__ import annotations

from margtrack.estimator.jit import njit


@njit(cache=True, inline="always")
def objective(w, x, y, z, dx, dy, dz, sx, sy, sz):
    """f(q, d, s) = q* ⊗ d ⊗ q - s = rotate_inverse(q, d) - s (004 "General Optimization").

    004's expanded f (after Madgwick) has two sign slips in the extracted text: the z terms
    of row 2 read ``q1q2 - q3q4`` and the x terms of row 3 ``q1q3 - q2q4``; rotating by a
    unit q gives ``q1q2 + q3q4`` and ``q1q3 + q2q4``, which is also what 004's own
    Jacobian differentiates. Uses the unit-norm form ``1/2 - q3² - q4²`` as 004 does.
    """
    f1 = (
        2.0 * dx * (0.5 - y * y - z * z)
        + 2.0 * dy * (w * z + x * y)
        + 2.0 * dz * (x * z - w * y)
        - sx
    )
    f2 = (
        2.0 * dx * (x * y - w * z)
        + 2.0 * dy * (0.5 - x * x - z * z)
        + 2.0 * dz * (w * x + y * z)
        - sy
    )
    f3 = (
        2.0 * dx * (w * y + x * z)
        + 2.0 * dy * (y * z - w * x)
        + 2.0 * dz * (0.5 - x * x - y * y)
        - sz
    )
    return f1, f2, f3


@njit(cache=True, inline="always")
def jacobian(w, x, y, z, dx, dy, dz):
    """J = ∂f/∂[q1, q2, q3, q4] (3 x 4, row-major 12-tuple) of :func:`objective`.

    Derived from f; it equals 004's J except the last entry, which the extracted text
    gives as ``2x_x q2 - 2x_y q3 - 3`` (OCR slip): ∂f3/∂q4 = ``2 d_x q2 + 2 d_y q3``.
    """
    return (
        2.0 * dy * z - 2.0 * dz * y,
        2.0 * dy * y + 2.0 * dz * z,
        -4.0 * dx * y + 2.0 * dy * x - 2.0 * dz * w,
        -4.0 * dx * z + 2.0 * dy * w + 2.0 * dz * x,
        -2.0 * dx * z + 2.0 * dz * x,
        2.0 * dx * y - 4.0 * dy * x + 2.0 * dz * w,
        2.0 * dx * x + 2.0 * dz * z,
        -2.0 * dx * w - 4.0 * dy * z + 2.0 * dz * y,
        2.0 * dx * y - 2.0 * dy * x,
        2.0 * dx * z - 2.0 * dy * w - 4.0 * dz * x,
        2.0 * dx * w + 2.0 * dy * z - 4.0 * dz * y,
        2.0 * dx * x + 2.0 * dy * y,
    )


@njit(cache=True, inline="always")
def gradient_term(w, x, y, z, dx, dy, dz, sx, sy, sz):
    """∇f = Jᵀ f (004 "General Optimization Algorithm") for one reference direction."""
    f1, f2, f3 = objective(w, x, y, z, dx, dy, dz, sx, sy, sz)
    j = jacobian(w, x, y, z, dx, dy, dz)
    return (
        j[0] * f1 + j[4] * f2 + j[8] * f3,
        j[1] * f1 + j[5] * f2 + j[9] * f3,
        j[2] * f1 + j[6] * f2 + j[10] * f3,
        j[3] * f1 + j[7] * f2 + j[11] * f3,
    )


@njit(cache=True)
def objective_jacobian(q, d, s, f_out, j_out):
    """Array form of :func:`objective` and :func:`jacobian` for tests: f_out (3,), j_out (3, 4)."""
    f = objective(q[0], q[1], q[2], q[3], d[0], d[1], d[2], s[0], s[1], s[2])
    j = jacobian(q[0], q[1], q[2], q[3], d[0], d[1], d[2])
    for r in range(3):
        f_out[r] = f[r]
        for c in range(4):
            j_out[r, c] = j[4 * r + c]


@njit(cache=True, inline="always")
def rotate(w, x, y, z, vx, vy, vz):
    """rotate(q, v) = R(q) v (body to earth)."""
    return (
        (1.0 - 2.0 * (y * y + z * z)) * vx
        + 2.0 * (x * y - w * z) * vy
        + 2.0 * (x * z + w * y) * vz,
        2.0 * (x * y + w * z) * vx
        + (1.0 - 2.0 * (x * x + z * z)) * vy
        + 2.0 * (y * z - w * x) * vz,
        2.0 * (x * z - w * y) * vx
        + 2.0 * (y * z + w * x) * vy
        + (1.0 - 2.0 * (x * x + y * y)) * vz,
    )


@njit(cache=True, inline="always")
def rotate_inverse(w, x, y, z, vx, vy, vz):
    """rotate_inverse(q, v) = R(q)ᵀ v (earth to body)."""
    return rotate(w, -x, -y, -z, vx, vy, vz)
