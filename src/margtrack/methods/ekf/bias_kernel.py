"""Kernel of Marins' EKF with a gyroscope bias state: ``x = [ω, q, b]`` (10), in 003's spirit.

001's rate model has no bias: a gyroscope bias enters its measured rate as signal, and
the quaternion measurement has to pull the attitude back against it all the time. Here,
as in 003's augmented state (eqs. 20-31, bias of the angular velocity as a state), the
gyroscope measures ``ω + b + v`` and the bias is a random walk, ``ḃ = w_b`` with white
``w_b`` of density ``σ_b`` (rad/s/√s), so over an interval h: ``b⁺ = b``,
``Var Δb = σ_b² h``. Everything else is 001's model and update
(:mod:`margtrack.methods.ekf.kernel`): ``F = diag(F₇, I₃)``, ``Q = diag(Q₇, σ_b² h I₃)``, and
the gyroscope rows of H are ``[I₃ 0 I₃]``. b is what is left after the still start's gyro
null (when it is used), so the bias of the raw rate is ``null + b``.

A restart after a gap keeps b and its covariance block (what is known of the sensor),
like the dip and the null. Row: :mod:`margtrack.methods.ekf.kernel`'s layout with n = 10, then
the bias of the raw rate (``E_BIAS``, 3, rad/s) and its sd (``E_BIAS_SD``, 3). Extra
outputs per sample: the rate state (3), the covariance diagonal (10), the Gauss-Newton
iterations, the ``degenerate`` code, the gyro null (3), the bias of the raw rate (3) and
its sd (3).
"""

from __future__ import annotations

from margtrack.estimator import skeleton as contract
from margtrack.estimator.jit import njit
from margtrack.methods.ekf.kernel import E_X, hold_n, start_n, step_n

N = 10  # [ω (3), q (4), b (3)]
# the row and output offsets of ekf.offsets(N) and ekf.out_offsets(N)
E_P = E_X + N  # 100: covariance, row-major
E_PH = E_P + N * N  # 10: scratch of an update
E_BIAS = E_PH + N  # 3: the bias of the raw rate, null + b, rad/s
E_BIAS_SD = E_BIAS + 3  # 3: its sd, rad/s
N_ROW = E_BIAS_SD + 3
X_RATE = 0  # 3
X_COV = 3  # 10
X_ITER = X_COV + N
X_CODE = X_ITER + 1
X_NULL = X_CODE + 1  # 3
X_BIAS = X_NULL + 3  # 3
X_BIAS_SD = X_BIAS + 3  # 3
N_OUT = X_BIAS_SD + 3
N_X = N_OUT  # what ``run`` writes per sample

__all__ = [
    "E_BIAS", "E_BIAS_SD", "E_P", "E_X", "N_ROW", "lanes", "run", "start",
]


@njit(cache=True, inline="always")
def _start(row, coef, first, qw, qx, qy, qz):
    start_n(row, coef, first, qw, qx, qy, qz, N)


@njit(cache=True, inline="always")
def _step(row, coef, h, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """:func:`margtrack.methods.ekf.kernel.step_n` with the bias state (compiled once for n = 10
    and called)."""
    return step_n(row, coef, h, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out, N)


@njit(cache=True, inline="always")
def _hold(row, coef, x_out):
    hold_n(row, coef, x_out, N)


run, lanes, start = contract.entry_points(__name__)
