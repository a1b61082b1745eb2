"""Relative orientation across a joint on the dual-IMU dataset: margtrack.joint against peers.

The 9 trials of ../shared/data/dualimu (Weygers & Kok 2020, 50 Hz, two sensors across a
1-, 2- or 3-DOF joint, optical reference). Per trial, the RMSE (deg) of the relative
orientation ``conj(q₁) ⊗ q₂`` against the reference one sample earlier, with no alignment
between the optical and the sensor frames: the dataset's own reference code's protocol
(``margtrack.joint.dualimu.score``). Side by side:

- margtrack online (``relative_orientation``) and offline (``offline=True``);
- dfjimu's MEKF-acc (``mekf_acc``, its defaults) and MAP-acc (``map_acc`` with the
  reference code's covariances ``cov_w = 0.01 I``, ``cov_i = 0.1 I``, ``cov_lnk = I`` and its
  10 iterations; the package's default of up to 1000 iterations converges to the same
  figures within 0.01 deg and takes up to 16 s a trial);
- two independent 6-D vqf filters (``vqf.VQF``, its defaults, no magnetometer): their
  relative heading is free and drifts.

Every method gets the same lever arms, estimated from the trial by margtrack's least
squares (``estimate_lever_arms``), as a user without a tape measure would; a second table
uses the dataset's measured ones. A third table repeats the first after fitting the two
constant optical-to-sensor rotations by least squares (``score_aligned``), a check of how
much of each error is the frames' misalignment. Speed: samples/s of each method over the 9
trials with the lever arms given (so their estimation is not counted, for any method), best
of 7 calls in a row after a warm-up call, measured in the same run, every method on one
thread: margtrack's run on one, and this script sets ``OMP_NUM_THREADS=1`` (unless it is
set) for dfjimu, whose MAP-acc assembles its system with OpenMP. On a shared 2-core machine
its OpenMP threads wait on each other: 20,000 samples/s there against 250,000 on one thread.

Leave-one-trial-out (``--loto``): for each trial, the grid's parameter set (gyroscope noise
x link noise x gyroscope timing) with the lowest mean RMSE on the other 8, scored on the
one left out.

Run: python benchmarks/joint_dualimu.py [--data DIR] [--loto] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from margtrack import quaternion as qt
from margtrack.bench.speed import measure
from margtrack.joint import estimate_lever_arms, pair_inputs, read_dualimu, relative_orientation
from margtrack.joint.dualimu import DualImuTrial, score, score_aligned

# one thread for dfjimu's OpenMP, as margtrack's (read when dfjimu's library loads)
os.environ.setdefault("OMP_NUM_THREADS", "1")

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "dualimu"
METHODS = ("online", "offline", "MEKF-acc", "MAP-acc", "6-D vqf")
GRID = {
    "gyr_noise_rad_s_sqrt_hz": (0.005, 0.01, 0.02),
    "link_noise_m_s2": (0.25, 0.5, 1.0),
    "gyr_timing": ("instant", "interval"),
}


def _arrays(trial: DualImuTrial) -> list[np.ndarray]:
    return [np.ascontiguousarray(a) for a in (trial.parent.gyr, trial.child.gyr,
                                              trial.parent.acc, trial.child.acc)]


def runners(trial: DualImuTrial, arms: np.ndarray) -> dict[str, Callable[[], np.ndarray]]:
    """Each method as a call returning the relative orientation (N, 4)."""
    import dfjimu
    import vqf

    g1, g2, a1, a2 = _arrays(trial)
    rate = trial.parent.rate_hz
    start = np.array([1.0, 0.0, 0.0, 0.0])

    def rel(pair: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        return qt.multiply(qt.conjugate(pair[0]), pair[1])

    def map_acc() -> np.ndarray:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # 10 iterations, as the reference code runs it
            return rel(dfjimu.map_acc(g1, g2, a1, a2, arms[0], arms[1], rate, start,
                                      0.01 * np.eye(6), 0.1 * np.eye(3), np.eye(3),
                                      iterations=10))

    def six_d() -> np.ndarray:
        out = []
        for g, a in ((g1, a1), (g2, a2)):
            out.append(vqf.VQF(1.0 / rate).updateBatch(g, a)["quat6D"])
        return rel((out[0], out[1]))

    return {
        "online": lambda: relative_orientation(trial.parent, trial.child,
                                               lever_arms=arms).quat,
        "offline": lambda: relative_orientation(trial.parent, trial.child, offline=True,
                                                lever_arms=arms).quat,
        "MEKF-acc": lambda: rel(dfjimu.mekf_acc(g1, g2, a1, a2, arms[0], arms[1], rate, start)),
        "MAP-acc": map_acc,
        "6-D vqf": six_d,
    }


def table(title: str, names: list[str], rows: dict[str, dict[str, float]]) -> None:
    print(f"\n{title}")
    print(f"{'trial':<12}" + "".join(f"{m:>10}" for m in METHODS))
    for name in names:
        print(f"{name:<12}" + "".join(f"{rows[m][name]:>10.2f}" for m in METHODS))
    print(f"{'mean':<12}" + "".join(f"{np.mean(list(rows[m].values())):>10.2f}"
                                    for m in METHODS))


def speed(trials: list[DualImuTrial], repeats: int = 7,
          methods: tuple[str, ...] = METHODS) -> dict[str, float]:
    """samples/s of each method over all trials, measured lever arms given: per trial and
    method a warm-up call (numba's compile or cache load, imports) and the best of
    ``repeats`` calls in a row (``margtrack.bench.speed.measure``)."""
    total = dict.fromkeys(methods, 0.0)
    samples = 0
    for trial in trials:
        calls = runners(trial, trial.lever_arms_m)
        for m in methods:
            total[m] += measure(m, calls[m], trial.parent.n_samples, repeats=repeats).seconds
        samples += trial.parent.n_samples
    return {m: samples / total[m] for m in methods}


def leave_one_out(trials: list[DualImuTrial], arms: dict[str, np.ndarray]) -> dict[str, dict]:
    """Held-out RMSE per trial for online and offline with the grid's best set on the rest."""
    keys = list(GRID)
    sets = [dict(zip(keys, values, strict=True)) for values in itertools.product(*GRID.values())]
    out: dict[str, dict] = {}
    for offline in (False, True):
        scores = np.array([[score(relative_orientation(t.parent, t.child, offline=offline,
                                                        lever_arms=arms[t.name],
                                                        params=p).quat, t)
                            for t in trials] for p in sets])  # (sets, trials)
        held, chosen = {}, {}
        for k, t in enumerate(trials):
            rest = np.delete(scores, k, axis=1).mean(axis=1)
            best = int(np.argmin(rest))
            held[t.name], chosen[t.name] = float(scores[best, k]), sets[best]
        default = next(i for i, p in enumerate(sets) if p == {
            "gyr_noise_rad_s_sqrt_hz": 0.01, "link_noise_m_s2": 0.5, "gyr_timing": "instant"})
        out["offline" if offline else "online"] = {
            "held_out": held, "chosen": chosen,
            "best_on_all": sets[int(np.argmin(scores.mean(axis=1)))],
            "default_mean": float(scores[default].mean()),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--loto", action="store_true", help="leave-one-trial-out figures")
    parser.add_argument("--json", type=Path, help="write every figure to this JSON file")
    args = parser.parse_args()
    paths = sorted(args.data.glob("data_*.mat"))
    if not paths:
        raise SystemExit(f"no dual-IMU trials (data_*.mat) in {args.data}")
    trials = [read_dualimu(p) for p in paths]
    names = [t.name.removeprefix("data_") for t in trials]
    results: dict[str, object] = {}
    est_arms: dict[str, np.ndarray] = {}
    for t in trials:
        inputs = pair_inputs(t.parent, t.child)
        est_arms[t.name] = estimate_lever_arms(inputs.t, inputs.gyr, inputs.acc).r_m
    for label, which in (("estimated", est_arms), ("measured", None)):
        rows = {m: {} for m in METHODS}
        aligned = {m: {} for m in METHODS}
        for t, name in zip(trials, names, strict=True):
            arms = which[t.name] if which is not None else t.lever_arms_m
            for m, call in runners(t, arms).items():
                q = call()
                rows[m][name] = score(q, t)
                if which is not None:
                    aligned[m][name] = score_aligned(q, t)
        table(f"RMSE (deg), lever arms {label} (joint centre to sensor):", names, rows)
        results[f"rmse_deg_lever_arms_{label}"] = rows
        if which is not None:
            table("RMSE (deg) after a least-squares fit of the two constant optical-to-sensor "
                  "rotations, lever arms estimated:", names, aligned)
            results["rmse_deg_aligned"] = aligned
    print("\nlever arms estimated - measured (mm), parent | child:")
    for t, name in zip(trials, names, strict=True):
        d = 1e3 * (est_arms[t.name] - t.lever_arms_m)
        print(f"{name:<12}" + " ".join(f"{v:6.1f}" for v in d[0]) + "  | "
              + " ".join(f"{v:6.1f}" for v in d[1]))
    rates = speed(trials)
    print("\nspeed over the 9 trials (lever arms given; best of 7 in a row, same run), "
          "samples/s:")
    for m in METHODS:
        print(f"  {m:<10}{rates[m]:>14,.0f}")
    results["samples_per_s"] = rates
    if args.loto:
        loto = leave_one_out(trials, est_arms)
        print("\nleave-one-trial-out RMSE (deg), lever arms estimated; the set chosen on the "
              "other 8 from", {k: list(v) for k, v in GRID.items()})
        for mode in ("online", "offline"):
            held = loto[mode]["held_out"]
            print(f"  {mode:<8}" + " ".join(f"{held[t.name]:.2f}" for t in trials)
                  + f"   mean {np.mean(list(held.values())):.2f} (defaults: "
                  f"{loto[mode]['default_mean']:.2f}); best on all 9: {loto[mode]['best_on_all']}")
        results["leave_one_trial_out"] = loto
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=float), encoding="utf-8")


if __name__ == "__main__":
    main()
