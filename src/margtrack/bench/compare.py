"""Compare margtrack's methods with other libraries on BROAD in one run: table and bar plot.

Every method gets one parameter set for all trials (its defaults), a fresh start per
trial, and is scored with the same metric (RMSE over movement samples, degrees); the
speed column is samples per second of pure estimation time in the same run.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from margtrack.bench.runner import KEYS, Adapter, Method, Scores, evaluate_all
from margtrack.recording import Recording

__all__ = ["Comparison", "compare", "plot_comparison"]


@dataclass(frozen=True)
class Comparison:
    """The scores of every compared method (:class:`~margtrack.bench.runner.Scores`)."""

    methods: tuple[Scores, ...]

    def table_rows(self, groups: Sequence[str | None]) -> list[list[str]]:
        """Rows: label, then total/heading/inclination per group, then samples/s."""
        rows = []
        for m in self.methods:
            row = [m.method]
            for g in groups:
                means = m.mean(g)
                row += [f"{means[k]:.2f}" for k in KEYS]
            row.append(f"{m.samples_per_s:,.0f}")
            rows.append(row)
        return rows


def compare(
    recordings: Sequence[tuple[Recording, tuple[str, ...]]],
    methods: Sequence[tuple[str, Method | Callable[[Recording], NDArray[np.float64]]]],
    progress: Callable[[str], None] | None = None,
) -> Comparison:
    """Score each ``(label, method)`` on every recording with the one runner.

    ``method`` is an Estimator, an :class:`~margtrack.bench.runner.Adapter`, or a plain
    function ``run(recording)`` returning (N, 4) quaternions in ENU (made an Adapter).
    """
    results = []
    for label, method in methods:
        runner = method if isinstance(method, Method) else Adapter(method, label)

        def told(name: str, label: str = label) -> None:
            if progress is not None:
                progress(f"{label}: {name}")

        results.append(evaluate_all(runner, recordings, label=label, progress=told))
    return Comparison(tuple(results))


def plot_comparison(comparison: Comparison, path: str | Path, groups: Sequence[str]) -> Path:
    """Grouped bar plot of the mean total RMSE per group and method, saved as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [m.method for m in comparison.methods]
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
