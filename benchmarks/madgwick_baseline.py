"""Baseline for every filter on BROAD: ``ahrs.filters.Madgwick`` (MARG) with one tuned β.

Run ``python benchmarks/madgwick_baseline.py [--data DIR] [--betas 0.05,0.07,...] [--jobs 2]``.

ahrs's Madgwick is wrapped as a margtrack :class:`Estimator` (``AhrsMadgwick`` below) so that
:func:`margtrack.bench.tune.tune` evaluates it exactly like margtrack's own methods: a fresh
filter per trial, one β for all 16 trials, RMSE over each trial's movement samples, then the
mean per group and overall. The filter itself is ahrs's, called sample by sample through
``Madgwick.updateMARG(q, gyr, acc, mag, dt)`` with the per-sample Δt.

Frames: ahrs's Madgwick estimates the orientation in NWU (x north, y west, z up;
docs/conventions.md). BROAD's truth is ENU, so every output is converted,
``q_enu = qz(+90°) ⊗ q_nwu``, before scoring. The start is the TRIAD orientation of the first
sample, the same one ahrs's own MARG start (``ecompass``) gives (tested in
tests/methods/test_gradient_ahrs.py). ahrs is pure Python (~56 µs per sample on an idle
core, ~50 s per β over the 858,735 BROAD samples), so the β grid is split over ``--jobs``
processes: about 2 min for the default 4 β on 2 idle cores.

Printed: every β's mean RMSE, the per-trial/per-group table of the best β, and for
comparison margtrack's ``gradient`` filter tuned the same way in the same run (its β grid,
the table of its best β, which is its documented default).

``--rest-null`` first subtracts from every trial's gyro the null that margtrack's
``bachmann`` and ``ekf`` take from the still start (``margtrack.methods.rest_null``, 1 s
minimum), so the filters without a bias state can be compared on the same input.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from rich.console import Console

from margtrack import quaternion as quat
from margtrack.bench.broad import format_table, group_order
from margtrack.bench.runner import Scores
from margtrack.bench.tune import tune
from margtrack.estimator import Estimator, Params, State
from margtrack.io import broad_trials, read_broad
from margtrack.methods.gradient import Gradient
from margtrack.methods.rest_null import RestNullState, subtract_rest_null
from margtrack.recording import Recording

BROAD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "broad"
# brackets the optimum; a wider scan gave total RMSE 5.28 deg at β 0.05 and 5.22 at 0.12
DEFAULT_BETAS = (0.07, 0.08, 0.09, 0.1)
GRADIENT_BETAS = (0.005, 0.01, 0.015, 0.02, 0.0225, 0.025, 0.0275, 0.03, 0.04, 0.05, 0.075, 0.1)
# q_enu = _NWU_TO_ENU ⊗ q_nwu: +90 deg about up (north = NWU x becomes ENU y)
_NWU_TO_ENU = np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])


@dataclass(frozen=True)
class AhrsMadgwickParams(Params):
    """β of ahrs's Madgwick, rad/s (its ``gain``; ahrs's MARG default 0.041); ENU output."""

    beta: float = 0.041


class AhrsMadgwick(Estimator[AhrsMadgwickParams, State]):
    """``ahrs.filters.Madgwick.updateMARG`` sample by sample, output converted NWU to ENU."""

    name = "ahrs-madgwick"
    params_type = AhrsMadgwickParams
    mag_optional = False

    def _new_state(self, quat0: np.ndarray) -> State:
        return State(quat=np.array(quat0, dtype=np.float64))

    def _process(self, state, gyr, acc, mag, dt):
        from ahrs.filters import Madgwick

        if self.params.frame != "ENU":
            raise ValueError("AhrsMadgwick reports ENU only")
        out = np.empty((acc.shape[0], acc.shape[1], 4))
        for s in range(acc.shape[0]):
            m = Madgwick(gain=self.params.beta)
            q = quat.multiply(quat.conjugate(_NWU_TO_ENU), state.quat[s])
            g, a, b = gyr[s], acc[s], mag[s]
            q_nwu = np.empty((acc.shape[1], 4))
            for i in range(acc.shape[1]):
                if dt[i] > 0.0:
                    q = m.updateMARG(q, g[i], a[i], b[i], dt=float(dt[i]))
                q_nwu[i] = q
            out[s] = quat.multiply(_NWU_TO_ENU, q_nwu)
            state.quat[s] = out[s, -1]
        return out, {}


def _without_rest_null(rec: Recording) -> Recording:
    """``rec`` with the gyro null of its still start (1 s minimum) subtracted."""
    dt = np.concatenate([[0.0], np.diff(rec.t)])
    mag = None if rec.mag is None else rec.mag[None].copy()
    gyr, _ = subtract_rest_null(
        RestNullState.new(1), rec.gyr[None].copy(), rec.acc[None].copy(), mag, dt, 1.0
    )
    return dataclasses.replace(rec, gyr=gyr[0])


def _recordings(folder: Path, rest_null: bool = False) -> list[tuple[Recording, tuple[str, ...]]]:
    recs = [(read_broad(t.path), tuple(t.groups)) for t in broad_trials(folder)]
    return [(_without_rest_null(r) if rest_null else r, g) for r, g in recs]


def _tune_one(folder: str, beta: float, rest_null: bool = False) -> Scores:
    """One β on every trial (runs in a worker process; reads the trials itself)."""
    recs = _recordings(Path(folder), rest_null)
    return tune(AhrsMadgwick, {"beta": [beta]}, recs, group_order=group_order(Path(folder))).best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=BROAD)
    parser.add_argument("--betas", default=",".join(str(b) for b in DEFAULT_BETAS))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--rest-null", action="store_true",
                        help="subtract the still-start gyro null from every trial first")
    args = parser.parse_args()
    betas = [float(b) for b in args.betas.split(",")]
    console = Console()
    n_trials = len(broad_trials(args.data))
    console.print(f"ahrs Madgwick (MARG) on {n_trials} BROAD trials, β grid {betas}, "
                  f"{args.jobs} process(es)"
                  + (", gyro null from the still start removed" if args.rest_null else ""))
    start = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        work = partial(_tune_one, rest_null=args.rest_null)
        results = list(pool.map(work, [str(args.data)] * len(betas), betas))
    elapsed = time.perf_counter() - start
    results.sort(key=lambda r: r.mean()["total_rmse_deg"])
    for r in sorted(results, key=lambda r: r.params["beta"]):
        m = r.mean()
        console.print(
            f"  beta={r.params['beta']:<6}  total {m['total_rmse_deg']:.3f}  "
            f"heading {m['heading_rmse_deg']:.3f}  inclination {m['inclination_rmse_deg']:.3f} deg"
        )
    best = results[0]
    console.print(f"grid done in {elapsed:.0f} s; "
                  f"{best.samples_per_s:.4g} samples/s for ahrs (one process)")
    console.print(format_table(best))
    console.print(f"[bold]baseline: ahrs Madgwick β = {best.params['beta']}: mean total RMSE "
                  f"{best.mean()['total_rmse_deg']:.2f} deg[/]")

    recs = _recordings(args.data, args.rest_null)
    ours = tune(Gradient, {"beta": list(GRADIENT_BETAS)}, recs, group_order=group_order(args.data))
    console.print("\nmargtrack gradient (MARG, forward component), same trials, same metric:")
    for r in sorted(ours.results, key=lambda r: r.params["beta"]):
        m = r.mean()
        console.print(
            f"  beta={r.params['beta']:<6}  total {m['total_rmse_deg']:.3f}  "
            f"heading {m['heading_rmse_deg']:.3f}  inclination {m['inclination_rmse_deg']:.3f} deg"
        )
    console.print(format_table(ours.best))
    default = next(r for r in ours.results if r.params["beta"] == Gradient().params.beta)
    console.print(
        f"[bold]gradient: best β = {ours.best.params['beta']} "
        f"({ours.best.mean()['total_rmse_deg']:.2f} deg), default β = "
        f"{default.params['beta']} ({default.mean()['total_rmse_deg']:.2f} deg) vs ahrs "
        f"Madgwick {best.mean()['total_rmse_deg']:.2f} deg; "
        f"{ours.best.samples_per_s:.4g} samples/s[/]"
    )


if __name__ == "__main__":
    main()
