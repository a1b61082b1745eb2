"""The source protocol of the live engine: timestamped blocks of multi-sensor MARG samples.

A source delivers :class:`Chunk` objects: N frames (sample times ``t_s``) of K of the
source's S sensors (``sensors``, indices into ``SourceInfo.sensor_names``), with

- ``gyr`` (K, N, 3) angular rate, rad/s, sensor frame;
- ``acc`` (K, N, 3) specific force, m/s², sensor frame (at rest it points up);
- ``mag`` (K, N, 3) magnetic field, any unit (µT preferred), or ``None`` for a source
  without magnetometers;
- ``arrival_s`` (N,): when each frame reached the program, on the :func:`time.perf_counter`
  clock; the engine's end-to-end latency is measured from it;
- ``seq`` (N,) int64 or ``None``: the sender's per-sensor sequence number of each sample
  (line sources whose lines carry one, :mod:`margtrack.live.lines`); the engine counts
  losses from its gaps (without it, from timestamp gaps).

Block sources (replay, simulator) deliver every sensor at once (K = S); line sources (UDP,
serial) deliver one sensor's sample at a time (K = N = 1) and the engine's
:class:`~margtrack.live.assembler.FrameAssembler` puts frames together.

A source is polled, not iterated by a thread of its own: :meth:`Source.poll` returns what
is available now, waiting at most ``timeout_s`` for the first chunk, so the engine's single
worker thread can check for shutdown between polls. :func:`iter_chunks` wraps the polling
loop as an iterator for scripts.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["BaseSource", "Chunk", "Pacer", "Source", "SourceInfo", "SourceStats", "iter_chunks"]


@dataclass(frozen=True, eq=False)
class Chunk:
    """N frames of K sensors (shapes and units in the module docstring)."""

    t_s: Array
    sensors: NDArray[np.intp]
    gyr: Array
    acc: Array
    mag: Array | None
    arrival_s: Array
    seq: NDArray[np.int64] | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames N."""
        return int(self.t_s.shape[0])

    @property
    def n_sensors(self) -> int:
        """Number of sensors K in this chunk."""
        return int(self.sensors.shape[0])


@dataclass(frozen=True)
class SourceInfo:
    """What a source delivers.

    sensor_names : one name per sensor index; a segment name (``"left_thigh"``, aliases such
        as ``"left_upper_leg"`` allowed) or ``"<person>/<segment>"`` lets the engine build
        body models (:mod:`margtrack.live.avatars`).
    rate_hz : nominal sample rate, Hz, or ``None`` if unknown (network sources).
    has_mag : whether chunks carry ``mag``.
    description : a one-line label for the viewer.
    """

    sensor_names: tuple[str, ...]
    rate_hz: float | None
    has_mag: bool
    description: str = ""

    @property
    def n_sensors(self) -> int:
        """Number of sensors S."""
        return len(self.sensor_names)


@dataclass
class SourceStats:
    """Counters of a source: what it received and what it had to reject.

    samples : sensor samples delivered; malformed : input lines or packets rejected;
    last_error : the reason for the latest rejection (``""`` if none).
    """

    samples: int = 0
    malformed: int = 0
    last_error: str = ""
    errors: list[str] = field(default_factory=list)

    def reject(self, reason: str, keep: int = 20) -> None:
        """Count one rejected input and remember why (the first ``keep`` reasons are kept)."""
        self.malformed += 1
        self.last_error = reason
        if len(self.errors) < keep:
            self.errors.append(reason)


@runtime_checkable
class Source(Protocol):
    """What the engine needs from a source (see the module docstring)."""

    @property
    def info(self) -> SourceInfo: ...

    @property
    def finished(self) -> bool: ...

    @property
    def stats(self) -> SourceStats: ...

    def open(self) -> None: ...

    def poll(self, timeout_s: float) -> list[Chunk]: ...

    def close(self) -> None: ...


class BaseSource:
    """Shared plumbing: ``info``, ``stats``, ``finished``, context manager, idempotent close."""

    def __init__(self, info: SourceInfo) -> None:
        self._info = info
        self._stats = SourceStats()
        self._finished = False
        self._opened = False

    @property
    def info(self) -> SourceInfo:
        """Sensor names, nominal rate and whether there is a magnetometer."""
        return self._info

    @property
    def stats(self) -> SourceStats:
        """Counters of delivered and rejected input."""
        return self._stats

    @property
    def finished(self) -> bool:
        """True once the source has delivered everything it ever will."""
        return self._finished

    def open(self) -> None:
        """Start the clock or the connection (the engine calls this once before polling)."""
        self._opened = True

    def poll(self, timeout_s: float) -> list[Chunk]:  # pragma: no cover - abstract
        """Chunks available now, waiting up to ``timeout_s`` s for the first one."""
        raise TypeError(f"{type(self).__name__} must implement poll()")

    def close(self) -> None:
        """Release the connection; calling it twice is harmless."""
        self._finished = True

    def __enter__(self) -> BaseSource:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def iter_chunks(source: Source, timeout_s: float = 0.05) -> Iterator[Chunk]:
    """Iterate over a source's chunks until it is finished (opens and closes it)."""
    source.open()
    try:
        while True:
            chunks = source.poll(timeout_s)
            yield from chunks
            if source.finished and not chunks:
                return
    finally:
        source.close()


class Pacer:
    """Wall-clock pacing of recorded time: data time ``t`` is due at ``start + (t - t0)/speed``.

    Parameters
    ----------
    t0_s : data time of the first frame, s.
    speed : playback speed factor (> 0); ``math.inf`` delivers everything at once.
    clock : the wall clock (``time.perf_counter``), injectable for tests.
    """

    def __init__(self, t0_s: float, speed: float, clock: object = time.perf_counter) -> None:
        if not (speed > 0):
            raise ValueError(f"speed must be > 0 (math.inf: as fast as possible), got {speed}")
        self.t0_s = float(t0_s)
        self.speed = float(speed)
        self._clock = clock
        self.start_s: float | None = None

    @property
    def unpaced(self) -> bool:
        """True at infinite speed."""
        return math.isinf(self.speed)

    def start(self) -> None:
        """Start the wall clock now (the first frame is due immediately)."""
        self.start_s = self._clock()  # type: ignore[operator]

    def now(self) -> float:
        """Current wall-clock time."""
        return float(self._clock())  # type: ignore[operator]

    def due_time(self, t_s: Array) -> Array:
        """Wall-clock times (perf_counter) at which data times ``t_s`` are due."""
        if self.start_s is None:
            raise ValueError("Pacer.start() must be called first")
        if self.unpaced:
            return np.full(np.shape(t_s), self.start_s)
        return self.start_s + (np.asarray(t_s) - self.t0_s) / self.speed

    def data_time_now(self) -> float:
        """The latest data time due now (``inf`` when unpaced)."""
        if self.start_s is None:
            raise ValueError("Pacer.start() must be called first")
        if self.unpaced:
            return math.inf
        return self.t0_s + (self.now() - self.start_s) * self.speed
