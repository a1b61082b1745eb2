"""Each live sensor's reference field norm, for the magnetic-norm check of its health.

A sensor's reference is the median of ``REF_SAMPLES`` finite, non-zero field norms from the
start of its field data, one at most every ``REF_SPAN_S / REF_SAMPLES`` s of data time, so
they span about its first ``REF_SPAN_S`` (the first second). They are collected as the
batches come by a compiled pass over the sensors (:mod:`margtrack.live.field_norm_kernel`: the
frames due only, the median per sensor once its samples are in), while any sensor lacks a
reference; nothing after. (The median of every sensor's whole first second in one batch
stalled the engine's worker for 0.3-0.5 s at 84,000 sensors, and the catch-up after it broke
real time; numpy's masks, gathers and partitions over the sensors still cost 3-70 ms a batch
at 118,000.) A sensor whose field never gives a finite norm (none, or a dead magnetometer)
keeps no reference (NaN): its check reads "unknown".
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from margtrack.live.field_norm_kernel import feed_norms

__all__ = ["REF_SAMPLES", "REF_SPAN_S", "FieldNormReference"]

#: norms per sensor whose median is its reference (odd: the median is one of them)
REF_SAMPLES = 15
#: data time the reference's norms span, s
REF_SPAN_S = 1.0


class FieldNormReference:
    """The reference norms of S sensors (``norm``, (S,), NaN until known); module docstring."""

    def __init__(self, n_sensors: int) -> None:
        self.norm: NDArray[np.float64] = np.full(n_sensors, np.nan)
        self._norms = np.zeros((n_sensors, REF_SAMPLES))
        self._count = np.zeros(n_sensors, dtype=np.int64)
        self._due_s = np.full(n_sensors, -np.inf)  # data time of each sensor's next norm
        self._left = n_sensors  # sensors without a reference yet

    @property
    def complete(self) -> bool:
        """Whether every sensor has its reference."""
        return self._left == 0

    def feed(self, t_s: NDArray[np.float64], mag: NDArray[np.float64]) -> None:
        """One batch: frame times t_s (N,) s and the field mag (S, N, 3), any unit."""
        if self._left:
            self._left = int(feed_norms(np.asarray(t_s, dtype=np.float64), mag,
                                        REF_SPAN_S / REF_SAMPLES, self._norms, self._count,
                                        self._due_s, self.norm))
