"""Kernel of plain gyroscope integration (the baseline estimator)."""

from __future__ import annotations

from numba import njit

from margtrack.kernels._quat import exp_half, mul


@njit(cache=True)
def integrate_gyro(quat_state, gyr, dt, quat_out):
    """Integrate body rates for S sensors: ``q_i = q_{i-1} ⊗ exp(ω_i dt_i / 2)``.

    quat_state (S, 4) in/out: orientation before sample 0, replaced by the last one.
    gyr (S, N, 3) rad/s; dt (N,) s (dt[0] = 0 leaves the first output at the state);
    quat_out (S, N, 4) filled. Exact for rates constant over each interval.

    Screened input (``estimator/screening.py``): gyr is finite and within range; a sample
    with ``dt = 0`` (first sample, gap, skipped timestamp) leaves the orientation exactly
    as it was (``exp(ω · 0 / 2)`` is the identity).
    """
    n_sensors, n_samples = gyr.shape[0], gyr.shape[1]
    for s in range(n_sensors):
        w, x, y, z = quat_state[s, 0], quat_state[s, 1], quat_state[s, 2], quat_state[s, 3]
        for i in range(n_samples):
            dw, dx, dy, dz = exp_half(gyr[s, i, 0], gyr[s, i, 1], gyr[s, i, 2], dt[i])
            w, x, y, z = mul(w, x, y, z, dw, dx, dy, dz)
            quat_out[s, i, 0] = w
            quat_out[s, i, 1] = x
            quat_out[s, i, 2] = y
            quat_out[s, i, 3] = z
        quat_state[s, 0], quat_state[s, 1], quat_state[s, 2], quat_state[s, 3] = w, x, y, z
