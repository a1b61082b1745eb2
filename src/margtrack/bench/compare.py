"""Compare margtrack's methods with other libraries on BROAD in one run: table and bar plot.

Every method gets one parameter set for all trials (its defaults), a fresh start per
trial, and is scored with the same metric (RMSE over movement samples, degrees); the
speed column is samples per second of pure estimation time in the same run.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from margtrack.bench.metrics import error_series, summarize
from margtrack.recording import Recording

__all__ = ["Comparison", "MethodScores", "compare", "plot_comparison"]

KEYS = ("total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg")


@dataclass(frozen=True)
class MethodScores:
    """One method's per-trial RMSE figures (deg), trial groups, and its speed."""

    label: str
    trials: dict[str, dict[str, float]]
    groups: dict[str, tuple[str, ...]]
    samples: int
    seconds: float

    def mean(self, group: str | None = None) -> dict[str, float]:
        """Mean over trials (of ``group``) of each RMSE figure."""
        names = [t for t in self.trials if group is None or group in self.groups[t]]
        if not names:
            raise ValueError(f"no trial in group {group!r}")
        return {k: float(np.mean([self.trials[t][k] for t in names])) for k in KEYS}

    @property
    def samples_per_s(self) -> float:
        """Samples per second of estimation time."""
        return self.samples / self.seconds if self.seconds > 0 else float("nan")


@dataclass(frozen=True)
class Comparison:
    """The scores of every compared method."""

    methods: tuple[MethodScores, ...]

    def table_rows(self, groups: Sequence[str | None]) -> list[list[str]]:
        """Rows: label, then total/heading/inclination per group, then samples/s."""
        rows = []
        for m in self.methods:
            row = [m.label]
            for g in groups:
                means = m.mean(g)
                row += [f"{means[k]:.2f}" for k in KEYS]
            row.append(f"{m.samples_per_s:,.0f}")
            rows.append(row)
        return rows


def compare(
    recordings: Sequence[tuple[Recording, tuple[str, ...]]],
    methods: Sequence[tuple[str, Callable[[Recording], NDArray[np.float64]]]],
    progress: Callable[[str], None] | None = None,
) -> Comparison:
    """Score each ``(label, run)`` where ``run(recording)`` returns (N, 4) quats in ENU."""
    results = []
    for label, run in methods:
        trials: dict[str, dict[str, float]] = {}
        groups: dict[str, tuple[str, ...]] = {}
        samples, seconds = 0, 0.0
        for rec, rec_groups in recordings:
            if progress is not None:
                progress(f"{label}: {rec.name}")
            start = time.perf_counter()
            q = run(rec)
            seconds += time.perf_counter() - start
            samples += rec.n_samples
            assert rec.quat_true is not None
            s = summarize(error_series(q, rec.quat_true, "ENU", rec.frame), rec.movement)
            trials[rec.name] = {k: getattr(s, k) for k in KEYS}
            groups[rec.name] = rec_groups
        results.append(MethodScores(label, trials, groups, samples, seconds))
    return Comparison(tuple(results))


def plot_comparison(comparison: Comparison, path: str | Path, groups: Sequence[str]) -> Path:
    """Grouped bar plot of the mean total RMSE per group and method, saved as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [m.label for m in comparison.methods]
    x = np.arange(len(labels))
    width = 0.8 / len(groups)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(labels) + 2), 4.5))
    for k, g in enumerate(groups):
        values = [m.mean(None if g == "all" else g)["total_rmse_deg"] for m in comparison.methods]
        bars = ax.bar(x + (k - (len(groups) - 1) / 2) * width, values, width, label=g)
        ax.bar_label(bars, fmt="%.2f", fontsize=7)
    ax.set_xticks(x, labels, rotation=20)
    ax.set_ylabel("mean total RMSE (deg)")
    ax.set_title("BROAD: orientation error, one parameter set per method")
    ax.legend()
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out
