"""Speed of the Bachmann filter next to ahrs, imufusion and vqf on the same 1,000,000 samples.

Run ``python benchmarks/complementary_speed.py [--samples N] [--ahrs-samples N]``.

Input: the BROAD trials of ../shared/data/broad concatenated and repeated to N samples
(a simulated random motion if the data are absent), treated as one 286 Hz stream.
Printed: samples/s (best of 3, compilation excluded) of

- margtrack ``Bachmann.run`` for one sensor, for 15 sensors at once (the same stream for
  each, (15, N, 3) arrays; samples/s counts all 15 N), without the base class's unit
  plausibility check, and with the round-robin schedule;
- margtrack ``Bachmann.update`` per call (one sample through the whole public API);
- ahrs ``Madgwick`` (pure Python; on the first ``--ahrs-samples`` samples, one run);
- imufusion ``Ahrs.update`` called in a Python loop (C library, per-sample call);
- vqf ``VQF.updateBatch`` (C++ loop, causal) and ``offlineVQF`` (C++, acausal);

and the ratio of each to margtrack's one-sensor ``run``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from margtrack.bench.speed import Throughput, measure, speed_input
from margtrack.methods.bachmann import Bachmann

RATE_HZ = 286.0




def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--ahrs-samples", type=int, default=100_000)
    parser.add_argument("--update-calls", type=int, default=20_000)
    args = parser.parse_args()
    n = args.samples
    data = speed_input(n, rate_hz=RATE_HZ)
    gyr, acc, mag, source = data.gyr, data.acc, data.mag, data.source
    print(f"input: {n} samples from {source}, {RATE_HZ} Hz\n")
    results: list[tuple[Throughput, str]] = []

    def run_one() -> None:
        Bachmann().run(gyr=gyr, acc=acc, mag=mag, rate_hz=RATE_HZ)

    base = measure("margtrack Bachmann.run, 1 sensor", run_one, n)
    results.append((base, "numba kernel"))

    n_sensors = 15
    stacked = {
        k: np.ascontiguousarray(np.broadcast_to(x, (n_sensors, n, 3)))
        for k, x in (("gyr", gyr), ("acc", acc), ("mag", mag))
    }

    def run_many(check_units: bool = True, **params) -> None:
        Bachmann(**params).run(**stacked, rate_hz=RATE_HZ, check_units=check_units)

    many = measure("margtrack Bachmann.run, 15 sensors", run_many, n_sensors * n)
    results.append((many, "one kernel call, samples of all sensors counted"))
    unchecked = measure(
        "margtrack Bachmann.run, 15 sensors, check_units=False",
        lambda: run_many(check_units=False),
        n_sensors * n,
    )
    results.append((unchecked, "without the unit plausibility check"))
    rr = measure(
        "margtrack Bachmann.run, 15 sensors, round robin",
        lambda: run_many(correction_interval=n_sensors, round_robin=True),
        n_sensors * n,
    )
    results.append((rr, "one new correction per cycle (000)"))
    stacked.clear()

    calls = min(args.update_calls, n)
    live = Bachmann(rate_hz=RATE_HZ)
    live.update(gyr[0], acc[0], mag[0])

    def updates() -> None:
        for i in range(calls):
            live.update(gyr[i], acc[i], mag[i])

    results.append((measure("margtrack Bachmann.update per call", updates, calls), "Python API"))

    import imufusion
    from ahrs.filters import Madgwick
    from vqf import VQF, offlineVQF

    m = min(args.ahrs_samples, n)
    start = time.perf_counter()
    Madgwick(gyr=gyr[:m], acc=acc[:m], mag=mag[:m], frequency=RATE_HZ, beta=0.08)
    ahrs_t = Throughput("ahrs Madgwick", m, time.perf_counter() - start)
    results.append((ahrs_t, f"pure Python, first {m} samples, one run"))

    gyr_deg = np.degrees(gyr)
    acc_g = acc / 9.80665

    def fusion() -> None:
        ahrs = imufusion.Ahrs()
        ahrs.set_settings(imufusion.AhrsSettings(sample_rate=int(RATE_HZ)))
        for i in range(n):
            ahrs.update(gyr_deg[i], acc_g[i], mag[i])

    results.append((measure("imufusion Ahrs.update loop", fusion, n, repeats=1), "C, Python loop"))

    def vqf_batch() -> None:
        VQF(1.0 / RATE_HZ).updateBatch(gyr, acc, mag)

    results.append((measure("vqf VQF.updateBatch", vqf_batch, n), "C++ loop, causal"))
    results.append(
        (
            measure("vqf offlineVQF", lambda: offlineVQF(gyr, acc, mag, 1.0 / RATE_HZ), n),
            "C++, acausal",
        )
    )

    width = max(len(r.label) for r, _ in results)
    print(f"{'':{width}}  {'samples/s':>12}  {'us/sample':>10}  {'vs run 1':>8}  note")
    for r, note in results:
        print(
            f"{r.label:{width}}  {r.samples_per_s:12.4g}  {r.us_per_sample:10.4g}  "
            f"{r.ratio_to(base):8.3g}  {note}"
        )
    vqf = next(r for r, _ in results if r.label == "vqf VQF.updateBatch")
    print(
        f"\nBachmann.run (1 sensor) is {base.ratio_to(vqf):.2f}x vqf's updateBatch; "
        f"15 sensors at once: {many.ratio_to(vqf):.2f}x per sample."
    )
    from multi_sensor_speed import print_floors  # the sibling benchmark's floors

    print_floors(gyr)


if __name__ == "__main__":
    main()
