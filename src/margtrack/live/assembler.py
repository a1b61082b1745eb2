"""Frames from chunks: every sensor's sample at one time, in time order, gaps counted.

The filters run S sensors on common timestamps, so the engine needs complete frames. Block
sources deliver them already (a chunk with all S sensors passes straight through); line
sources deliver one sensor's sample at a time, and :class:`FrameAssembler` collects the
samples with equal time (within ``tol_s``; after rounding onto ``tick_hz``, if given) until

- every sensor has reported or is stale (below): the frame is complete;
- a later frame completes first, or the frame has waited ``max_wait_s`` (wall clock): it
  is emitted incomplete, each missing sensor holding its previous sample (zero-order hold;
  counted in ``dropped`` per sensor). A frame with a sensor never seen before that is not
  stale yet is discarded whole (there is nothing to hold), also counted.

A sample for a time at or before the last emitted frame arrives too late to be used: it is
counted in ``late`` (and per sensor in ``late_by_sensor``) and discarded, as are repeated
samples (``duplicates``). Times within ``tol_s`` are one frame: sensors re-synchronised by
:class:`~margtrack.live.clocks.SensorClocks` land within rounding of their peers.

Stale sensors: a sensor without a sample for more than ``stale_after_s`` of session time
(one never seen: since the session's first frame) while nothing of it arrived for as long
on the wall clock is *stale*: frames no longer wait for
it, and its samples in them are all-zero (no rate, no measurement: the engine holds its
orientation instead of integrating its last rate), marked in ``Frames.stale`` and timed in
``stale_s``. Its first sample after that is marked in ``Frames.restart`` (its filter
restarts there; counted in ``resumed``), as are the samples at which
:meth:`FrameAssembler.request_restart` asked for one (a clock resync).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.live.protocol import Chunk

Array = NDArray[np.float64]

__all__ = ["FrameAssembler", "Frames", "concatenate"]


@dataclass(frozen=True, eq=False)
class Frames:
    """N complete frames of all S sensors: the engine's unit of work.

    t_s (N,) session time, s; gyr/acc/mag (S, N, 3) (mag None without magnetometers);
    arrival_s (N,) the perf_counter time each frame was complete (its latest sample's
    arrival); held (S, N) bool: True where a missing sample was replaced by the sensor's
    previous one (by zeros where stale). stale (S, N): the sensor was stale (None:
    nowhere). restart (S, N): its filter restarts at this sample (None: nowhere).
    """

    t_s: Array
    gyr: Array
    acc: Array
    mag: Array | None
    arrival_s: Array
    held: NDArray[np.bool_]
    stale: NDArray[np.bool_] | None = None
    restart: NDArray[np.bool_] | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames N."""
        return int(self.t_s.shape[0])

    def part(self, start: int, stop: int) -> Frames:
        """Frames ``start`` to ``stop`` (exclusive, clipped to N) as views; itself if all."""
        if start <= 0 and stop >= self.n_frames:
            return self

        def cut(x: NDArray[Any] | None) -> NDArray[Any] | None:
            return None if x is None else x[:, start:stop]

        return Frames(self.t_s[start:stop], self.gyr[:, start:stop], self.acc[:, start:stop],
                      cut(self.mag), self.arrival_s[start:stop], self.held[:, start:stop],
                      cut(self.stale), cut(self.restart))


class _Pending:
    __slots__ = ("acc", "arrival", "first_arrival", "gyr", "mag", "present")

    def __init__(self, n: int, with_mag: bool, arrival: float) -> None:
        self.gyr = np.zeros((n, 3))
        self.acc = np.zeros((n, 3))
        self.mag = np.zeros((n, 3)) if with_mag else None
        self.present = np.zeros(n, dtype=bool)
        self.arrival = arrival
        self.first_arrival = arrival


class FrameAssembler:
    """Puts chunks together into :class:`Frames` (policy in the module docstring).

    Parameters
    ----------
    n_sensors : S.
    with_mag : whether chunks carry the magnetometer.
    max_wait_s : longest wall-clock wait of an incomplete frame for its missing sensors, s.
    tick_hz : if given, sample times are rounded to multiples of ``1 / tick_hz`` before
        grouping (sensors on unsynchronised clocks at about that rate).
    stale_after_s : session time without a sample after which a sensor is stale, s
        (None: never).
    tol_s : times closer than this are one frame, s.
    """

    def __init__(
        self, n_sensors: int, with_mag: bool, max_wait_s: float = 0.05,
        tick_hz: float | None = None, stale_after_s: float | None = None,
        tol_s: float = 1e-6,
    ) -> None:
        if n_sensors < 1:
            raise ValueError(f"n_sensors must be >= 1, got {n_sensors}")
        if not max_wait_s >= 0:
            raise ValueError(f"max_wait_s must be >= 0, got {max_wait_s}")
        if tick_hz is not None and not (np.isfinite(tick_hz) and tick_hz > 0):
            raise ValueError(f"tick_hz must be a finite number > 0, got {tick_hz}")
        if stale_after_s is not None and not (math.isfinite(stale_after_s)
                                              and stale_after_s > 0):
            raise ValueError(f"stale_after_s must be a finite number > 0, got {stale_after_s}")
        if not (math.isfinite(tol_s) and tol_s >= 0):
            raise ValueError(f"tol_s must be a finite number >= 0, got {tol_s}")
        self.n_sensors = n_sensors
        self.with_mag = with_mag
        self.max_wait_s = max_wait_s
        self.tick_hz = tick_hz
        self.stale_after_s = math.inf if stale_after_s is None else float(stale_after_s)
        self._can_be_stale = stale_after_s is not None
        self.tol_s = float(tol_s)
        self._pending: dict[float, _Pending] = {}
        self._last_t = -np.inf
        self._first_t = math.nan
        self._last = _Pending(n_sensors, with_mag, 0.0)  # latest sample of every sensor
        self._last_view: tuple[Array, Array, Array | None] | None = None  # full-chunk path
        self._all = np.arange(n_sensors)
        self._seen_t = np.full(n_sensors, np.nan)  # time of each sensor's latest sample in
        #: wall-clock (perf_counter) time anything of each sensor last arrived; the engine
        #: shares its clocks' array here, so held-back samples count as signs of life
        self.heard_s = np.full(n_sensors, -np.inf)
        self._now = -np.inf  # the latest arrival: a slow engine does not make sensors quiet
        self._check_after = -math.inf  # no sensor can be stale at times up to this
        self._none = np.zeros(n_sensors, dtype=bool)  # read-only by convention
        self._any_stale = False
        self._stale = np.zeros(n_sensors, dtype=bool)
        self._restart_at: list[tuple[NDArray[np.intp], float]] = []
        self.late = 0
        self.duplicates = 0
        self.late_by_sensor = np.zeros(n_sensors, dtype=np.int64)
        self.duplicates_by_sensor = np.zeros(n_sensors, dtype=np.int64)
        self.dropped = np.zeros(n_sensors, dtype=np.int64)
        self.discarded_frames = 0
        self.discarded_by_sensor = np.zeros(n_sensors, dtype=np.int64)
        self.stale_s = np.zeros(n_sensors)
        self.resumed = np.zeros(n_sensors, dtype=np.int64)

    @property
    def last_time_s(self) -> float:
        """Time of the last emitted frame (``-inf`` before the first)."""
        return self._last_t

    @property
    def stale(self) -> NDArray[np.bool_]:
        """(S,) whether each sensor was stale in the last emitted frame."""
        return self._stale.copy()

    @property
    def waiting(self) -> int:
        """Frames waiting for samples."""
        return len(self._pending)

    def request_restart(self, sensors: int | NDArray[np.intp], t_s: float) -> None:
        """Mark the first emitted sample at or after ``t_s`` of ``sensors`` (one index or an
        index array) as a filter restart."""
        self._restart_at.append((np.atleast_1d(np.asarray(sensors, dtype=np.intp)), float(t_s)))

    def push(self, chunks: list[Chunk], now_s: float) -> list[Frames]:
        """Add chunks; return the frames that are ready, oldest first."""
        out: list[Frames] = []
        for chunk in chunks:
            if chunk.mag is None and self.with_mag:
                raise ValueError("this source promised a magnetometer but a chunk has none")
            full = chunk.n_sensors == self.n_sensors and (
                chunk.sensors is self._all or np.array_equal(chunk.sensors, self._all))
            if full and self.tick_hz is None:
                out.extend(self._emit_pending_before(float(chunk.t_s[0])))
                block = self._block(chunk)
                if block is not None:
                    out.append(block)
            else:
                out.extend(self._add_samples(chunk))
        out.extend(self.expire(now_s))
        return out

    def expire(self, now_s: float, flush: bool = False) -> list[Frames]:
        """Emit incomplete frames that waited longer than ``max_wait_s`` (all if ``flush``)."""
        old = [t for t, p in self._pending.items()
               if flush or now_s - p.first_arrival >= self.max_wait_s]
        if not old:
            return []
        return self._emit_pending_before(max(old), inclusive=True)

    # -- internals ----------------------------------------------------------------------
    def _absent(self, t: float) -> NDArray[np.bool_]:
        """(S,) sensors stale at time ``t``: no sample for more than ``stale_after_s`` of
        session time before ``t``, nor any input from them for as long on the wall clock."""
        if t <= self._check_after or not self._can_be_stale:
            return self._none  # every sensor had a sample within stale_after_s of t
        since = np.where(np.isnan(self._seen_t), self._first_t, self._seen_t)
        oldest = float(np.min(since))
        self._check_after = oldest + self.stale_after_s + self.tol_s if oldest == oldest \
            else -math.inf
        if t <= self._check_after:
            return self._none
        quiet = ~(self._now - self.heard_s <= self.stale_after_s)  # never heard: quiet
        return (t - since > self.stale_after_s + self.tol_s) & quiet

    def _restarts(self, t: Array) -> NDArray[np.bool_] | None:
        """(S, N) restart marks for frames at ``t`` from the requests due by then."""
        if not self._restart_at:
            return None
        mask = np.zeros((self.n_sensors, t.size), dtype=bool)
        keep = []
        for sensors, when in self._restart_at:  # one entry per request (all sensors of a block)
            hits = np.flatnonzero(t >= when - self.tol_s)
            if hits.size:
                mask[sensors, hits[0]] = True
            else:
                keep.append((sensors, when))
        self._restart_at = keep
        return mask

    def _block(self, chunk: Chunk) -> Frames | None:
        keep = chunk.t_s > self._last_t
        if not keep.any():
            self.late += chunk.n_frames * self.n_sensors
            self.late_by_sensor += chunk.n_frames
            return None
        start = int(np.argmax(keep))
        self.late += start * self.n_sensors
        self.late_by_sensor += start
        t = chunk.t_s[start:]
        if math.isnan(self._first_t):
            self._first_t = float(t[0])
        gyr, acc = chunk.gyr[:, start:], chunk.acc[:, start:]
        mag = None if chunk.mag is None or not self.with_mag else chunk.mag[:, start:]
        # the last frame is kept as a view; copied only if a later frame needs holds
        self._last_view = (gyr[:, -1], acc[:, -1], None if mag is None else mag[:, -1])
        self._last_t = float(t[-1])
        self._seen_t[:] = self._last_t
        restart = self._restarts(t)
        if self._stale.any():
            restart = np.zeros((self.n_sensors, t.size), dtype=bool) if restart is None \
                else restart
            restart[self._stale, 0] = True
            self.resumed += self._stale
            self._stale = np.zeros(self.n_sensors, dtype=bool)
            self._any_stale = False
        return Frames(t, gyr, acc, mag, chunk.arrival_s[start:],
                      np.zeros((self.n_sensors, t.size), dtype=bool), None, restart)

    def _remember(self, gyr: Array, acc: Array, mag: Array | None,
                  which: NDArray[np.bool_]) -> None:
        if self._last_view is not None:
            view, self._last_view = self._last_view, None
            self._remember(*view, np.ones(self.n_sensors, dtype=bool))
        self._last.gyr[which] = gyr[which]
        self._last.acc[which] = acc[which]
        if mag is not None and self._last.mag is not None:
            self._last.mag[which] = mag[which]
        self._last.present |= which

    def _slot(self, t: float) -> float:
        """The pending frame time within ``tol_s`` of ``t``, else ``t``."""
        if t in self._pending or self.tol_s == 0.0:
            return t
        for key in self._pending:
            if abs(key - t) <= self.tol_s:
                return key
        return t

    def _add_samples(self, chunk: Chunk) -> list[Frames]:
        out: list[Frames] = []
        for n in range(chunk.n_frames):
            t = float(chunk.t_s[n])
            if self.tick_hz is not None:
                t = round(t * self.tick_hz) / self.tick_hz
            if t <= self._last_t + self.tol_s:
                self.late += chunk.n_sensors
                self.late_by_sensor[chunk.sensors] += 1
                continue
            t = self._slot(t)
            if math.isnan(self._first_t):
                self._first_t = t
            arrival = float(chunk.arrival_s[n])
            pending = self._pending.get(t)
            if pending is None:
                pending = self._pending[t] = _Pending(self.n_sensors, self.with_mag, arrival)
            for k, s in enumerate(chunk.sensors):
                if pending.present[s]:
                    self.duplicates += 1
                    self.duplicates_by_sensor[s] += 1
                    continue
                pending.gyr[s] = chunk.gyr[k, n]
                pending.acc[s] = chunk.acc[k, n]
                if pending.mag is not None and chunk.mag is not None:
                    pending.mag[s] = chunk.mag[k, n]
                pending.present[s] = True
                if not self._seen_t[s] >= t:
                    self._seen_t[s] = t
                if not self.heard_s[s] >= arrival:
                    self.heard_s[s] = arrival
            if arrival > self._now:
                self._now = arrival
            pending.arrival = max(pending.arrival, arrival)
            if pending.present.all() or (self._can_be_stale
                                         and (pending.present | self._absent(t)).all()):
                out.extend(self._emit_pending_before(t, inclusive=True))
        return out

    def _emit_pending_before(self, t_limit: float, inclusive: bool = False) -> list[Frames]:
        times = sorted(t for t in self._pending if t < t_limit or (inclusive and t == t_limit))
        frames = []
        for t in times:
            p = self._pending.pop(t)
            missing = ~p.present
            if self._last_view is not None:
                self._remember(*self._last_view, np.ones(self.n_sensors, dtype=bool))
            absent = self._absent(t)
            stale = self._none if absent is self._none else missing & absent
            any_stale = stale is not self._none and bool(stale.any())
            if not any_stale:
                stale = self._none
            if not self._last.present.all() and np.any(missing & ~stale & ~self._last.present):
                self.discarded_frames += 1
                self.dropped += p.present  # what did arrive is lost with the frame
                self.discarded_by_sensor += p.present
                continue
            complete = bool(p.present.all())
            if not complete:
                self.dropped += missing
                hold = missing & ~stale if any_stale else missing
                for arr, last in ((p.gyr, self._last.gyr), (p.acc, self._last.acc),
                                  (p.mag, self._last.mag)):
                    if arr is not None and last is not None:
                        arr[hold] = last[hold]  # stale rows stay all-zero
            self._remember(p.gyr, p.acc, p.mag, p.present)
            back = None
            if self._any_stale:
                back = p.present & self._stale
                self.resumed += back
            if any_stale:
                prev = self._last_t if math.isfinite(self._last_t) else t
                self.stale_s[stale] += t - prev
                self._stale = stale.copy()
            elif self._any_stale:
                self._stale = np.zeros(self.n_sensors, dtype=bool)
            self._any_stale = any_stale
            self._last_t = t
            restart = self._restarts(np.array([t])) if self._restart_at else None
            if back is not None and back.any():
                restart = np.zeros((self.n_sensors, 1), dtype=bool) if restart is None \
                    else restart
                restart[back, 0] = True
            frames.append(Frames(
                np.array([t]), p.gyr[:, None], p.acc[:, None],
                None if p.mag is None else p.mag[:, None], np.array([p.arrival]),
                missing[:, None], stale[:, None].copy() if any_stale else None, restart,
            ))
        return frames


def concatenate(frames: list[Frames]) -> Frames:
    """One :class:`Frames` of several, in order (the engine processes them in one batch)."""
    if len(frames) == 1:
        return frames[0]
    mags = [f.mag for f in frames]

    def masks(name: str) -> NDArray[np.bool_] | None:
        parts = [getattr(f, name) for f in frames]
        if all(m is None for m in parts):
            return None
        return np.concatenate([np.zeros_like(f.held) if m is None else m
                               for f, m in zip(frames, parts, strict=True)], axis=1)

    return Frames(
        np.concatenate([f.t_s for f in frames]),
        np.concatenate([f.gyr for f in frames], axis=1),
        np.concatenate([f.acc for f in frames], axis=1),
        None if mags[0] is None else np.concatenate(mags, axis=1),
        np.concatenate([f.arrival_s for f in frames]),
        np.concatenate([f.held for f in frames], axis=1),
        masks("stale"),
        masks("restart"),
    )
