"""Speed of Marins' EKF (``ekf``), approaches 2 and 1 and the bias state, next to vqf and ahrs.

Run ``python benchmarks/ekf_speed.py [--samples N] [--ahrs-samples N] [--calls N]``.

Input: the 16 BROAD trials of ../shared/data/broad concatenated (858,735 samples at 286 Hz;
cut to ``--samples``), or a simulated random motion if the data are absent. Printed, best
of 3 with compilation excluded:

- batch throughput, samples/s and ns/sample: margtrack ``MarinsEkf.run`` with approach 2
  (gyro + Gauss-Newton quaternion, ``H = I``; 001's choice) and approach 1 (nine
  nonlinear outputs) for 1 sensor, approach 2 with the gyro bias state
  (``bias_states=True``, 10 states), approach 2 for 8 sensors in one call, and approach 2
  with one Gauss-Newton iteration per sample; ``vqf.VQF.updateBatch`` (C++) on the same
  samples in the same run (the issue's reference: the ratio column against it);
  ``ahrs.filters.EKF`` (pure Python, a 4-state quaternion EKF with acc/mag outputs,
  MARG because ``mag`` is given to its batch constructor) on the first
  ``--ahrs-samples`` only (about 0.1 ms per sample);
- per-call cost of one live sample, µs: ``MarinsEkf.update`` and ahrs ``EKF.update``
  (which uses the magnetometer only when the object's ``mag`` attribute is set: it is);

with ratios to vqf's batch (batch rows) and to ``MarinsEkf.update`` (live rows). The
cost of approach 1 relative to approach 2 is 001's argument for approach 2. Last, the two
floors in ns per sample, one thread (``multi_sensor_speed.print_floors``: the bytes a 9-D
filter moves per sample at the measured copy bandwidth, and one quaternion integration
step), beside which the batch rows' ns/sample stand.
"""

from __future__ import annotations

import argparse

import numpy as np

from margtrack.bench.speed import Throughput, measure, print_table, speed_input
from margtrack.methods.ekf import MarinsEkf, MarinsEkfParams

RATE_HZ = 285.714
N_SENSORS = 8






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

    def batch(params: MarinsEkfParams, label: str) -> Throughput:
        return measure(label, lambda: MarinsEkf(params).run(gyr=gyr, acc=acc, mag=mag, t=t), n)

    defaults = MarinsEkfParams()
    two = batch(defaults, "margtrack MarinsEkf.run, approach 2")
    one = batch(MarinsEkfParams(approach=1), "margtrack MarinsEkf.run, approach 1")
    bias = batch(MarinsEkfParams(bias_states=True), "approach 2, bias_states (10 states)")
    single = batch(MarinsEkfParams(gn_max_iterations=1), "approach 2, 1 Gauss-Newton step")
    import vqf

    reference = measure("vqf VQF.updateBatch (C++)", lambda: vqf.VQF(1.0 / RATE_HZ).updateBatch(
        gyr, acc, mag), n)
    iterations = MarinsEkf().run(gyr=gyr, acc=acc, mag=mag, t=t).outputs["iterations"]
    m = min(n, 100_000)
    stack = [np.ascontiguousarray(np.broadcast_to(x[:m], (N_SENSORS, m, 3)))
             for x in (gyr, acc, mag)]
    multi = measure(f"approach 2, {N_SENSORS} sensors", lambda: MarinsEkf().run(
        gyr=stack[0], acc=stack[1], mag=stack[2], t=t[:m]), N_SENSORS * m)

    from ahrs.filters import EKF

    k = min(n, args.ahrs_samples)
    ahrs_batch = measure("ahrs EKF (batch constructor, MARG)", lambda: EKF(
        gyr=gyr[:k], acc=acc[:k], mag=mag[:k], frequency=RATE_HZ), k, repeats=1)

    calls = min(args.calls, n)
    live = MarinsEkf(rate_hz=RATE_HZ)

    def run_live() -> None:
        live.reset()
        for i in range(calls):
            live.update(gyr[i], acc[i], mag[i])

    update = measure("margtrack MarinsEkf.update", run_live, calls)
    ekf = EKF(frequency=RATE_HZ)
    ekf.mag = mag[:calls]  # ahrs's h() switches to MARG when its mag attribute is set

    def run_ahrs_live() -> None:
        q = np.array([1.0, 0.0, 0.0, 0.0])
        for i in range(calls):
            q = ekf.update(q, gyr[i], acc[i], mag[i])

    ahrs_update = measure("ahrs EKF.update", run_ahrs_live, calls)

    print(f"\nbatch (compilation excluded; approach 2 default: at most "
          f"{defaults.gn_max_iterations} Gauss-Newton steps, {iterations.mean():.2f} on average)")
    print_table([
        (two, f"{1e3 * two.us_per_sample:.0f} ns/sample"),
        (one, f"approach 1 costs {two.samples_per_s / one.samples_per_s:.2f} x approach 2"),
        (bias, f"{1e3 * bias.us_per_sample:.0f} ns/sample"),
        (single, ""),
        (multi, f"{N_SENSORS} x {m} samples"),
        (reference, f"{1e3 * reference.us_per_sample:.0f} ns/sample"),
        (ahrs_batch, f"first {k} samples only"),
    ], reference, "vqf")
    print("\nlive, one sample per call")
    print_table([(update, "validation, state copy, kernel"), (ahrs_update, "")], update, "update")
    from multi_sensor_speed import print_floors  # the sibling benchmark's floors

    print_floors(gyr)


if __name__ == "__main__":
    main()
