"""Offline joint estimate: the MAP of both orientation series over the whole recording.

The cost is the negative log-posterior of the filter's own model (:mod:`.kernel`), summed
over every sample, in Gauss-Newton form over per-sample orientation increments
``δ_t = (δ₁, δ₂)`` (earth frame, ``R ← Exp(δ) R``)::

    motion, per sensor and interval:  e = Log(R_t Exp(-ω̄_t dt) R_{t-1}ᵀ),  weight 1/(σ_g² dt)
                                      (ω̄_t the interval's rate, as in the filter)
    link, per sample:                 e = R₁c₁ - R₂c₂,                      weight 1/σ_link²
    inclination, per sample:          e = ((R₁c₁ + R₂c₂)/2)ₓ,ᵧ,             weight 1/σ_incl,t²

The motion residual is the earth-frame gap between a sample's orientation and the gyroscope's
prediction from the one before; its Jacobians are ``+I`` and ``-D ≈ -I`` (``D`` the residual's
own rotation, within a few milliradians of I once the gyroscopes are followed). With them
the normal equations are block tridiagonal (a full 6x6 block per sample, a diagonal one
between neighbours), assembled in one compiled pass (:func:`_normal_equations`) and solved
by a block Cholesky (:func:`_solve`) in O(N) per iteration.

Start: a forward filter pass gives the state at the end of the recording, a backward pass
from there gives every sample an estimate that has already seen the motion after it (so a
still start, where the relative heading is unobservable, is not guessed). Gauss-Newton then
converges in a few iterations (it stops when the relative orientation moves less than
``tolerance_rad``). The global heading (a rotation of both sensors about the vertical) does
not change the cost: each step's common turn about the vertical is taken out.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from margtrack import quaternion as qt
from margtrack.joint.kernel import (
    C_GRAVITY,
    C_GYR_PREV,
    C_GYR_VAR,
    C_INCL_GAIN,
    C_INCL_VAR,
    C_LINK_VAR,
    _rotate_by,
    _times_exp,
)

Array = NDArray[np.float64]

__all__ = ["map_refine"]

@numba.njit(cache=True)
def _motion_residual(qa: np.ndarray, step: np.ndarray, qb: np.ndarray, out: np.ndarray) -> None:
    """out = Log(qa ⊗ step* ⊗ qb*), the earth-frame rotation vector (rad) of one interval."""
    # m = qa ⊗ conj(step)
    s0, s1, s2, s3 = step[0], -step[1], -step[2], -step[3]
    m0 = qa[0] * s0 - qa[1] * s1 - qa[2] * s2 - qa[3] * s3
    m1 = qa[0] * s1 + qa[1] * s0 + qa[2] * s3 - qa[3] * s2
    m2 = qa[0] * s2 - qa[1] * s3 + qa[2] * s0 + qa[3] * s1
    m3 = qa[0] * s3 + qa[1] * s2 - qa[2] * s1 + qa[3] * s0
    # e = m ⊗ conj(qb)
    b0, b1, b2, b3 = qb[0], -qb[1], -qb[2], -qb[3]
    e0 = m0 * b0 - m1 * b1 - m2 * b2 - m3 * b3
    e1 = m0 * b1 + m1 * b0 + m2 * b3 - m3 * b2
    e2 = m0 * b2 - m1 * b3 + m2 * b0 + m3 * b1
    e3 = m0 * b3 + m1 * b2 - m2 * b1 + m3 * b0
    if e0 < 0.0:
        e0, e1, e2, e3 = -e0, -e1, -e2, -e3
    sin_half = np.sqrt(e1 * e1 + e2 * e2 + e3 * e3)
    scale = 2.0 / e0 if sin_half < 1e-9 else 2.0 * np.arctan2(sin_half, e0) / sin_half
    out[0], out[1], out[2] = scale * e1, scale * e2, scale * e3


@numba.njit(cache=True)
def _normal_equations(
    q: np.ndarray, c: np.ndarray, steps: np.ndarray, w_motion: np.ndarray,
    meas_ok: np.ndarray, coeffs: np.ndarray, diag: np.ndarray, grad: np.ndarray,
) -> None:
    """Gauss-Newton normal equations ``A δ = -grad`` at ``q`` (module docstring).

    q (2, N, 4); c (2, N, 3); steps (2, N-1, 4) the gyroscope's turn of each interval;
    w_motion (N-1,) each interval's weight (0 across a gap). ``A`` is block tridiagonal:
    ``diag`` (N, 6, 6) receives its diagonal blocks (upper triangles only), its blocks
    between neighbours are ``-w_motion[k] I``; grad (N, 6) receives ``Jᵀ W e``.
    """
    n = q.shape[1]
    diag[:, :, :] = 0.0
    grad[:, :] = 0.0
    g = coeffs[C_GRAVITY]
    w_link = 1.0 / coeffs[C_LINK_VAR]
    v = np.zeros((2, 3))
    jac = np.zeros((5, 6))
    res = np.zeros(5)
    wts = np.zeros(5)
    e = np.zeros(3)
    for k in range(n):
        if meas_ok[k]:
            _rotate_by(q[0, k], c[0, k], v[0])
            _rotate_by(q[1, k], c[1, k], v[1])
            mx = 0.5 * (v[0, 0] + v[1, 0])
            my = 0.5 * (v[0, 1] + v[1, 1])
            mz = 0.5 * (v[0, 2] + v[1, 2])
            off = np.sqrt(mx * mx + my * my + mz * mz) - g
            w_incl = 1.0 / (coeffs[C_INCL_VAR] + coeffs[C_INCL_GAIN] * off * off)
            for i in range(3):
                res[i] = v[0, i] - v[1, i]
                wts[i] = w_link
            res[3], res[4] = mx, my
            wts[3], wts[4] = w_incl, w_incl
            # rows: link = [-[v₁]×, [v₂]×], inclination x, y = rows 0, 1 of -[v_i]×/2
            for s in range(2):
                a = 3 * s
                x, y, z = v[s, 0], v[s, 1], v[s, 2]
                sign = -1.0 if s == 0 else 1.0
                jac[0, a], jac[0, a + 1], jac[0, a + 2] = 0.0, -sign * z, sign * y
                jac[1, a], jac[1, a + 1], jac[1, a + 2] = sign * z, 0.0, -sign * x
                jac[2, a], jac[2, a + 1], jac[2, a + 2] = -sign * y, sign * x, 0.0
                jac[3, a], jac[3, a + 1], jac[3, a + 2] = 0.0, 0.5 * z, -0.5 * y
                jac[4, a], jac[4, a + 1], jac[4, a + 2] = -0.5 * z, 0.0, 0.5 * x
            for i in range(6):
                acc = 0.0
                for r in range(5):
                    acc += jac[r, i] * wts[r] * res[r]
                grad[k, i] += acc
                for j in range(i, 6):
                    acc = 0.0
                    for r in range(5):
                        acc += jac[r, i] * wts[r] * jac[r, j]
                    diag[k, i, j] += acc
        if k > 0 and w_motion[k - 1] > 0.0:
            w = w_motion[k - 1]
            for s in range(2):
                _motion_residual(q[s, k], steps[s, k - 1], q[s, k - 1], e)
                for i in range(3):
                    d = 3 * s + i
                    grad[k, d] += w * e[i]
                    grad[k - 1, d] -= w * e[i]
                    diag[k, d, d] += w
                    diag[k - 1, d, d] += w
        for i in range(6):
            diag[k, i, i] += 1e-9  # keeps a segment without any measurement solvable


@numba.njit(cache=True)
def _solve(diag: np.ndarray, off: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """x with ``A x = rhs`` for the block-tridiagonal SPD ``A`` of :func:`_normal_equations`.

    diag (N, 6, 6) the diagonal blocks (upper triangles read; overwritten by the Cholesky
    factors), off (N-1,) the neighbours' blocks ``-off[k] I``, rhs (N, 6). Block Cholesky:
    ``L_k L_kᵀ = D_k - C_kᵀ C_k`` with ``C_k = L_{k-1}⁻¹ (-off[k-1] I)`` lower triangular,
    then forward and back substitution; about 500 flops per sample.
    """
    n = diag.shape[0]
    low = np.zeros((n, 6, 6))  # C_k, lower triangular
    y = np.empty((n, 6))
    x = np.empty((n, 6))
    for k in range(n):
        d = diag[k]
        if k > 0:
            # C = L_{k-1}⁻¹ (-w I): column j solves L c = -w e_j (zero above j)
            lp = diag[k - 1]
            w = off[k - 1]
            cm = low[k]
            for j in range(6):
                for i in range(j, 6):
                    acc = -w if i == j else 0.0
                    for m in range(j, i):
                        acc -= lp[i, m] * cm[m, j]
                    cm[i, j] = acc / lp[i, i]
            # S = D - CᵀC (upper triangle)
            for i in range(6):
                for j in range(i, 6):
                    acc = 0.0
                    for m in range(j, 6):  # C lower: C[m, i] C[m, j] needs m >= max(i, j)
                        acc += cm[m, i] * cm[m, j]
                    d[i, j] -= acc
        # Cholesky of the upper triangle into the lower one: d[i, j] (i >= j) = L[i, j]
        for j in range(6):
            acc = d[j, j]
            for m in range(j):
                acc -= d[j, m] * d[j, m]
            ljj = np.sqrt(acc)
            d[j, j] = ljj
            for i in range(j + 1, 6):
                acc = d[j, i]
                for m in range(j):
                    acc -= d[i, m] * d[j, m]
                d[i, j] = acc / ljj
        # forward: L_k y_k = rhs_k - C_kᵀ y_{k-1}
        for i in range(6):
            acc = rhs[k, i]
            if k > 0:
                for m in range(i, 6):
                    acc -= low[k, m, i] * y[k - 1, m]
            for m in range(i):
                acc -= d[i, m] * y[k, m]
            y[k, i] = acc / d[i, i]
    for k in range(n - 1, -1, -1):
        d = diag[k]
        # back: L_kᵀ x_k = y_k - C_{k+1} x_{k+1}
        for i in range(5, -1, -1):
            acc = y[k, i]
            if k < n - 1:
                for m in range(i + 1):
                    acc -= low[k + 1, i, m] * x[k + 1, m]
            for m in range(i + 1, 6):
                acc -= d[m, i] * x[k, m]
            x[k, i] = acc / d[i, i]
    return x


@numba.njit(cache=True)
def _apply(q: np.ndarray, step: np.ndarray) -> None:
    """q[s, k] ← Exp(step[k, s]) ⊗ q[s, k] for both sensors and every sample."""
    for k in range(q.shape[1]):
        for s in range(2):
            _times_exp(q[s, k], step[k, s, 0], step[k, s, 1], step[k, s, 2], True, True)


def map_refine(
    t: Array,
    gyr: Array,
    c: Array,
    meas_ok: NDArray[np.bool_],
    restart: NDArray[np.bool_],
    q: Array,
    coeffs: Array,
    max_iterations: int,
    tolerance_rad: float,
) -> tuple[Array, int, float]:
    """Gauss-Newton MAP of both orientation series from the start ``q`` (module docstring).

    Parameters
    ----------
    t : (N,) s. gyr, c : (2, N, 3) rad/s and m/s² (joint-centre specific forces), sensor
        frames. meas_ok, restart : (N,) bool as in :func:`.kernel.filter_pass`.
    q : (2, N, 4) the starting orientations (the backward filter pass).
    coeffs : the filter's coefficients (:mod:`.kernel`'s ``C_`` slots).
    max_iterations, tolerance_rad : stop after that many iterations or when the largest
        update of the relative orientation is below the tolerance.

    Returns
    -------
    ``(q, iterations, last_step_rad)``: the orientations (2, N, 4), the iterations run and
    the largest update of the relative orientation in the last one.
    """
    n = t.shape[0]
    q = np.array(q, dtype=np.float64)
    dt = np.diff(t)
    w_motion = np.where(~restart[1:], 1.0 / (coeffs[C_GYR_VAR] * np.maximum(dt, 1e-12)), 0.0)
    prev = coeffs[C_GYR_PREV]
    steps = np.stack([qt.from_rotvec((prev * gyr[s, :-1] + (1.0 - prev) * gyr[s, 1:])
                                     * dt[:, None]) for s in range(2)])
    segment = np.cumsum(np.concatenate([[False], restart[1:]]))
    per_segment = np.bincount(segment)
    diag = np.empty((n, 6, 6))
    grad = np.empty((n, 6))
    iterations, largest = 0, np.inf
    for iterations in range(1, max_iterations + 1):  # noqa: B007
        _normal_equations(q, c, steps, w_motion, meas_ok, coeffs, diag, grad)
        step = _solve(diag, w_motion, -grad).reshape(n, 2, 3)
        # a common turn about the vertical is no change (the gauge): take it out, per
        # segment, so the parent's mean heading stays where it started
        turn = np.bincount(segment, step[:, 0, 2]) / per_segment
        step[:, :, 2] -= turn[segment][:, None]
        _apply(q, step)
        # the output's change: the child's turn relative to the parent's
        largest = float(np.max(np.abs(step[:, 1] - step[:, 0])))
        if largest < tolerance_rad:
            break
    return q, iterations, largest
