"""Small dense linear algebra for the kernels: Cholesky factor, Kalman gain, 3x3 adjugate.

Explicit loops over fixed-size buffers: for the 3-9 dimensional systems of the filters
they are several times faster in numba than ``np.linalg`` calls, which allocate.
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit


@njit(cache=True)
def cholesky(s, m, chol):
    """Lower Cholesky factor of ``s[:m, :m]`` into ``chol``; False if not positive definite."""
    for r in range(m):
        for c in range(r + 1):
            acc = s[r, c]
            for k in range(c):
                acc -= chol[r, k] * chol[c, k]
            if r == c:
                if not acc > 0.0:
                    return False
                chol[r, r] = math.sqrt(acc)
            else:
                chol[r, c] = acc / chol[c, c]
    return True


@njit(cache=True, inline="always")
def add_kalman_gain_n(chol, m, n, rhs, innov, x, y, gain):
    """:func:`add_kalman_gain` with the state size ``n`` given (inlined, so a caller's
    literal ``m`` and ``n`` unroll)."""
    for c in range(n):  # Y = S⁻¹ rhs
        for r in range(m):
            acc = rhs[r, c]
            for k in range(r):
                acc -= chol[r, k] * y[k, c]
            y[r, c] = acc / chol[r, r]
        for r in range(m - 1, -1, -1):
            acc = y[r, c]
            for k in range(r + 1, m):
                acc -= chol[k, r] * y[k, c]
            y[r, c] = acc / chol[r, r]
    for i in range(n):
        acc = 0.0
        for k in range(m):
            gain[i, k] = y[k, i]
            acc += y[k, i] * innov[k]
        x[i] += acc


@njit(cache=True)
def add_kalman_gain(chol, m, rhs, innov, x, y, gain):
    """Kalman gain ``K = rhsᵀ S⁻¹`` with ``S = chol cholᵀ`` into ``gain`` (n, m); ``x += K ν``.

    ``rhs`` (m, n) is ``H P``; ``y`` (m, n) a buffer. Two triangular solves per column of
    ``rhs`` replace the inverse of ``S``.
    """
    add_kalman_gain_n(chol, m, x.shape[0], rhs, innov, x, y, gain)


@njit(cache=True, inline="always")
def sym3_adjugate(a00, a01, a02, a11, a12, a22):
    """Adjugate and determinant of the symmetric 3x3 matrix with upper triangle a00 ... a22:
    (c00, c01, c02, c11, c12, c22, det), the adjugate's upper triangle; the inverse is the
    adjugate / det."""
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    return c00, c01, c02, c11, c12, c22, a00 * c00 + a01 * c01 + a02 * c02
