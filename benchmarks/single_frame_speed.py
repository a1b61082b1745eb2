"""Speed of the single-frame estimators next to ahrs's FQA, QUEST, TRIAD and Davenport.

Run ``python benchmarks/single_frame_speed.py [--samples N] [--source broad|sim]
[--repeats N] [--ahrs-repeats N]``.

Input: the first ``--samples`` (default 100,000) samples of the 16 BROAD trials of
../shared/data/broad concatenated (286 Hz, real motion), or a simulated noisy 100 Hz random
motion (``--source sim``, or when the data are absent). Every estimator runs through its
public ``run(acc=, mag=, t=, check_units=False)`` (validation, state, kernel; "kernel"
times the kernel call alone), state reset before each run, best of ``--repeats`` with
compilation excluded; ahrs runs ``--ahrs-repeats`` times (default once: its per-sample
Python loop takes seconds) per estimator on the same samples. Times are process CPU times,
so other processes on a shared machine slow neither side. Printed: samples/s, µs/sample,
the ratio to the ahrs counterpart (TRIAD/TRIAD, FQA/FQA, QUEST/QUEST, Davenport/Davenport;
Gauss-Newton and Newton, which ahrs lacks, against ahrs's QUEST, its fastest of the
three named in issue 3) and to the slowest and fastest ahrs estimator measured; last, the
floors of ``multi_sensor_speed.print_floors`` in ns per sample (a single-frame estimator has
no serial chain: the memory floor is its limit).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from margtrack.bench.experiments.single_frame import COUNTERPART, speed_input, speed_table
from margtrack.recording import Recording

BROAD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "broad"


def broad_input(n: int) -> Recording | None:
    """The first n samples of the BROAD trials concatenated (timestamps made continuous)."""
    if not (BROAD / "trials.json").is_file():
        return None
    from margtrack.io import broad_trials, read_broad

    parts: list[Recording] = []
    total = 0
    for trial in broad_trials(BROAD):
        parts.append(read_broad(trial.path))
        total += parts[-1].n_samples
        if total >= n:
            break
    acc = np.concatenate([r.acc for r in parts])[:n]
    mag = np.concatenate([r.mag for r in parts])[:n]
    gyr = np.concatenate([r.gyr for r in parts])[:n]
    t = np.arange(acc.shape[0]) / 285.714
    return Recording(t=t, gyr=gyr, acc=acc, mag=mag, frame="ENU", name="broad-concatenated")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--ahrs-repeats", type=int, default=1)
    parser.add_argument("--source", choices=("broad", "sim"), default="broad")
    args = parser.parse_args()
    rec = broad_input(args.samples) if args.source == "broad" else None
    source = "BROAD trials concatenated"
    if rec is None:
        rec, source = speed_input(args.samples), "simulated noisy random motion, 100 Hz"
    print(f"input: {rec.n_samples} samples, {source}\n")
    rates = speed_table(rec, repeats=args.repeats, ahrs_repeats=args.ahrs_repeats)
    ahrs = {k: v for k, v in rates.items() if k.startswith("ahrs")}
    ours = {k: v for k, v in rates.items() if k not in ahrs and not k.endswith("kernel")}
    slow = min(ahrs.values(), default=float("nan"))
    fast = max(ahrs.values(), default=float("nan"))
    head = f"{'':14}{'samples/s':>12}{'us/sample':>11}{'kernel/s':>12}  {'vs counterpart':>28}"
    print(head + f"{'vs slowest ahrs':>17}{'vs fastest ahrs':>17}")
    for name, rate in ours.items():
        other = COUNTERPART[name]
        ratio = f"{rate / ahrs[other]:7.0f} x {other}" if other in ahrs else "n/a"
        print(f"{name:14}{rate:12.4g}{1e6 / rate:11.4g}{rates[name + ' kernel']:12.4g}  "
              f"{ratio:>28}{rate / slow:17.0f}{rate / fast:17.0f}")
    for name, rate in ahrs.items():
        print(f"{name:14}{rate:12.4g}{1e6 / rate:11.4g}")
    if not ahrs:
        print("(ahrs is not installed: no comparison)")
    else:
        print(f"\nfqa / quest = {ours['fqa'] / ours['quest']:.2f} "
              "(002 III-D: FQA 25 % faster than QUEST in MATLAB, 1.25)")
    from multi_sensor_speed import print_floors  # the sibling benchmark's floors

    print_floors(rec.gyr)  # (no serial chain in a single-frame estimator: the memory floor)


if __name__ == "__main__":
    main()
