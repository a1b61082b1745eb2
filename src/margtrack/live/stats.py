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
  the sensor's median norm over its first second (``mag_ok`` within ``mag_norm_tol``;
  :mod:`margtrack.live.field_norm`).
- *per-sensor counts* (:class:`SensorHealth`, the headless summary and the page):
  ``received`` samples that reached the engine, ``processed`` samples the filter ran on
  (not held), ``lost`` samples never received (sequence-number or timestamp gaps),
  ``gaps`` intervals with missing samples or restarts (losses, resyncs, stale spells),
  ``resyncs`` clock re-synchronisations, ``bad_time`` samples discarded for a stamp out of
  line with the sensor's clock, ``late``/``duplicates`` samples discarded by the frame
  assembly, ``faults`` processed samples with a fault flag (the input policy's or a
  rejected disturbance; rest and initialising are states, not faults),
  ``reinitialised`` filter re-initialisations after a failure, ``stale`` whether the
  sensor is stale now and ``stale_s`` the session time it spent stale, s.
"""

from __future__ import annotations

import json
import math
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.live.field_norm import FieldNormReference

Array = NDArray[np.float64]

__all__ = ["EngineStats", "SensorHealth", "StatsMeter", "sensor_counts", "summary_dict",
           "write_summary"]


@dataclass(frozen=True, eq=False)
class SensorHealth:
    """Per-sensor health (arrays of S, order of ``names``); see the module docstring."""

    names: tuple[str, ...]
    rate_hz: Array
    dropped: NDArray[np.int64]
    mag_norm_ratio: Array
    mag_ok: NDArray[np.bool_]
    counts: dict[str, NDArray[np.int64]] = field(default_factory=dict)
    stale: NDArray[np.bool_] | None = None
    stale_s: Array | None = None
    errors: tuple[str, ...] = ()

    def sensor(self, index: int) -> dict[str, object]:
        """Sensor ``index``'s counts as plain Python values (the summary's per-sensor entry)."""
        out: dict[str, object] = {k: int(v[index]) for k, v in self.counts.items()}
        out["stale"] = bool(self.stale[index]) if self.stale is not None else False
        out["stale_s"] = float(self.stale_s[index]) if self.stale_s is not None else 0.0
        rate = float(self.rate_hz[index])
        out["rate_hz"] = rate if np.isfinite(rate) else None
        ratio = float(self.mag_norm_ratio[index])
        out["mag_norm_ratio"] = ratio if np.isfinite(ratio) else None
        out["last_error"] = (self.errors[index] or None) if self.errors else None
        return out


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
    #: session time of the last processed frame, s (0 at the session's first frame)
    session_s: float = 0.0
    #: why the engine stopped on its own (its bug or a broken source), None while it is fine
    engine_error: str | None = None
    #: samples never received (sequence-number or timestamp gaps), all sensors
    lost_samples: int = 0
    #: sensors stale now
    stale_sensors: int = 0

    def summary(self) -> str:
        """One line for logs and the viewer."""
        return (
            f"{self.frames} frames, {self.poses_published} poses, "
            f"{self.processing_s_per_frame * 1e3:.3f} ms/frame "
            f"({self.processing_s_per_sample * 1e6:.2f} us/sample), latency p50 "
            f"{self.latency_p50_s * 1e3:.1f} ms p95 {self.latency_p95_s * 1e3:.1f} ms, "
            f"dropped {self.dropped_samples}, lost {self.lost_samples}, "
            f"late frames {self.late_frames}"
            + (f", {self.stale_sensors} stale" if self.stale_sensors else "")
            + (f"; STOPPED: {self.engine_error}" if self.engine_error else "")
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
        # per batch: (last frame time, frames N, (S,) held samples or None when none was):
        # O(1) per batch while nothing is held, whatever S
        self._received: deque[tuple[float, int, NDArray[np.int64] | None]] = deque()
        self._mag_ref = FieldNormReference(n)
        self._mag_now = np.full(n, np.nan)
        #: (S, 3) the latest sample's field, kept as a view (a source does not overwrite the
        #: samples it handed over): its norm is taken only when :meth:`health` asks
        self._mag_latest: Array | None = None

    def batch(self, t_s: Array, held: NDArray[np.bool_], mag: Array | None,
              seconds: float, late: int) -> None:
        """Record one processed batch of N frames that took ``seconds``."""
        n = t_s.size
        self.frames += n
        self.batches += 1
        self.late_frames += late
        self._per_frame.append(seconds / n)
        held_rows = held.sum(axis=1) if held.any() else None
        self._received.append((float(t_s[-1]), n, held_rows))
        while self._received and self._received[0][0] < t_s[-1] - self.window_s:
            self._received.popleft()
        if mag is not None:
            self._mag_ref.feed(t_s, mag)
            self._mag_latest = mag[:, -1]  # its norm is taken only when health() asks

    def published(self, latency_s: float) -> None:
        """Record one published pose."""
        self.poses += 1
        self._latency.append(latency_s)

    def health(self, dropped: NDArray[np.int64], **extra: object) -> SensorHealth:
        """Per-sensor rate, drops and magnetic-norm check now (``extra``: the other fields)."""
        n = len(self.names)
        rate = np.zeros(n)
        if len(self._received) >= 2:
            span = self._received[-1][0] - self._received[0][0]
            later = list(self._received)[1:]
            counts = np.full(n, sum(frames for _, frames, _ in later), dtype=np.int64)
            for _, _, held_rows in later:
                if held_rows is not None:
                    counts -= held_rows
            rate = counts / span if span > 0 else rate
        latest = self._mag_latest
        if latest is not None:
            self._mag_now = np.linalg.norm(latest, axis=1)
        ratio = self._mag_now / self._mag_ref.norm
        ok = np.abs(ratio - 1.0) <= self.mag_norm_tol  # NaN (no reference yet) -> False
        return SensorHealth(self.names, np.asarray(rate, float), dropped.copy(), ratio, ok,
                            **extra)  # type: ignore[arg-type]

    def snapshot(self, n_sensors: int, dropped: NDArray[np.int64], late_samples: int,
                 malformed: int, calibration: str, error: str,
                 **sensor_fields: object) -> EngineStats:
        """An :class:`EngineStats` of everything so far (``sensor_fields``: SensorHealth's)."""
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
            health=self.health(dropped, **sensor_fields),
            calibration=calibration,
            error=error,
        )


def sensor_counts(clocks: Any, assembler: Any, filters: Any) -> dict[str, NDArray[np.int64]]:
    """The per-sensor counts of :class:`SensorHealth` (copies) from the engine's
    :class:`~margtrack.live.clocks.SensorClocks`, :class:`~margtrack.live.assembler.
    FrameAssembler` and :class:`~margtrack.live.filtering.SensorFilters`."""
    c, a, f = clocks, assembler, filters
    return {
        "received": c.received.copy(), "processed": f.processed.copy(),
        "lost": c.lost.copy(), "gaps": c.gaps + a.resumed, "resyncs": c.resyncs.copy(),
        "faults": f.faults.copy(), "reinitialised": f.reinitialised.copy(),
        "held": a.dropped - a.discarded_by_sensor, "late": a.late_by_sensor.copy(),
        "duplicates": a.duplicates_by_sensor.copy(), "bad_time": c.bad_time.copy(),
        "discarded": a.discarded_by_sensor.copy(),
    }


def _number(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def summary_dict(stats: EngineStats, **engine_extra: object) -> dict[str, object]:
    """The headless summary: ``{"engine": {...}, "sensors": {NAME: {...}}}`` (JSON-ready).

    ``engine.error`` is None unless the engine stopped on its own (its bug, a broken
    source); per sensor the counts of :class:`SensorHealth` (module docstring).
    """
    engine: dict[str, object] = {
        "error": stats.engine_error,
        "frames": stats.frames,
        "session_s": _number(stats.session_s),
        "poses": stats.poses_published,
        "lost": stats.lost_samples,
        "dropped": stats.dropped_samples,
        "late_samples": stats.late_samples,
        "malformed_lines": stats.malformed_lines,
        "latency_p50_s": _number(stats.latency_p50_s),
        "latency_p95_s": _number(stats.latency_p95_s),
        "processing_s_per_frame": _number(stats.processing_s_per_frame),
        "subscriber_errors": stats.subscriber_errors,
        "messages": stats.error or None,
        "calibration": stats.calibration,
        **engine_extra,
    }
    sensors = {name: stats.health.sensor(i) for i, name in enumerate(stats.health.names)}
    return {"engine": engine, "sensors": sensors}


def write_summary(summary: dict[str, object], path: str | Path, force: bool = True) -> Path:
    """Write a :func:`summary_dict` as JSON atomically (temp file + rename); returns the path.

    ``force=False`` refuses an existing file (the CLI checks that before the session).
    """
    from margtrack.io.safe_output import atomic_output, check_output

    out = check_output(path, (), force=force)
    with atomic_output(out) as tmp:
        Path(tmp).write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
    return out
