"""The live engine's in-memory recording of processed orientations (``start_recording``).

Thread-safe: any thread starts or stops it, the worker appends every processed batch
(times (N,) s, session clock; orientations (N, S, 4) sensor to earth; with a body model,
the walking roots (N, A, 3) m, NaN while they stay at the avatars' places). Stopping returns a
:class:`~margtrack.live.recording.LiveRecording` (exported by the viewer as CSV/.sto/BVH).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.live.avatars import Avatars
from margtrack.live.recording import LiveRecording

Array = NDArray[np.float64]

__all__ = ["OrientationLog"]


class OrientationLog:
    """Processed orientations of S named sensors while recording (module docstring)."""

    def __init__(self, sensor_names: Sequence[str], avatars: Avatars | None) -> None:
        self.sensor_names = tuple(sensor_names)
        self.avatars = avatars
        self._lock = threading.Lock()
        self._parts: list[tuple[Array, Array, Array | None]] | None = None

    def start(self) -> None:
        """Record every batch from now on (replaces an unfinished recording)."""
        with self._lock:
            self._parts = []

    @property
    def active(self) -> bool:
        """Whether a recording is running."""
        with self._lock:
            return self._parts is not None

    def appender(self) -> Callable[[Array, Array, Array | None], None] | None:
        """Where the worker appends this batch's ``(t_s, q, root_m)`` (None while not
        recording); ``root_m`` None: the roots at the avatars' places."""
        with self._lock:
            parts = self._parts
        if parts is None:
            return None
        return lambda t_s, q, root_m: parts.append(
            (t_s.copy(), q.copy(), None if root_m is None else root_m.copy()))

    def stop(self, frame: str, calibrations: Sequence[Any]) -> LiveRecording:
        """Stop and return what was recorded (``ValueError`` if nothing was started)."""
        with self._lock:
            parts, self._parts = self._parts, None
        if parts is None:
            raise ValueError("no recording is running; call start_recording() first")
        t = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0)
        empty = np.zeros((0, len(self.sensor_names), 4))
        q = np.concatenate([p[1] for p in parts]) if parts else empty
        root = None
        if self.avatars is not None and any(p[2] is not None for p in parts):
            n_people = self.avatars.n_people
            root = np.concatenate([p[2] if p[2] is not None else np.full(
                (p[0].size, n_people, 3), np.nan) for p in parts])
        return LiveRecording(t, q, self.sensor_names, frame, self.avatars, tuple(calibrations),
                             root)
