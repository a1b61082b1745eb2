"""A magnet carried by the sensor at 1-10 cm: each method's error per distance, simulated.

BROAD's attached-magnet trials have the magnet at 1, 3 and 5 cm; this sweep shows the same
mechanism at the distances they do not cover, with truth everywhere. The magnet is a point
dipole fixed in the body frame (``margtrack.sim.attached_dipole``): a constant hard-iron
offset of ``2 (μ0/4π) m / r³`` along the magnet's axis (0.1 A·m²: 20 mT at 1 cm, 20 µT at
10 cm, against a 50 µT earth field), present from the first sample. The motion is
``margtrack.sim.random_motion`` (60 s at 100 Hz, up to 200 deg/s, 2 cm translation) seen
by the consumer-MEMS error presets, in ENU; the same motion and noise at every distance
(one seed per repetition), so the rows differ only by the magnet. The magnetometer preset
clips at ±4900 µT, so at 1 cm (20 mT) its x axis sits at the clip level, which the input
screening learns and ignores: no usable field there.

Per distance and method: the RMSE (deg) of total, heading and inclination error over all
samples (``margtrack.bench.runner.score``), mean over the seeds. Methods: margtrack's
(default robust, bachmann, gradient, ekf, bias-kf, and the gyro-free TRIAD, whose heading
follows the magnetometer sample by sample) with their defaults; ``robust-no-hi``, robust
without its online hard-iron estimate (``hard_iron_tau_s=0``: robust before it); and
vqf's ``VQF`` and ``offlineVQF`` (defaults) when vqf is installed.

Run: python benchmarks/attached_magnet_sweep.py [--distances-cm 1,2,3,4,5,7,10]
     [--moment 0.1] [--seeds 3] [--methods robust,triad] [--no-before] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from margtrack import methods, sim
from margtrack.bench.runner import KEYS, Method, evaluate

DEFAULT_METHODS = ("robust", "bachmann", "gradient", "ekf", "bias-kf", "triad")
DEFAULT_DISTANCES_CM = (1.0, 2.0, 3.0, 4.0, 5.0, 7.0, 10.0)


def peers() -> list[tuple[str, Method]]:
    """vqf's online and offline filters as methods, when vqf is installed."""
    if importlib.util.find_spec("vqf") is None:
        return []
    from margtrack.bench.external import EXTERNAL

    return [("vqf", EXTERNAL["vqf"]), ("vqf-offline", EXTERNAL["vqf-offline"])]


def recording(
    distance_cm: float | None,
    seed: int,
    moment_am2: float = 0.1,
    duration_s: float = 60.0,
    rate_hz: float = 100.0,
):
    """The simulated recording with the magnet at ``distance_cm`` (None: no magnet).

    The magnet sits on the body x axis with its moment along it (on-axis field).
    """
    motion = sim.random_motion(
        duration_s, rate_hz, seed, max_rate_deg_s=200.0, bandwidth_hz=2.0, translation_m=0.02
    )
    magnet = [] if distance_cm is None else [sim.attached_dipole(distance_cm / 100, moment_am2)]
    return sim.simulate(
        motion, frame="ENU", gyr_errors=sim.SensorErrors.mems_gyr(),
        acc_errors=sim.SensorErrors.mems_acc(), mag_errors=sim.SensorErrors.mems_mag(),
        mag_disturbances=magnet, seed=seed, name=f"magnet-{distance_cm}cm-{seed}",
    )


def sweep(
    runs: Sequence[tuple[str, Method]],
    distances_cm: Sequence[float | None] = (None, *DEFAULT_DISTANCES_CM),
    seeds: Sequence[int] = (0, 1, 2),
    moment_am2: float = 0.1,
    duration_s: float = 60.0,
    rate_hz: float = 100.0,
) -> list[dict[str, Any]]:
    """One row per (distance, method): the mean over ``seeds`` of each figure in :data:`KEYS`.

    ``distance_cm`` None is the recording without a magnet (the baseline).
    """
    rows = []
    for distance in distances_cm:
        recs = [recording(distance, s, moment_am2, duration_s, rate_hz) for s in seeds]
        offset = 0.0 if distance is None else float(
            np.linalg.norm(sim.attached_dipole(distance / 100, moment_am2).offset_ut)
        )
        for name, method in runs:
            scores = [evaluate(method, r) for r in recs]
            rows.append({
                "distance_cm": distance,
                "offset_ut": offset,
                "method": name,
                **{k: float(np.mean([getattr(s, k) for s in scores])) for k in KEYS},
            })
    return rows


def print_table(rows: list[dict[str, Any]], moment_am2: float, n_seeds: int) -> None:
    print(f"attached dipole {moment_am2:g} A·m² on the body x axis, moment along it; "
          f"RMSE (deg), mean of {n_seeds} seed(s)")
    print(f"{'distance':>9} {'|offset| µT':>12}  {'method':<12} {'total':>7} {'heading':>8} "
          f"{'inclin.':>8}")
    last = object()
    for r in rows:
        d = "none" if r["distance_cm"] is None else f"{r['distance_cm']:g} cm"
        if r["distance_cm"] != last:
            print()
            last = r["distance_cm"]
        print(f"{d:>9} {r['offset_ut']:>12.1f}  {r['method']:<12} {r['total_rmse_deg']:>7.2f} "
              f"{r['heading_rmse_deg']:>8.2f} {r['inclination_rmse_deg']:>8.2f}")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--distances-cm", default=",".join(f"{d:g}" for d in DEFAULT_DISTANCES_CM))
    parser.add_argument("--moment", type=float, default=0.1, help="A·m² (default 0.1)")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--duration", type=float, default=60.0, help="s (default 60)")
    parser.add_argument("--methods", default=",".join(DEFAULT_METHODS))
    parser.add_argument("--no-peers", action="store_true", help="leave vqf out")
    parser.add_argument("--no-before", action="store_true",
                        help="leave out robust without its hard-iron estimate")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    distances = [None, *(float(d) for d in args.distances_cm.split(","))]
    runs: list[tuple[str, Method]] = [
        (m, methods.get(m)(frame="ENU")) for m in args.methods.split(",") if m
    ]
    if not args.no_before:
        runs.append(("robust-no-hi", methods.get("robust")(frame="ENU", hard_iron_tau_s=0.0)))
    if not args.no_peers:
        runs += peers()
    start = time.perf_counter()
    rows = sweep(runs, distances, range(args.seeds), args.moment, args.duration)
    print_table(rows, args.moment, args.seeds)
    print(f"\n{time.perf_counter() - start:.0f} s (numba compiles included)")
    if args.json:
        out = Path(args.json)
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(json.dumps(rows, indent=2))
        os.replace(tmp, out)  # written whole or not at all


if __name__ == "__main__":
    main()
