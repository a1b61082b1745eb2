"""Speed of the gradient filter next to ahrs's Madgwick, imufusion and vqf on the same data.

Run ``python benchmarks/gradient_speed.py [--samples N] [--ahrs-samples N] [--calls N]``.

Input: the 16 BROAD trials of ../shared/data/broad concatenated (858,735 samples at 286 Hz;
repeated or cut to ``--samples``), or a simulated random motion if the data are absent.
Printed, best of 3 with compilation excluded:

- batch throughput, samples/s: margtrack ``Gradient.run`` for 1 sensor and for 15 sensors
  in one call ((15, N, 3) arrays, all 15 N samples counted); vqf ``VQF.updateBatch`` (C++,
  causal) and ``offlineVQF`` (C++, acausal); ahrs ``Madgwick`` (pure Python, its own
  per-sample loop, on the first ``--ahrs-samples``);
- per-call cost of one live sample, µs: margtrack ``Gradient.update`` and ``update_gyr``
  (the whole public API: validation, state copy, kernel), ahrs ``Madgwick.updateMARG``,
  imufusion ``Ahrs.update`` (C, one Python call per sample);

with ratios to margtrack's one-sensor ``run`` and to its ``update``.
"""

from __future__ import annotations

import argparse

import numpy as np

from margtrack.bench.speed import Throughput, measure, print_table, speed_input
from margtrack.methods.gradient import Gradient

RATE_HZ = 285.714  # BROAD's sampling rate
N_SENSORS = 15






def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=None, help="default: all BROAD samples")
    parser.add_argument("--ahrs-samples", type=int, default=50_000)
    parser.add_argument("--calls", type=int, default=20_000, help="per-call measurements")
    args = parser.parse_args()
    data = speed_input(args.samples, rate_hz=RATE_HZ)
    gyr, acc, mag, source = data.gyr, data.acc, data.mag, data.source
    n = gyr.shape[0]
    print(f"input: {n} samples from {source}, {RATE_HZ} Hz, MARG\n")

    import imufusion
    from ahrs.filters import Madgwick
    from vqf import VQF, offlineVQF

    # -- batch ---------------------------------------------------------------------------
    batch: list[tuple[Throughput, str]] = []
    base = measure("margtrack Gradient.run, 1 sensor",
                   lambda: Gradient().run(gyr=gyr, acc=acc, mag=mag, rate_hz=RATE_HZ), n)
    batch.append((base, "numba kernel"))
    stacked = {k: np.ascontiguousarray(np.broadcast_to(x, (N_SENSORS, n, 3)))
               for k, x in (("gyr", gyr), ("acc", acc), ("mag", mag))}
    many = measure(f"margtrack Gradient.run, {N_SENSORS} sensors",
                   lambda: Gradient().run(**stacked, rate_hz=RATE_HZ), N_SENSORS * n)
    batch.append((many, "one kernel call, every sensor's samples counted"))
    stacked.clear()
    batch.append((measure("vqf VQF.updateBatch",
                          lambda: VQF(1.0 / RATE_HZ).updateBatch(gyr, acc, mag), n),
                  "C++ loop, causal"))
    batch.append((measure("vqf offlineVQF",
                          lambda: offlineVQF(gyr, acc, mag, 1.0 / RATE_HZ), n),
                  "C++, acausal"))
    m = min(args.ahrs_samples, n)
    batch.append((measure("ahrs Madgwick(gyr, acc, mag)",
                          lambda: Madgwick(gyr=gyr[:m], acc=acc[:m], mag=mag[:m],
                                           frequency=RATE_HZ, gain=0.08), m, repeats=1),
                   f"pure Python, first {m} samples"))
    print("batch")
    print_table(batch, base, "run 1 sensor")

    # -- per call ------------------------------------------------------------------------
    calls = min(args.calls, n)
    live = Gradient(rate_hz=RATE_HZ)
    live.update(gyr[0], acc[0], mag[0])

    def updates() -> None:
        for i in range(calls):
            live.update(gyr[i], acc[i], mag[i])

    per_call: list[tuple[Throughput, str]] = []
    upd = measure("margtrack Gradient.update", updates, calls)
    per_call.append((upd, "whole public API per sample"))
    asyn = Gradient(rate_hz=RATE_HZ)
    asyn.update_acc(acc[0])
    asyn.update_mag(mag[0])
    asyn.update_gyr(gyr[0])

    def async_updates() -> None:
        for i in range(calls):
            asyn.update_acc(acc[i])
            asyn.update_mag(mag[i])
            asyn.update_gyr(gyr[i])

    per_call.append((measure("margtrack update_acc+update_mag+update_gyr", async_updates, calls),
                     "three calls per sample"))
    madgwick = Madgwick(gain=0.08, Dt=1.0 / RATE_HZ)
    q = np.array([1.0, 0.0, 0.0, 0.0])

    def ahrs_calls() -> None:
        nonlocal q
        for i in range(calls):
            q = madgwick.updateMARG(q, gyr[i], acc[i], mag[i])

    per_call.append((measure("ahrs Madgwick.updateMARG", ahrs_calls, calls, repeats=1),
                     "pure Python"))
    gyr_deg = np.degrees(gyr)
    acc_g = acc / 9.80665
    fusion = imufusion.Ahrs()
    fusion.set_settings(imufusion.AhrsSettings(sample_rate=round(RATE_HZ)))
    fusion.set_sample_period(1.0 / RATE_HZ)

    def fusion_calls() -> None:
        for i in range(calls):
            fusion.update(gyr_deg[i], acc_g[i], mag[i])

    per_call.append((measure("imufusion Ahrs.update", fusion_calls, calls), "C, Python call"))
    print("\nper call (one sample)")
    print_table(per_call, upd, "update")
    vqf = batch[2][0]
    print(f"\nGradient.run is {base.ratio_to(vqf):.2f}x vqf updateBatch per sample "
          f"({many.ratio_to(vqf):.2f}x with {N_SENSORS} sensors per call); "
          f"update() costs {upd.us_per_sample:.1f} us per call, "
          f"{per_call[2][0].us_per_sample / upd.us_per_sample:.2f}x less than ahrs updateMARG.")
    from multi_sensor_speed import print_floors  # the sibling benchmark's floors

    print_floors(gyr)


if __name__ == "__main__":
    main()
