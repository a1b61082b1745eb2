"""Kernel of plain gyroscope integration (the baseline estimator), on ``kernels/contract.py``.

Row layout after the contract's slots: ``G_Q`` (4) the integrated orientation. No extra
outputs, no parameters of its own.
"""

from __future__ import annotations

from margtrack.kernels import contract
from margtrack.kernels._quat import exp_half, mul
from margtrack.kernels.jit import njit

G_Q = contract.N_CONTRACT  # 4: orientation, body to earth
N_ROW = G_Q + 4


@njit(cache=True)
def _start(row, coef, first, qw, qx, qy, qz):
    row[G_Q], row[G_Q + 1], row[G_Q + 2], row[G_Q + 3] = qw, qx, qy, qz


@njit(cache=True)
def _step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """``q_i = q_{i-1} ⊗ exp(ω_i dt_i / 2)``: exact for a rate constant over the interval;
    ``dt = 0`` leaves q as it was (exp of zero is the identity)."""
    dw, dx, dy, dz = exp_half(g0, g1, g2, dt)
    w, x, y, z = mul(row[G_Q], row[G_Q + 1], row[G_Q + 2], row[G_Q + 3], dw, dx, dy, dz)
    row[G_Q], row[G_Q + 1], row[G_Q + 2], row[G_Q + 3] = w, x, y, z
    q_out[0], q_out[1], q_out[2], q_out[3] = w, x, y, z
    return 0


@njit(cache=True)
def _hold(row, coef, x_out):
    """Nothing to write: plain integration has no extra outputs."""


@njit(cache=True, nogil=True, _nrt=False)
def series(rows, coefs, dts, ks, tflags, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples on the shared clock's values (``contract.series``)."""
    contract.series(_start, _step, _hold, rows, coefs, dts, ks, tflags, gyr, acc, mag,
                    has, q_out, x_out, flags_out)


@njit(cache=True, nogil=True)
def run(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples (``contract.run_series`` with :func:`series`)."""
    contract.run_series(series, rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out,
                        flags_out)


@njit(cache=True)
def sample(row, coef, scoef, clk, imu, has, q_out, x_out):
    """One screened sample of one sensor (``contract.sample``), compiled once for
    :func:`update` and :func:`update_one`."""
    return contract.sample(_start, _step, _hold, row, coef, scoef, clk, imu, has, q_out, x_out)


@njit(cache=True)
def update(rows, clock, coefs, dt, gyr, acc, mag, has, q_out, x_out, flags_out):
    """One sample of S sensors (``contract.update_samples``)."""
    contract.update_samples(sample, rows, clock, coefs, dt, gyr, acc, mag, has,
                            q_out, x_out, flags_out)


@njit(cache=True)
def update_one(rows, clock, coefs, dt, g, a, m, has, out):
    """One sample of one sensor (``contract.update_one``); returns the flags."""
    return contract.update_one(sample, rows, clock, coefs, dt, g, a, m, has, out)


@njit(cache=True)
def start(rows, coefs, quat0):
    """Start S sensors at quat0 (S, 4) (``contract.start_rows``)."""
    contract.start_rows(_start, rows, coefs, quat0)
