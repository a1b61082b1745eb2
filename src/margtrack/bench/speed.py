"""Throughput measurement: samples per second of any callable, best of several repeats.

Speed is reported as samples/s and as a ratio against another implementation measured in
the same run on the same data; never asserted in unit tests.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["Throughput", "measure"]


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
