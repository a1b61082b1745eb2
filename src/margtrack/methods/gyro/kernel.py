"""Kernel of plain gyroscope integration (the baseline estimator), on ``estimator/skeleton.py``.

Row layout after the contract's slots: ``G_Q`` (4) the integrated orientation. No extra
outputs, no parameters of its own.
"""

from __future__ import annotations

from margtrack.estimator import skeleton as contract
from margtrack.estimator.jit import njit
from margtrack.estimator.quat_kernel import exp_half, mul

G_Q = contract.N_CONTRACT  # 4: orientation, body to earth
N_ROW = G_Q + 4
N_X = 0  # no extra outputs


@njit(cache=True, inline="always")
def _start(row, coef, first, qw, qx, qy, qz):
    row[G_Q], row[G_Q + 1], row[G_Q + 2], row[G_Q + 3] = qw, qx, qy, qz


@njit(cache=True, inline="always")
def _step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """``q_i = q_{i-1} ⊗ exp(ω_i dt_i / 2)``: exact for a rate constant over the interval;
    ``dt = 0`` leaves q as it was (exp of zero is the identity)."""
    dw, dx, dy, dz = exp_half(g0, g1, g2, dt)
    w, x, y, z = mul(row[G_Q], row[G_Q + 1], row[G_Q + 2], row[G_Q + 3], dw, dx, dy, dz)
    row[G_Q], row[G_Q + 1], row[G_Q + 2], row[G_Q + 3] = w, x, y, z
    q_out[0], q_out[1], q_out[2], q_out[3] = w, x, y, z
    return 0


@njit(cache=True, inline="always")
def _hold(row, coef, x_out):
    """Nothing to write: plain integration has no extra outputs."""


run, lanes, start = contract.entry_points(__name__)
