"""A run of the live engine in its worker thread: start, wait, stop, its statistics.

:class:`EngineThread` is the part of :class:`~margtrack.live.engine.Engine` that runs it
in its :class:`~margtrack.live.worker.Worker` (one thread per engine, the only one that
runs the filters): :meth:`~EngineThread.start` opens the source and attaches a replay
that re-applies its session's events; :meth:`~EngineThread.stop` (or leaving the ``with``
block) joins the worker and closes the source; :meth:`~EngineThread.stats` is a snapshot
of the run so far, from any thread. When the worker ends, the reason it
stopped on its own (if it did) is kept and the headless summary
(:meth:`~EngineThread.summary`) written to ``summary_path``.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

from margtrack.live.assembler import FrameAssembler
from margtrack.live.clocks import SensorClocks
from margtrack.live.filtering import SensorFilters
from margtrack.live.pose import Pose
from margtrack.live.protocol import Source, SourceInfo
from margtrack.live.stats import (
    EngineStats,
    StatsMeter,
    sensor_counts,
    summary_dict,
    write_summary,
)
from margtrack.live.walking_root import LiveRoot
from margtrack.live.worker import Worker

if TYPE_CHECKING:
    from typing import Self

__all__ = ["FIRST_POSE_TIMEOUT_S", "EngineThread"]

#: how long a stop waits for a worker that has not made its first pose yet, s: compiling
#: every kernel of a method and the body model on a cold cache takes up to a few minutes
#: on a slow machine
FIRST_POSE_TIMEOUT_S = 600.0


class EngineThread:
    """Start, wait for and stop an engine's worker thread; its statistics (module
    docstring)."""

    info: SourceInfo
    summary_path: str | None
    _worker: Worker
    _source: Source | None
    _fatal: str | None
    _error: str
    # the engine's (margtrack.live.engine.Engine)
    method: str
    no_mag: bool
    stale_after_s: float
    _root: LiveRoot | None
    _latest: Pose | None
    _assembler: FrameAssembler
    _clocks: SensorClocks
    _filters: SensorFilters
    _meter: StatsMeter
    joints: list[dict[str, Any]]
    calibration_status: str
    session_time_s: float

    def stats(self) -> EngineStats:
        """A snapshot of timing, latency, losses and sensor health."""
        a, c, f = self._assembler, self._clocks, self._filters
        malformed = self._source.stats.malformed if self._source is not None else 0
        dropped = a.dropped.copy()
        stale = a.stale
        stats = self._meter.snapshot(self.info.n_sensors, dropped, a.late, malformed,
                                     self.calibration_status, self._error,
                                     counts=sensor_counts(c, a, f), stale=stale,
                                     stale_s=a.stale_s.copy(), errors=tuple(f.errors))
        return dataclasses.replace(stats, session_s=self.session_time_s,
                                   engine_error=self._fatal,
                                   lost_samples=int(c.lost.sum()),
                                   stale_sensors=int(stale.sum()))

    def summary(self) -> dict[str, Any]:
        """The headless summary (:func:`margtrack.live.stats.summary_dict`) now."""
        extra: dict[str, Any] = {"no_mag": True, "joints": self.joints} if self.no_mag else {}
        if self._root is not None:
            extra["root_moved_m"] = self._root.moved_m(self._latest)
        return summary_dict(self.stats(), method=self.method, running=self.running,
                            stale_after_s=self.stale_after_s, **extra)

    def write_summary(self, path: str) -> None:
        """Write :meth:`summary` to ``path`` as JSON, atomically (replaces an older file)."""
        write_summary(self.summary(), path, force=True)

    def start(self, source: Source, poll_timeout_s: float = 0.02) -> Self:
        """Run the engine on ``source`` in a worker thread (opened here, closed at the end)."""
        if self._worker.started:
            raise ValueError("this engine was already started; build a new one")
        if tuple(source.info.sensor_names) != self.info.sensor_names:
            raise ValueError("the source's sensors differ from the ones the engine was built for")
        self._source = source
        attach: Any = getattr(source, "attach_engine", None)  # a replay re-applying events
        if attach is not None:
            attach(self)
        self._worker.start(source, poll_timeout_s)
        return self

    def _finish(self, fatal: str | None) -> None:
        """The worker's last act: note why it stopped on its own, write the summary."""
        if fatal is not None:
            self._fatal = fatal
            self._error = fatal
        if self.summary_path is not None:
            try:
                self.write_summary(self.summary_path)
            except Exception as exc:  # the session's result stays in stats()
                self._error = f"could not write the summary {self.summary_path}: {exc!r}"

    @property
    def running(self) -> bool:
        """Whether the worker thread is alive."""
        return self._worker.running

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until the source is exhausted (or the engine stopped); True if it ended."""
        return self._worker.wait(timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the worker, close the source and join the thread (idempotent).

        Before the first pose the worker may be inside numba compiling the kernels (a cold
        cache: tens of seconds, which no stop request interrupts): then it is given up to
        :data:`FIRST_POSE_TIMEOUT_S`."""
        if self._latest is None:
            timeout_s = max(timeout_s, FIRST_POSE_TIMEOUT_S)
        self._worker.stop(timeout_s)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
