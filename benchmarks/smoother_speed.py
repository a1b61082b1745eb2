"""Speed of the smoother (``smoother``) on one stream, next to offline VQF.

Run ``python benchmarks/smoother_speed.py [--samples N] [--repeats K]``.

Input: the BROAD trials of ../shared/data/broad concatenated (a simulated random motion
if the data are absent), cut to ``--samples`` (300,000 by default), on a uniform time base
at 285.714 Hz. Printed, best of ``--repeats`` with compilation excluded, samples/s and
µs/sample of

- ``Smoother.run`` (``robust``'s forward pass included);
- ``vqf.offlineVQF`` (C++, VQF's offline estimate: a forward and a backward pass) on the
  same samples in the same run: the ratio column is against it;

then the smoother's time split into ``robust``'s forward pass, the accelerometer's
low-pass, the Kalman filter forward
and the Rauch-Tung-Striebel pass backward (each timed inside one run).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from margtrack.bench.speed import measure, print_table, speed_input
from margtrack.methods import smoother as smoother_module
from margtrack.methods.robust import Robust
from margtrack.methods.smoother import Smoother

RATE_HZ = 285.714


def split(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, t: np.ndarray) -> dict[str, float]:
    """Seconds of one ``Smoother.run`` spent in ``robust``, the accelerometer's low-pass,
    the forward filter and the backward pass (the module's functions wrapped with a timer
    for this call only)."""
    seconds: dict[str, float] = {}
    kernel = smoother_module.kernel
    originals = {"forward": kernel.forward, "backward": kernel.backward,
                 "low-pass": kernel.lowpassed_acc, "robust": Robust._run_arrays}

    def timed(name, func):
        def call(*args, **kwargs):
            start = time.perf_counter()
            out = func(*args, **kwargs)
            seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - start
            return out
        return call

    kernel.forward = timed("forward", originals["forward"])
    kernel.backward = timed("backward", originals["backward"])
    kernel.lowpassed_acc = timed("low-pass", originals["low-pass"])
    Robust._run_arrays = timed("robust", originals["robust"])
    try:
        start = time.perf_counter()
        Smoother().run(gyr=gyr, acc=acc, mag=mag, t=t)
        seconds["total"] = time.perf_counter() - start
    finally:
        kernel.forward, kernel.backward = originals["forward"], originals["backward"]
        kernel.lowpassed_acc = originals["low-pass"]
        Robust._run_arrays = originals["robust"]
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=300_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    data = speed_input(args.samples, rate_hz=RATE_HZ)
    gyr, acc, mag = data.gyr, data.acc, data.mag
    n = gyr.shape[0]
    t = np.arange(n) / RATE_HZ
    print(f"input: {data.source}, {n} samples used, one stream")
    import vqf

    smoother = measure("margtrack Smoother.run", lambda: Smoother().run(
        gyr=gyr, acc=acc, mag=mag, t=t), n, repeats=args.repeats)
    reference = measure("vqf offlineVQF (C++)", lambda: vqf.offlineVQF(
        gyr, acc, mag, 1.0 / RATE_HZ), n, repeats=args.repeats)
    print_table([(smoother, ""), (reference, "")], reference, "offline vqf")
    parts = split(gyr, acc, mag, t)
    print("\nthe smoother's time, one run: " + ", ".join(
        f"{name} {parts[name]:.3f} s"
        for name in ("robust", "low-pass", "forward", "backward", "total")))


if __name__ == "__main__":
    main()
