"""A raw live recording replayed as a live source, the session's events re-applied.

:class:`LiveReplaySource` plays a raw live recording (:mod:`margtrack.io.live_hdf5`, written
by ``margtrack live --record`` and the page's recording) in the engine batches of the
session and, once attached to an engine (:meth:`Engine.start` does it), re-applies the
session's parameter changes and body calibrations at the frames where they happened and
gives the engine the session's held/stale/restart flags of each frame: the session's poses
come back exactly. :func:`margtrack.live.replay.replay_path` picks it for such a file.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from margtrack.io.live_hdf5 import RawLiveRecording
from margtrack.live.assembler import Frames
from margtrack.live.joint_chain import lever_arms_from_json
from margtrack.live.protocol import BaseSource, Chunk, Pacer, SourceInfo
from margtrack.live.recording import calibration_from_dict

if TYPE_CHECKING:
    from margtrack.live.engine import Engine

__all__ = ["LiveReplaySource"]


class LiveReplaySource(BaseSource):
    """A raw live recording replayed batch by batch, its events re-applied (module docstring).

    Parameters
    ----------
    recording : what :func:`margtrack.io.live_hdf5.read_live_recording` returns.
    speed : playback speed factor > 0 (``math.inf``: as fast as polled); a batch is
        delivered when its last frame is due.

    Attributes ``method`` and ``params`` are the session's, and so are ``no_mag`` (whether
    it ran without magnetometers) and ``lever_arms`` (joint name -> the lever arms in force
    when its recording started; joints left out were estimated during it, and are again):
    build the engine with them to reproduce it. A recording from before these were stored
    has ``no_mag`` None. With another method the recorded parameter changes are skipped (they
    belong to the recorded method) and counted in ``skipped_events``.
    """

    def __init__(self, recording: RawLiveRecording, speed: float = math.inf) -> None:
        rec = recording
        name = rec.path.name if rec.path is not None else "live recording"
        super().__init__(SourceInfo(rec.sensor_names, rec.rate_hz, rec.mag is not None,
                                    f"replay {name}"))
        self.recording = rec
        self.method, self.params = rec.method, dict(rec.params)
        no_mag = rec.meta.get("no_mag")
        self.no_mag: bool | None = None if no_mag is None else bool(no_mag)
        self.lever_arms = lever_arms_from_json(rec.meta.get("lever_arms") or {})
        self._ends = np.cumsum(rec.batch_frames)
        self._batch = 0
        self._pacer = Pacer(float(rec.t_s[0]) if rec.n_frames else 0.0, speed)
        self._events: dict[int, list[Any]] = {}
        for e in rec.events:
            self._events.setdefault(e.frame, []).append(e)
        self._engine: Engine | None = None
        self._engine_frames = 0
        self.skipped_events = 0
        self.applied_events = 0

    def open(self) -> None:
        """Start the playback clock (idempotent)."""
        if not self._opened:
            self._pacer.start()
        super().open()

    def attach_engine(self, engine: Engine) -> None:
        """Re-apply the recorded events on ``engine`` as its batches go by (once)."""
        if self._engine is not None:
            raise ValueError("this replay is already attached to an engine")
        if tuple(engine.info.sensor_names) != self.info.sensor_names:
            raise ValueError("the engine was built for other sensors than the recording's")
        self._engine = engine
        engine.before_batch.append(self._apply)

    def _apply(self, frames: Frames) -> Frames | None:
        engine = self._engine
        first, self._engine_frames = self._engine_frames, self._engine_frames + frames.n_frames
        if engine is None:
            return None
        for frame in [f for f in self._events if f < self._engine_frames]:
            for event in self._events.pop(frame):
                self._apply_one(engine, event.kind, event.data, frame, first)
        return self._flags(frames, first)

    def _flags(self, frames: Frames, first: int) -> Frames | None:
        """The session's held/stale/restart flags on the same frames (its filter restarts)."""
        rec, last = self.recording, first + frames.n_frames
        if last > rec.n_frames or not np.array_equal(frames.t_s, rec.t_s[first:last]):
            return None  # not the recorded frames: leave them
        flags = {k: None if v is None or not v[:, first:last].any() else v[:, first:last]
                 for k, v in (("stale", rec.stale), ("restart", rec.restart))}
        return dataclasses.replace(frames, held=rec.held[:, first:last].copy(), **flags)

    def _apply_one(self, engine: Engine, kind: str, data: dict[str, Any], frame: int,
                   first: int) -> None:
        if kind == "params":
            if data.get("method") != engine.method:
                self.skipped_events += 1
                return
            engine.set_params(**_params_values(engine, data["params"]))
        elif kind == "calibration":
            if engine.avatars is None:
                self.skipped_events += 1
                return
            engine.set_calibrations([calibration_from_dict(c) for c in data["calibrations"]])
        else:
            return
        self.applied_events += 1
        if frame != first:  # the replay's batches differ from the session's: nearest frame
            self._stats.last_error = f"event at frame {frame} applied at frame {first}"

    def poll(self, timeout_s: float) -> list[Chunk]:
        """The next recorded batch once its last frame is due (one chunk per poll)."""
        if self._finished:
            return []
        if not self._opened:
            self.open()
        if self._batch >= self._ends.size:
            self._finished = True
            return []
        i = 0 if self._batch == 0 else int(self._ends[self._batch - 1])
        j = int(self._ends[self._batch])
        rec = self.recording
        if not self._pacer.unpaced:
            wait = float(self._pacer.due_time(rec.t_s[j - 1])) - self._pacer.now()
            if wait > timeout_s:
                _sleep(timeout_s)
                return []
            _sleep(wait)
        self._batch += 1
        self._stats.samples += (j - i) * self.info.n_sensors
        arrival = np.full(j - i, self._pacer.now())
        chunk = Chunk(rec.t_s[i:j], np.arange(self.info.n_sensors, dtype=np.intp),
                      rec.gyr[:, i:j], rec.acc[:, i:j],
                      None if rec.mag is None else rec.mag[:, i:j], arrival)
        if self._batch >= self._ends.size:
            self._finished = True
        return [chunk]


def _params_values(engine: Engine, values: dict[str, Any]) -> dict[str, Any]:
    """Recorded parameter values (JSON) typed like the engine's current ones."""
    current = engine.params
    out = {}
    for key, value in values.items():
        if not hasattr(current, key):
            raise ValueError(f"recorded parameter {key!r} is not a parameter of "
                             f"{engine.method}")
        old = getattr(current, key)
        out[key] = np.asarray(value, dtype=np.float64) if isinstance(old, np.ndarray) else (
            tuple(value) if isinstance(old, tuple) else value)
    return out


def _sleep(seconds: float) -> None:
    if seconds > 0:
        time.sleep(seconds)
