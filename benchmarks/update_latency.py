"""Latency of one live sample: µs per ``update()`` call of every recursive method, with peers.

Run ``python benchmarks/update_latency.py [--calls N] [--warmup N] [--repeats N]``.

Input: the 16 BROAD trials of ../shared/data/broad concatenated (gyr rad/s, acc m/s²,
mag µT at 286 Hz; the first ``--warmup + --calls`` samples are used), or a simulated random
motion when the data are absent (a note says so). Every method gets the same samples.

Measured in one run, on one thread, with ``time.perf_counter_ns`` around a Python loop of
``--calls`` calls (after ``--warmup`` calls that compile the numba kernels and pass the
unit check of the first 500 updates; each from a fresh instance; the rows are measured in
turn, ``--repeats`` rounds, and the best of each row is kept):

- margtrack ``Estimator.update(gyr, acc, mag)`` for every registered method that uses the
  gyroscope (the whole public path: unit probe, screening, state copy, kernel, flags);
- imufusion ``Ahrs.update(gyr_deg_s, acc_g, mag)`` (x-io's Fusion, C, ENU, default gain;
  it takes deg/s and g, converted before timing);
- vqf ``VQF.update(gyr, acc, mag)`` (VQF's C++ core, one Cython call per sample).

The loop and the row indexing are the same for every row, so the figures compare the cost
of the call. Printed: µs per call and how many times a peer's cost each row is (> 1: the
row is slower than that peer).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from functools import partial

import numpy as np
from numpy.typing import NDArray

from margtrack import methods
from margtrack.bench.speed import speed_input
from margtrack.frames import STANDARD_GRAVITY_M_S2

Array = NDArray[np.float64]
RATE_HZ = 285.714  # BROAD's sampling rate

#: the recursive methods, in the order printed
METHODS = ("gyro", "gradient", "bachmann", "robust", "ekf", "bias-kf")

Step = Callable[[Array, Array, Array], object]
Row = tuple[Array, Array, Array]


def recursive_methods() -> list[str]:
    """Registered methods that read the gyroscope and have an ``update`` (not the offline
    ones), ``METHODS`` first, any new one after."""
    found = [m for m in methods.available()
             if methods.get(m).uses_gyr and not getattr(methods.get(m), "offline", False)]
    return [m for m in METHODS if m in found] + sorted(set(found) - set(METHODS))


def margtrack_step(name: str) -> Step:
    """One ``update`` of a fresh estimator of method ``name`` at BROAD's rate."""
    est = methods.create(name, rate_hz=RATE_HZ)
    return est.update


def imufusion_step() -> Step:
    """One ``Ahrs.update`` of a fresh imufusion AHRS (ENU, default gain); deg/s and g in."""
    import imufusion

    ahrs = imufusion.Ahrs()
    # set as attributes: imufusion 1.3.3's AhrsSettings(convention=...) keyword is ignored
    settings = imufusion.AhrsSettings()
    settings.sample_rate = round(RATE_HZ)
    settings.convention = imufusion.CONVENTION_ENU
    ahrs.set_settings(settings)
    ahrs.set_sample_period(1.0 / RATE_HZ)
    return ahrs.update


def vqf_step() -> Step:
    """One ``VQF.update`` of a fresh VQF (default parameters)."""
    from vqf import VQF

    return VQF(1.0 / RATE_HZ).update


def time_calls(make: Callable[[], Step], rows: Sequence[Row], warmup: int) -> float:
    """µs per call of a fresh instance over ``rows``: the first ``warmup`` untimed."""
    step = make()
    for g, a, m in rows[:warmup]:
        step(g, a, m)
    timed = rows[warmup:]
    start = time.perf_counter_ns()
    for g, a, m in timed:
        step(g, a, m)
    return (time.perf_counter_ns() - start) / 1e3 / len(timed)


def best_of(
    makers: dict[str, tuple[Callable[[], Step], Sequence[Row]]], warmup: int, repeats: int
) -> dict[str, float]:
    """Best µs per call of each maker, the rows measured in turn ``repeats`` times over.

    Round-robin rather than one row after another, so a change of machine load between
    rows shows in every row alike and the ratios stay fair.
    """
    best = dict.fromkeys(makers, float("inf"))
    for _ in range(max(1, repeats)):
        for label, (make, rows) in makers.items():
            best[label] = min(best[label], time_calls(make, rows, warmup))
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20_000, help="timed calls per row")
    parser.add_argument("--warmup", type=int, default=1_000, help="untimed calls first")
    parser.add_argument("--repeats", type=int, default=3, help="best of this many")
    args = parser.parse_args()
    if args.calls <= 0 or args.warmup <= 0:
        parser.error("--calls and --warmup must be > 0")
    n = args.warmup + args.calls
    data = speed_input(n, rate_hz=RATE_HZ, fallback_duration_s=1.1 * n / RATE_HZ)
    if "BROAD" not in data.source:
        print(
            "note: ../shared/data/broad is absent; timing on a simulated random motion "
            "instead (same rates and units, the figures compare the same way)"
        )
    gyr, acc, mag = data.gyr, data.acc, data.mag
    print(f"input: first {n} samples of {data.source}, {RATE_HZ} Hz, MARG")
    print(
        f"{args.calls} timed calls after {args.warmup} warm-up calls, best of {args.repeats}, "
        "time.perf_counter_ns\n"
    )

    rows = [(gyr[i], acc[i], mag[i]) for i in range(n)]
    gyr_deg_s = np.degrees(gyr)
    acc_g = acc / STANDARD_GRAVITY_M_S2
    rows_fusion = [(gyr_deg_s[i], acc_g[i], mag[i]) for i in range(n)]  # deg/s and g
    makers: dict[str, tuple[Callable[[], Step], Sequence[Row]]] = {
        f"margtrack {name}.update": (partial(margtrack_step, name), rows)
        for name in recursive_methods()
    }
    makers["imufusion Ahrs.update"] = (imufusion_step, rows_fusion)
    makers["vqf VQF.update"] = (vqf_step, rows)
    us = best_of(makers, args.warmup, args.repeats)
    fusion, vqf = us["imufusion Ahrs.update"], us["vqf VQF.update"]
    notes = {
        "imufusion Ahrs.update": "C, one Python call per sample",
        "vqf VQF.update": "C++, one Cython call per sample",
    }
    rows_out = [
        (label, value, notes.get(label, "public update(): screening + kernel"))
        for label, value in us.items()
    ]

    width = max(len(label) for label, _, _ in rows_out)
    head = f"{'':{width}}  {'us/call':>9}  {'x imufusion':>11}  {'x vqf':>8}  note"
    print(head)
    print("-" * len(head))
    for label, value, note in rows_out:
        print(f"{label:{width}}  {value:9.2f}  {value / fusion:11.1f}  {value / vqf:8.1f}  {note}")
    ours = [value for label, value, _ in rows_out if label.startswith("margtrack")]
    print(
        f"\nmargtrack update(): {min(ours):.1f} to {max(ours):.1f} us per call, "
        f"{min(ours) / fusion:.0f}x to {max(ours) / fusion:.0f}x imufusion's and "
        f"{min(ours) / vqf:.0f}x to {max(ours) / vqf:.0f}x vqf's per-sample call."
    )


if __name__ == "__main__":
    main()
