"""Frames from chunks: every sensor's sample at one time, in time order, gaps counted.

The filters run S sensors on common timestamps, so the engine needs complete frames. Block
sources deliver them already (a chunk with all S sensors passes straight through); line
sources deliver one sensor's sample at a time, and :class:`FrameAssembler` collects the
samples with equal time (after rounding onto ``tick_hz``, if given) until

- every sensor has reported: the frame is complete;
- a later frame completes first, or the frame has waited ``max_wait_s`` (wall clock): it
  is emitted incomplete, each missing sensor holding its previous sample (zero-order hold;
  counted in ``dropped`` per sensor). A frame with a sensor never seen before is discarded
  whole (there is nothing to hold), also counted.

A sample for a time at or before the last emitted frame arrives too late to be used: it is
counted in ``late`` and discarded, as are repeated samples (``duplicates``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from margtrack.live.protocol import Chunk

Array = NDArray[np.float64]

__all__ = ["FrameAssembler", "Frames", "concatenate"]


@dataclass(frozen=True, eq=False)
class Frames:
    """N complete frames of all S sensors: the engine's unit of work.

    t_s (N,), gyr/acc/mag (S, N, 3) (mag None without magnetometers), arrival_s (N,) the
    perf_counter time each frame was complete (its latest sample's arrival), held (S, N)
    bool: True where a missing sample was replaced by the sensor's previous one.
    """

    t_s: Array
    gyr: Array
    acc: Array
    mag: Array | None
    arrival_s: Array
    held: NDArray[np.bool_]

    @property
    def n_frames(self) -> int:
        """Number of frames N."""
        return int(self.t_s.shape[0])


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
    """

    def __init__(
        self, n_sensors: int, with_mag: bool, max_wait_s: float = 0.05,
        tick_hz: float | None = None,
    ) -> None:
        if n_sensors < 1:
            raise ValueError(f"n_sensors must be >= 1, got {n_sensors}")
        if not max_wait_s >= 0:
            raise ValueError(f"max_wait_s must be >= 0, got {max_wait_s}")
        if tick_hz is not None and not (np.isfinite(tick_hz) and tick_hz > 0):
            raise ValueError(f"tick_hz must be a finite number > 0, got {tick_hz}")
        self.n_sensors = n_sensors
        self.with_mag = with_mag
        self.max_wait_s = max_wait_s
        self.tick_hz = tick_hz
        self._pending: dict[float, _Pending] = {}
        self._last_t = -np.inf
        self._last = _Pending(n_sensors, with_mag, 0.0)  # latest sample of every sensor
        self._last_view: tuple[Array, Array, Array | None] | None = None  # full-chunk path
        self._all = np.arange(n_sensors)
        self.late = 0
        self.duplicates = 0
        self.dropped = np.zeros(n_sensors, dtype=np.int64)
        self.discarded_frames = 0

    @property
    def last_time_s(self) -> float:
        """Time of the last emitted frame (``-inf`` before the first)."""
        return self._last_t

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
    def _block(self, chunk: Chunk) -> Frames | None:
        keep = chunk.t_s > self._last_t
        if not keep.any():
            self.late += chunk.n_frames * self.n_sensors
            return None
        start = int(np.argmax(keep))
        self.late += start * self.n_sensors
        t = chunk.t_s[start:]
        gyr, acc = chunk.gyr[:, start:], chunk.acc[:, start:]
        mag = None if chunk.mag is None or not self.with_mag else chunk.mag[:, start:]
        # the last frame is kept as a view; copied only if a later frame needs holds
        self._last_view = (gyr[:, -1], acc[:, -1], None if mag is None else mag[:, -1])
        self._last_t = float(t[-1])
        return Frames(t, gyr, acc, mag, chunk.arrival_s[start:],
                      np.zeros((self.n_sensors, t.size), dtype=bool))

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

    def _add_samples(self, chunk: Chunk) -> list[Frames]:
        out: list[Frames] = []
        for n in range(chunk.n_frames):
            t = float(chunk.t_s[n])
            if self.tick_hz is not None:
                t = round(t * self.tick_hz) / self.tick_hz
            if t <= self._last_t:
                self.late += chunk.n_sensors
                continue
            arrival = float(chunk.arrival_s[n])
            pending = self._pending.get(t)
            if pending is None:
                pending = self._pending[t] = _Pending(self.n_sensors, self.with_mag, arrival)
            for k, s in enumerate(chunk.sensors):
                if pending.present[s]:
                    self.duplicates += 1
                    continue
                pending.gyr[s] = chunk.gyr[k, n]
                pending.acc[s] = chunk.acc[k, n]
                if pending.mag is not None and chunk.mag is not None:
                    pending.mag[s] = chunk.mag[k, n]
                pending.present[s] = True
            pending.arrival = max(pending.arrival, arrival)
            if pending.present.all():
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
            if np.any(missing & ~self._last.present):
                self.discarded_frames += 1
                self.dropped += p.present  # what did arrive is lost with the frame
                continue
            self.dropped += missing
            for arr, last in ((p.gyr, self._last.gyr), (p.acc, self._last.acc),
                              (p.mag, self._last.mag)):
                if arr is not None and last is not None:
                    arr[missing] = last[missing]
            self._remember(p.gyr, p.acc, p.mag, p.present)
            self._last_t = t
            frames.append(Frames(
                np.array([t]), p.gyr[:, None].copy(), p.acc[:, None].copy(),
                None if p.mag is None else p.mag[:, None].copy(), np.array([p.arrival]),
                missing[:, None].copy(),
            ))
        return frames


def concatenate(frames: list[Frames]) -> Frames:
    """One :class:`Frames` of several, in order (the engine processes them in one batch)."""
    if len(frames) == 1:
        return frames[0]
    mags = [f.mag for f in frames]
    return Frames(
        np.concatenate([f.t_s for f in frames]),
        np.concatenate([f.gyr for f in frames], axis=1),
        np.concatenate([f.acc for f in frames], axis=1),
        None if mags[0] is None else np.concatenate(mags, axis=1),
        np.concatenate([f.arrival_s for f in frames]),
        np.concatenate([f.held for f in frames], axis=1),
    )
