"""What the engine measures while it runs: timing, latency, losses and sensor health.

Definitions (all times on the :func:`time.perf_counter` clock, s):

- *processing time* of a batch: from the start of its filter run to the end of publishing
  (filters, body model, recording, calibration, subscribers); per frame = batch time / N
  (the median over the last 512 batches, so a one-off pause such as numba loading its cache
  does not dominate), per sample = per frame / S. Cumulative totals are split in
  ``time_filter_s`` (the estimator's ``run``: its numba kernel plus the Python around it),
  ``time_body_s`` (body model, recording, calibration), ``time_publish_s`` (subscribers)
  and ``time_assemble_s`` (polling the source and assembling frames).
- *latency* of a published pose: ``published_s - arrival_s`` of its frame, where arrival is
  when the frame's last sample reached the program (:class:`~margtrack.live.protocol.Chunk`).
- *late frame*: processed more than ``late_after_s`` after its arrival.
- *dropped samples*: samples a frame lacked and the engine replaced by the sensor's previous
  one, samples of frames discarded whole, samples that arrived after their frame had been
  processed, and input lines the source rejected.
- *sensor health*: each sensor's received rate over the last ``window_s`` of data time, its
  dropped samples, and the magnetic-norm check ``|m| / |m_ref|`` of the latest sample against
  the sensor's median norm over its first second (``mag_ok`` within ``mag_norm_tol``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["EngineStats", "SensorHealth", "StatsMeter"]


@dataclass(frozen=True, eq=False)
class SensorHealth:
    """Per-sensor health (arrays of S, order of ``names``); see the module docstring."""

    names: tuple[str, ...]
    rate_hz: Array
    dropped: NDArray[np.int64]
    mag_norm_ratio: Array
    mag_ok: NDArray[np.bool_]


@dataclass(frozen=True, eq=False)
class EngineStats:
    """A snapshot of the engine's counters (definitions in the module docstring)."""

    frames: int
    samples: int
    batches: int
    poses_published: int
    subscriber_errors: int
    dropped_samples: int
    late_samples: int
    late_frames: int
    malformed_lines: int
    processing_s_per_frame: float
    processing_s_per_sample: float
    latency_p50_s: float
    latency_p95_s: float
    latency_max_s: float
    time_filter_s: float
    time_body_s: float
    time_publish_s: float
    time_assemble_s: float
    health: SensorHealth
    calibration: str
    error: str

    def summary(self) -> str:
        """One line for logs and the viewer."""
        return (
            f"{self.frames} frames, {self.poses_published} poses, "
            f"{self.processing_s_per_frame * 1e3:.3f} ms/frame "
            f"({self.processing_s_per_sample * 1e6:.2f} us/sample), latency p50 "
            f"{self.latency_p50_s * 1e3:.1f} ms p95 {self.latency_p95_s * 1e3:.1f} ms, "
            f"dropped {self.dropped_samples}, late frames {self.late_frames}"
        )


class StatsMeter:
    """Accumulates the engine's measurements; the engine's worker is its only writer."""

    def __init__(self, names: tuple[str, ...], window_s: float = 2.0,
                 mag_norm_tol: float = 0.1, keep: int = 512) -> None:
        n = len(names)
        self.names = names
        self.window_s = window_s
        self.mag_norm_tol = mag_norm_tol
        self.frames = 0
        self.batches = 0
        self.poses = 0
        self.subscriber_errors = 0
        self.late_frames = 0
        self.time_filter_s = 0.0
        self.time_body_s = 0.0
        self.time_publish_s = 0.0
        self.time_assemble_s = 0.0
        self._per_frame: deque[float] = deque(maxlen=keep)
        self._latency: deque[float] = deque(maxlen=keep)
        self._received: deque[tuple[float, NDArray[np.int64]]] = deque()
        self._mag_first: list[Array] = []
        self._mag_first_until = np.inf
        self._mag_ref = np.full(n, np.nan)
        self._mag_now = np.full(n, np.nan)

    def batch(self, t_s: Array, held: NDArray[np.bool_], mag: Array | None,
              seconds: float, late: int) -> None:
        """Record one processed batch of N frames that took ``seconds``."""
        n = t_s.size
        self.frames += n
        self.batches += 1
        self.late_frames += late
        self._per_frame.append(seconds / n)
        self._received.append((float(t_s[-1]), (~held).sum(axis=1)))
        while self._received and self._received[0][0] < t_s[-1] - self.window_s:
            self._received.popleft()
        if mag is not None:
            norms = np.linalg.norm(mag, axis=2)  # (S, N)
            self._mag_now = norms[:, -1]
            if np.isnan(self._mag_ref).any():
                if not self._mag_first:
                    self._mag_first_until = float(t_s[0]) + 1.0
                self._mag_first.append(norms)
                if t_s[-1] >= self._mag_first_until:
                    self._mag_ref = np.median(np.concatenate(self._mag_first, axis=1), axis=1)
                    self._mag_first = []

    def published(self, latency_s: float) -> None:
        """Record one published pose."""
        self.poses += 1
        self._latency.append(latency_s)

    def health(self, dropped: NDArray[np.int64]) -> SensorHealth:
        """Per-sensor rate, drops and magnetic-norm check now."""
        n = len(self.names)
        rate = np.zeros(n)
        if len(self._received) >= 2:
            span = self._received[-1][0] - self._received[0][0]
            counts = sum(c for _, c in list(self._received)[1:])
            rate = counts / span if span > 0 else rate
        ratio = self._mag_now / self._mag_ref
        ok = np.abs(ratio - 1.0) <= self.mag_norm_tol  # NaN (no reference yet) -> False
        return SensorHealth(self.names, np.asarray(rate, float), dropped.copy(), ratio, ok)

    def snapshot(self, n_sensors: int, dropped: NDArray[np.int64], late_samples: int,
                 malformed: int, calibration: str, error: str) -> EngineStats:
        """An :class:`EngineStats` of everything so far."""
        per_frame = float(np.median(self._per_frame)) if self._per_frame else float("nan")
        lat = np.asarray(self._latency) if self._latency else np.array([np.nan])
        return EngineStats(
            frames=self.frames,
            samples=self.frames * n_sensors,
            batches=self.batches,
            poses_published=self.poses,
            subscriber_errors=self.subscriber_errors,
            dropped_samples=int(dropped.sum()) + late_samples + malformed,
            late_samples=late_samples,
            late_frames=self.late_frames,
            malformed_lines=malformed,
            processing_s_per_frame=per_frame,
            processing_s_per_sample=per_frame / n_sensors,
            latency_p50_s=float(np.percentile(lat, 50)),
            latency_p95_s=float(np.percentile(lat, 95)),
            latency_max_s=float(np.max(lat)),
            time_filter_s=self.time_filter_s,
            time_body_s=self.time_body_s,
            time_publish_s=self.time_publish_s,
            time_assemble_s=self.time_assemble_s,
            health=self.health(dropped),
            calibration=calibration,
            error=error,
        )
