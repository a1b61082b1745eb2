"""Throughput measurement: samples per second of any callable, best of several repeats.

Speed is reported as samples/s and as a ratio against another implementation measured in
the same run on the same data; never asserted in unit tests.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["SpeedInput", "Throughput", "measure", "print_table", "speed_input"]

#: BROAD beside the repository (``../shared/data/broad``), the benchmarks' default input.
BROAD_FOLDER = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "broad"


@dataclass(frozen=True)
class Throughput:
    """Best wall time of ``repeats`` runs over ``n_samples`` samples."""

    label: str
    n_samples: int
    seconds: float

    @property
    def samples_per_s(self) -> float:
        """Samples processed per second."""
        return self.n_samples / self.seconds

    @property
    def us_per_sample(self) -> float:
        """Microseconds per sample."""
        return 1e6 * self.seconds / self.n_samples

    def ratio_to(self, other: Throughput) -> float:
        """How many times faster than ``other`` (> 1: this one is faster)."""
        return self.samples_per_s / other.samples_per_s


def measure(
    label: str, func: Callable[[], object], n_samples: int, *, repeats: int = 3, warmup: bool = True
) -> Throughput:
    """Time ``func()`` (which processes ``n_samples``) ``repeats`` times and keep the best.

    ``warmup`` calls it once first so compilation (numba) is not counted.
    """
    if n_samples <= 0:
        raise ValueError(f"n_samples must be > 0, got {n_samples}")
    if warmup:
        func()
    best = float("inf")
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        func()
        best = min(best, time.perf_counter() - start)
    return Throughput(label, n_samples, best)


@dataclass(frozen=True)
class SpeedInput:
    """The benchmark input: (N, 3) C-contiguous gyr rad/s, acc m/s², mag µT, and its source."""

    gyr: NDArray[np.float64]
    acc: NDArray[np.float64]
    mag: NDArray[np.float64]
    source: str


def speed_input(
    n_samples: int | None = None,
    *,
    folder: str | Path = BROAD_FOLDER,
    rate_hz: float = 285.714,
    fallback_duration_s: float = 3000.0,
) -> SpeedInput:
    """All BROAD trials of ``folder`` concatenated (a simulated random motion if absent).

    ``n_samples`` None takes everything; fewer truncates; more repeats the data end to end.
    """
    folder = Path(folder)
    if (folder / "trials.json").is_file():
        from margtrack.io import broad_trials, read_broad

        recs = [read_broad(t.path) for t in broad_trials(folder)]
        parts = [np.concatenate([getattr(r, k) for r in recs]) for k in ("gyr", "acc", "mag")]
        source = f"{len(recs)} BROAD trials ({parts[0].shape[0]} samples)"
    else:
        from margtrack import sim

        rec = sim.simulate_motion("random", duration_s=fallback_duration_s, rate_hz=rate_hz)
        parts = [rec.gyr, rec.acc, rec.mag]
        source = "a simulated random motion"
    available = parts[0].shape[0]
    n = available if n_samples is None else n_samples
    if n > available:
        reps = -(-n // available)
        parts = [np.tile(p, (reps, 1)) for p in parts]
        source += " repeated"
    gyr, acc, mag = (np.ascontiguousarray(p[:n]) for p in parts)
    return SpeedInput(gyr, acc, mag, source)


def print_table(rows: Sequence[tuple[Throughput, str]], ref: Throughput, ref_name: str) -> None:
    """Print samples/s, µs/sample and the ratio to ``ref`` of each (throughput, note) row."""
    width = max(len(r.label) for r, _ in rows)
    print(f"{'':{width}}  {'samples/s':>12}  {'us/sample':>10}  {'vs ' + ref_name:>14}  note")
    for r, note in rows:
        print(
            f"{r.label:{width}}  {r.samples_per_s:12.4g}  {r.us_per_sample:10.4g}  "
            f"{r.ratio_to(ref):14.3g}  {note}"
        )
