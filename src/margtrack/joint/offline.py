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
the normal equations are banded with half-bandwidth 6 (a full 6x6 block per sample, a
diagonal one between neighbours), solved by a banded Cholesky
(:func:`scipy.linalg.solveh_banded`) in O(N) per iteration.

Start: a forward filter pass gives the state at the end of the recording, a backward pass
from there gives every sample an estimate that has already seen the motion after it (so a
still start, where the relative heading is unobservable, is not guessed). Gauss-Newton then
converges in a few iterations. The global heading (a rotation of both sensors about the
vertical) does not change the cost: the parent's first heading is held by a unit prior.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from margtrack import quaternion as qt

Array = NDArray[np.float64]

__all__ = ["map_refine"]

_BAND = 6  # half-bandwidth of the normal equations: one sample's six unknowns


def _skew_rows(v: Array, scale: float) -> Array:
    """``scale · [v]×`` for each row of ``v`` (N, 3): (N, 3, 3)."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return scale * out


def _motion_residuals(q: Array, step: Array) -> Array:
    """Earth-frame residual of each interval, (N-1, 3): Log(q_t ⊗ Exp(-φ_t) ⊗ q_{t-1}*)."""
    pred = qt.multiply(q[1:], qt.conjugate(step))
    return qt.to_rotvec(qt.multiply(pred, qt.conjugate(q[:-1])))


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
        update is below the tolerance.

    Returns
    -------
    ``(q, iterations, last_step_rad)``: the orientations (2, N, 4), the iterations run and
    the largest update of the last one.
    """
    from scipy.linalg import solveh_banded

    from margtrack.joint.kernel import (
        C_GRAVITY,
        C_GYR_PREV,
        C_GYR_VAR,
        C_INCL_GAIN,
        C_INCL_VAR,
        C_LINK_VAR,
    )

    n = t.shape[0]
    q = np.array(q, dtype=np.float64)
    dt = np.diff(t)
    linked = ~restart[1:]  # interval t-1 -> t is integrated
    w_motion = np.where(linked, 1.0 / (coeffs[C_GYR_VAR] * np.maximum(dt, 1e-12)), 0.0)
    prev = coeffs[C_GYR_PREV]
    steps = [qt.from_rotvec((prev * gyr[s, :-1] + (1.0 - prev) * gyr[s, 1:]) * dt[:, None])
             for s in range(2)]
    g = coeffs[C_GRAVITY]
    w_link = np.where(meas_ok, 1.0 / coeffs[C_LINK_VAR], 0.0)
    # the global heading is free: hold the parent's at the start of every linked segment
    segment_start = np.flatnonzero(np.concatenate([[True], restart[1:]]))
    iterations, largest = 0, np.inf
    for iterations in range(1, max_iterations + 1):  # noqa: B007
        v = np.stack([qt.rotate(q[s], c[s]) for s in range(2)])  # (2, N, 3)
        mean = 0.5 * (v[0] + v[1])
        off = np.linalg.norm(mean, axis=1) - g
        w_incl = np.where(meas_ok, 1.0 / (coeffs[C_INCL_VAR] + coeffs[C_INCL_GAIN] * off**2), 0.0)
        # per-sample Jacobian (6 rows: link, inclination; 6 columns: δ₁, δ₂) and residual
        jac = np.empty((n, 6, 6))
        jac[:, :3, :3] = _skew_rows(v[0], -1.0)
        jac[:, :3, 3:] = _skew_rows(v[1], 1.0)
        jac[:, 3:, :3] = _skew_rows(v[0], -0.5)
        jac[:, 3:, 3:] = _skew_rows(v[1], -0.5)
        res = np.empty((n, 6))
        res[:, :3] = v[0] - v[1]
        res[:, 3:] = mean
        res[:, 5] -= g
        weights = np.concatenate([np.repeat(w_link[:, None], 3, 1),
                                  np.repeat(w_incl[:, None], 2, 1), np.zeros((n, 1))], axis=1)
        wj = jac * weights[:, :, None]
        blocks = np.einsum("nki,nkj->nij", jac, wj)  # Jᵀ W J, (N, 6, 6)
        grad = np.einsum("nki,nk->ni", wj, res)  # Jᵀ W e, (N, 6)
        # motion terms: +I on both diagonal blocks, -I between neighbours
        for s in range(2):
            e = _motion_residuals(q[s], steps[s]) * w_motion[:, None]  # W e, (N-1, 3)
            grad[1:, 3 * s:3 * s + 3] += e
            grad[:-1, 3 * s:3 * s + 3] -= e
            for a in range(3):
                blocks[1:, 3 * s + a, 3 * s + a] += w_motion
                blocks[:-1, 3 * s + a, 3 * s + a] += w_motion
        blocks[segment_start, 2, 2] += 1.0
        idx = np.arange(6)
        blocks[:, idx, idx] += 1e-9  # keeps a segment without any measurement solvable
        band = np.zeros((_BAND + 1, 6 * n))
        cols = 6 * np.arange(n)
        for b in range(6):
            for a in range(b + 1):
                band[_BAND + a - b, cols + b] = blocks[:, a, b]
        off_diag = np.repeat(-w_motion[:, None], 2, 1)  # (N-1, 2): one per sensor
        for s in range(2):
            for a in range(3):
                band[0, cols[1:] + 3 * s + a] = off_diag[:, s]
        step = solveh_banded(band, -grad.reshape(-1), lower=False,
                             check_finite=False).reshape(n, 2, 3)
        for s in range(2):
            q[s] = qt.multiply(qt.from_rotvec(step[:, s]), q[s])
        largest = float(np.max(np.abs(step)))
        if largest < tolerance_rad:
            break
    return q, iterations, largest
