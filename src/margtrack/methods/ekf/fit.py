"""The Gauss-Newton quaternion of Marins' EKF (001 eqs. 20-23), inlined into its step.

:func:`fit` is :func:`margtrack.single_frame.gauss_newton_kernel.gauss_newton_solve` (the same
iteration, safeguard and stopping rules, from the same helpers, so the same quaternion to
rounding; tests compare them) specialised for the filter's per-sample use:

- inline (the general solver is a called function, three calls deep per sample);
- the update (001 eq. 22, solved in closed form: ``gauss_newton._gauss_newton_delta``)
  is computed at an iterate only when it will be taken: the general solver computes it
  at every evaluation of the criterion, also at the last iterate (whose update the
  iteration cap discards) and at rejected halvings. With the filter's cap of 2 that is
  two updates per sample instead of three.

Conventions as in :mod:`margtrack.single_frame.gauss_newton_kernel`: unit body accelerometer ĝ and
magnetometer m̂, unit earth up u and field reference h, ``Q = |ε_g|² + ρ²|ε_m|²``
(001 eq. 20, ρ of 000 eq. 17).
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit
from margtrack.single_frame.gauss_newton_kernel import (
    MAX_HALVINGS,
    PROGRESS_FLOOR,
    _gauss_newton_delta,
    _pair_terms,
)

__all__ = ["fit"]


@njit(cache=True, inline="always")
def _residuals(gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, rho2):
    """Q at n = (w, x, y, z) and the terms its update needs (``_pair_terms`` of each pair)."""
    eg = _pair_terms(gx, gy, gz, ux, uy, uz, w, x, y, z)
    em = _pair_terms(mx, my, mz, hx, hy, hz, w, x, y, z)
    q = (eg[0] * eg[0] + eg[1] * eg[1] + eg[2] * eg[2]
         + rho2 * (em[0] * em[0] + em[1] * em[1] + em[2] * em[2]))
    return q, eg, em


@njit(cache=True, inline="always")
def _update(eg, em, rho2, w, x, y, z):
    """The Gauss-Newton update from n (001 eq. 22): (ok, n + Δ), as ``gauss_newton._step``."""
    ok, d0, d1, d2, d3 = _gauss_newton_delta(rho2, eg, em)
    return ok, w + d0, x + d1, y + d2, z + d3


@njit(cache=True, inline="always")
def fit(gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, rho, tolerance,
        max_iterations):
    """Gauss-Newton fit from the guess n = (w, x, y, z) (any non-zero norm).

    Returns ``(ok, w, x, y, z, iterations)`` as ``gauss_newton_solve`` does (without Q):
    the unit quaternion (w >= 0) of the last iterate and the updates applied; ok is False
    if the normal equations became singular or an iterate non-finite.
    """
    rho2 = rho * rho
    iterations = 0
    q, eg, em = _residuals(gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz, w, x, y, z, rho2)
    ok = math.isfinite(q)
    go = ok and q > tolerance and iterations < max_iterations
    ok_step, nw, nx, ny, nz = False, w, x, y, z
    if go:
        ok_step, nw, nx, ny, nz = _update(eg, em, rho2, w, x, y, z)
    while go:
        if not ok_step:
            ok = False
            break
        floor = PROGRESS_FLOOR * math.sqrt(q)
        tw, tx, ty, tz = nw, nx, ny, nz
        accepted = False
        for _ in range(MAX_HALVINGS + 1):
            qt, eg, em = _residuals(gx, gy, gz, mx, my, mz, ux, uy, uz, hx, hy, hz,
                                    tw, tx, ty, tz, rho2)
            if math.isfinite(qt) and qt <= q + floor:
                accepted = True
                break
            tw, tx, ty, tz = 0.5 * (w + tw), 0.5 * (x + tx), 0.5 * (y + ty), 0.5 * (z + tz)
        if not accepted:
            break
        stalled = q - qt <= tolerance + floor
        w, x, y, z, q = tw, tx, ty, tz, qt
        iterations += 1
        go = not stalled and q > tolerance and iterations < max_iterations
        if go:  # the update from the accepted iterate (gauss_newton forms it at once)
            ok_step, nw, nx, ny, nz = _update(eg, em, rho2, w, x, y, z)
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if not (ok and norm > 0.0):
        return False, w, x, y, z, iterations
    inv = math.copysign(1.0, w) / norm
    return True, w * inv, x * inv, y * inv, z * inv, iterations
