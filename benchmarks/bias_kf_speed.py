"""Speed of Ang's bias Kalman filter (``bias-kf``) next to ``ahrs.filters.EKF`` on the same data.

Run ``python benchmarks/bias_kf_speed.py [--samples N] [--ahrs-samples N] [--calls N]``.

Input: the 16 BROAD trials of ../shared/data/broad concatenated (858,735 samples at 286 Hz;
cut to ``--samples``), or a simulated random motion if the data are absent. Printed, best
of 3 with compilation excluded:

- batch throughput, samples/s: margtrack ``BiasKalman.run`` (defaults, with margtrack's
  extensions) for 1 sensor and for 8 sensors in one call, and as printed in 003
  (``BiasKalmanParams.as_printed()``); the printed filter written with ``np.linalg``/``@``
  inside numba (the alternative to the kernel's fixed-size loops, checked to give the same
  quaternions);
  ``ahrs.filters.EKF`` (pure Python, quaternion EKF with acc/mag, on the first
  ``--ahrs-samples``); the all-accelerometer rate solver and the solver + filter pipeline
  at 500 Hz on a simulated tremor recording;
- per-call cost of one live sample, µs: ``BiasKalman.update`` and ``ahrs`` ``EKF.update``;

with ratios to margtrack's one-sensor ``run``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit

from margtrack import frames
from margtrack.bench.speed import measure, print_table, speed_input
from margtrack.methods.bias_kf import (
    BiasKalman,
    BiasKalmanParams,
    initial_covariance,
    track_all_accelerometer,
)
from margtrack.methods.bias_kf.kernel import (
    _triad,
    fill_phi_q,
    fill_qtilde,
    fill_quat_noise,
    fill_triad_cov,
)

RATE_HZ = 285.714
N_SENSORS = 8




@njit(cache=False)
def bias_kf_linalg(q0, cov0, gyr, acc, mag, dt, up, north, gyr_var, bias_var, acc_var,
                   acc_motion_var, gravity2, mag_var, quat_out):  # fmt: skip
    """The kernel's filter (1 sensor) with 7x7 matrix products and ``np.linalg.inv``."""
    q = q0.copy()
    b = np.zeros(3)
    p = cov0.copy()
    h_mat = np.zeros((4, 7))
    for k in range(4):
        h_mat[k, k] = 1.0
    eye7 = np.eye(7)
    phi = np.empty((4, 4))
    qt = np.empty((4, 3))
    w4 = np.empty((4, 4))
    xi = np.empty((3, 3))
    for i in range(gyr.shape[0]):
        h = dt[i]
        if h > 0.0:
            w = (gyr[i] - b) * h
            fill_phi_q(w[0], w[1], w[2], phi)
            fill_qtilde(q[0], q[1], q[2], q[3], qt)
            f = np.eye(7)
            f[:4, :4] = phi
            f[:4, 4:] = -0.5 * h * (phi @ qt)
            q = phi @ q
            q /= np.linalg.norm(q)
            fill_quat_noise(q[0], q[1], q[2], q[3], np.diag(gyr_var * h), qt, w4)
            wn = np.zeros((7, 7))
            wn[:4, :4] = w4
            wn[4:, 4:] = np.diag(bias_var * h)
            p = f @ p @ f.T + wn
            res = _triad(acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2], up,
                         north)
            if res[0] == 0:
                z = np.array([res[1], res[2], res[3], res[4]])
                if z @ q < 0.0:
                    z = -z
                var_g = (acc_var / h + acc_motion_var) / gravity2
                var_n = (mag_var / h) / np.sum(mag[i] ** 2)
                fill_triad_cov(res[5], res[6], res[7], res[8], res[9], res[10], var_g, var_n, xi)
                fill_quat_noise(q[0], q[1], q[2], q[3], xi, qt, w4, 1.0)
                gain = p @ h_mat.T @ np.linalg.inv(h_mat @ p @ h_mat.T + w4)
                x = gain @ (z - q)
                ikh = eye7 - gain @ h_mat
                p = ikh @ p @ ikh.T + gain @ w4 @ gain.T
                p = 0.5 * (p + p.T)
                q = q + x[:4]
                q /= np.linalg.norm(q)
                b = b + x[4:]
        quat_out[i] = q




def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=None, help="default: all")
    parser.add_argument("--ahrs-samples", type=int, default=20_000)
    parser.add_argument("--calls", type=int, default=2_000, help="live update() calls timed")
    args = parser.parse_args()
    data = speed_input(args.samples, rate_hz=RATE_HZ)
    gyr, acc, mag, source = data.gyr, data.acc, data.mag, data.source
    n = gyr.shape[0]
    t = np.arange(n) / RATE_HZ
    print(f"input: {source}, {n} samples used")

    mine = measure("margtrack BiasKalman.run, 1 sensor", lambda: BiasKalman().run(
        gyr=gyr, acc=acc, mag=mag, t=t), n)
    m = min(n, 100_000)
    stack = [np.ascontiguousarray(np.broadcast_to(x[:m], (N_SENSORS, m, 3))) for x in (gyr, acc,
                                                                                     mag)]
    multi = measure(f"margtrack BiasKalman.run, {N_SENSORS} sensors", lambda: BiasKalman().run(
        gyr=stack[0], acc=stack[1], mag=stack[2], t=t[:m]), N_SENSORS * m)

    printed = BiasKalmanParams.as_printed()
    as_printed = measure("margtrack BiasKalman.run, as printed (003)", lambda: BiasKalman(
        printed).run(gyr=gyr, acc=acc, mag=mag, t=t), n)
    p = printed  # the numpy-linalg variant below is the filter as printed
    q0 = BiasKalman().run(gyr=gyr[:1], acc=acc[:1], mag=mag[:1], t=t[:1]).quat[0]
    cov0 = initial_covariance(q0, p.init_angle_std_rad, p.init_bias_std_rad_s)[0]
    dt = np.r_[0.0, np.diff(t)]
    gyr_var, bias_var = p.axis_variances()
    out = np.empty((n, 4))
    args_linalg = (q0, cov0, gyr, acc, mag, dt, frames.up("ENU"),
                   frames.mag_reference("ENU", 0.0), gyr_var, bias_var,
                   p.acc_noise_m_s2_sqrt_hz**2, (p.acc_motion_fraction * p.gravity_m_s2) ** 2,
                   p.gravity_m_s2**2, p.mag_relative_var() * float(np.sum(mag[0] ** 2)), out)
    start = time.perf_counter()
    bias_kf_linalg(*args_linalg)
    compile_s = time.perf_counter() - start
    linalg = measure("same filter, np.linalg + @ in numba", lambda: bias_kf_linalg(*args_linalg),
                     n, warmup=False)
    ref = BiasKalman(printed).run(gyr=gyr, acc=acc, mag=mag, t=t).quat
    agree = float(np.max(np.abs(np.abs(np.sum(out * ref, axis=1)) - 1.0)))

    from ahrs.filters import EKF

    k = min(n, args.ahrs_samples)
    ahrs_batch = measure("ahrs EKF (batch constructor)", lambda: EKF(
        gyr=gyr[:k], acc=acc[:k], mag=mag[:k], frequency=RATE_HZ), k, repeats=1)

    from margtrack.sim import all_accelerometer as aa
    from margtrack.single_frame.all_accelerometer import all_accelerometer_noise, angular_velocity

    rec = aa.simulate_all_accelerometer(
        aa.tremor_motion(200.0, 500.0, seed=1), acc_noise_m_s2_sqrt_hz=1e-3, seed=2)
    noise = all_accelerometer_noise(rec.array, 1e-3, 500.0)
    ap = BiasKalmanParams(gyr_noise_rad_s_sqrt_hz=noise.gyr_noise_rad_s_sqrt_hz,
                          gyr_bias_walk_rad_s_sqrt_s=noise.gyr_bias_walk_rad_s_sqrt_s,
                          acc_motion_fraction=0.01, mag_noise_ut_sqrt_hz=0.02)
    na = rec.t.shape[0]
    solver = measure("all-accelerometer rate solver (GN)", lambda: angular_velocity(
        rec.readings_m_s2, rec.array, t=rec.t), na)
    pipeline = measure("all-accelerometer solver + bias-kf", lambda: track_all_accelerometer(
        rec, ap), na)

    calls = min(args.calls, n)
    live = BiasKalman(rate_hz=RATE_HZ)

    def run_live() -> None:
        live.reset()
        for i in range(calls):
            live.update(gyr[i], acc[i], mag[i])

    update = measure("margtrack BiasKalman.update", run_live, calls)
    ekf = EKF(frequency=RATE_HZ)
    ekf.mag = mag[:calls]  # ahrs's h() switches to MARG when its mag attribute is set

    def run_ahrs_live() -> None:
        q = np.array([1.0, 0.0, 0.0, 0.0])
        for i in range(calls):
            q = ekf.update(q, gyr[i], acc[i], mag[i])

    ahrs_update = measure("ahrs EKF.update", run_ahrs_live, calls)

    print("\nbatch (compilation excluded; linalg variant compiled in "
          f"{compile_s:.1f} s; its quaternions differ from the kernel's as printed by {agree:.1e})")
    print_table([
        (mine, ""),
        (multi, f"{N_SENSORS} x {m} samples"),
        (as_printed, "extensions neutral"),
        (linalg, "as printed, 7x7 products + inv"),
        (ahrs_batch, f"first {k} samples"),
        (solver, f"{na} samples at 500 Hz"),
        (pipeline, f"{na} samples at 500 Hz"),
    ], mine, "run (1 sensor)")
    print("\nlive, one sample per call")
    print_table([(update, "one compiled call (screening + filter)"), (ahrs_update, "")], update,
                "update")
    from multi_sensor_speed import print_floors  # the sibling benchmark's floors

    print_floors(gyr)


if __name__ == "__main__":
    main()
