"""How well each method recovers from a gap in the middle of the movement, on BROAD.

Run ``python benchmarks/gap_recovery.py [--methods robust smoother ...] [--gap-s 2]
[--folder ../shared/data/broad] [--truth-window]``.

For every BROAD trial: the middle of its ``movement`` mask (the median of the movement
samples' times), ``--gap-s`` s of samples deleted there (the timestamps jump by more than
``max_gap_s``, so the method sees a gap and restarts), the method run with its default
parameters on the clean trial and on the cut one, both scored as ``margtrack evaluate``
scores (total RMSE, deg, over the movement samples that remain). Printed per trial and
method: clean, with the gap, and their ratio; then the mean over trials.

``--truth-window``: instead, what any window after the gap can know of the inclination.
The accelerations of the first 1.5 s and 3 s after the gap carried into the earth frame
by the optical truth (not the gyroscope), and the tilt of their mean: gravity plus the
velocity change over the window over its length, the physics of the motion and not a
filter's error (``estimator/restart_kernel.py``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from margtrack import quaternion as quat
from margtrack import registry
from margtrack.bench.runner import evaluate
from margtrack.io.broad import broad_trials, read_broad
from margtrack.recording import Recording

DEFAULT_FOLDER = Path(__file__).resolve().parents[2] / "shared" / "data" / "broad"


def with_gap(rec: Recording, gap_s: float) -> Recording:
    """``rec`` with ``gap_s`` s of samples removed at the middle of its movement."""
    moving = np.flatnonzero(rec.movement) if rec.movement is not None else np.arange(rec.t.size)
    t_mid = float(np.median(rec.t[moving]))
    keep = (rec.t < t_mid - gap_s / 2) | (rec.t >= t_mid + gap_s / 2)

    def cut(x):
        return None if x is None else x[keep]

    return Recording(t=rec.t[keep], gyr=rec.gyr[keep], acc=rec.acc[keep], mag=cut(rec.mag),
                     quat_true=cut(rec.quat_true), movement=cut(rec.movement), frame=rec.frame,
                     name=rec.name, meta=dict(rec.meta))


def truth_window_tilt_deg(cut: Recording, window_s: float) -> float:
    """deg, the tilt of the mean of ``cut``'s accelerations over ``window_s`` s after its
    gap, each carried into the earth frame by the truth (samples without truth left out)."""
    k = int(np.argmax(np.diff(cut.t))) + 1  # the gap: the longest interval
    span = slice(k, int(np.searchsorted(cut.t, cut.t[k] + window_s)))
    q = cut.quat_true[span]
    known = np.all(np.isfinite(q), axis=1)
    mean = quat.rotate(q[known], cut.acc[span][known]).mean(axis=0)
    return float(np.degrees(np.arctan2(np.hypot(mean[0], mean[1]), abs(mean[2]))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", nargs="+", default=["robust", "smoother"])
    parser.add_argument("--gap-s", type=float, default=2.0)
    parser.add_argument("--folder", type=Path, default=DEFAULT_FOLDER)
    parser.add_argument("--truth-window", action="store_true",
                        help="the tilt of the truth-carried mean acceleration after the gap")
    args = parser.parse_args()
    trials = broad_trials(args.folder)
    recs = [read_broad(tr.path) for tr in trials]
    cuts = [with_gap(r, args.gap_s) for r in recs]
    if args.truth_window:
        print(f"tilt (deg) of the mean acceleration over the window after the gap, carried "
              f"by the truth\n{'trial':42s} {'1.5 s':>7s} {'3 s':>7s}")
        for tr, cut in zip(trials, cuts, strict=True):
            print(f"{tr.name:42s}" + "".join(f" {truth_window_tilt_deg(cut, w):7.2f}"
                                             for w in (1.5, 3.0)))
        return
    for method in args.methods:
        est = registry.create(method)
        print(f"\n{method}: total RMSE, deg, over the movement samples ({args.gap_s:g} s gap)")
        print(f"{'trial':42s} {'clean':>7s} {'gap':>7s} {'ratio':>6s}")
        clean_all, gap_all = [], []
        for tr, rec, cut in zip(trials, recs, cuts, strict=True):
            clean = evaluate(est, rec).errors.total_rmse_deg
            gap = evaluate(est, cut).errors.total_rmse_deg
            clean_all.append(clean)
            gap_all.append(gap)
            mark = "" if gap <= 1.25 * clean else "  > 1.25x"
            print(f"{tr.name:42s} {clean:7.2f} {gap:7.2f} {gap / clean:6.2f}{mark}", flush=True)
        c, g = float(np.mean(clean_all)), float(np.mean(gap_all))
        worst = max(g / c for g, c in zip(gap_all, clean_all, strict=True))
        print(f"{'mean over trials':42s} {c:7.2f} {g:7.2f} {g / c:6.2f}  (worst ratio {worst:.2f})")


if __name__ == "__main__":
    main()
