"""Per-sensor clocks of a live session: device time to session time, resyncs and losses.

Session time starts at 0 at the first sample of the session: ``t_session = t_device -
offset``, one offset per sensor, at first the device time of the session's first sample
for every sensor (sensors sharing a clock keep equal times); ``device = session +
offset_s[sensor]`` (a raw recording keeps the chunks as they arrived, in device time).

Each sensor's clock is followed on its own (line sources, one sample per chunk):

- a step ``0 < dt <= jump_s`` is normal; a step of k sample periods (k >= 2) means k - 1
  samples were lost (counted in ``lost``, the interval counted in ``gaps``), unless the
  lines carry sequence numbers, which then count losses exactly;
- a step forward by more than ``jump_s`` that matches the wall-clock time since the
  sensor's previous sample (within 0.1 s + 10 %) is a silence, not a jump: a normal step;
- a step back (a reboot restarting at 0, a repeated or backward stamp) or forward by more
  than ``jump_s`` otherwise (a stamp of ``1e9``) makes that sample *suspect*: it is held
  back. If the sensor's next sample continues the old clock, the suspect was a bad stamp and is
  discarded (``bad_time``); if it continues the suspect's clock, the clock was reset: the
  sensor is *re-synchronised* (``resyncs``, ``gaps``): a new offset puts the confirming
  sample at the session time of the other sensors' latest sample plus the wall-clock time
  since it arrived, rounded to whole sample periods (after the sensor's own last sample),
  and the suspect one period before it. The engine restarts that sensor's filter there
  (:attr:`SensorClocks.restarts`): nothing after a reboot is discarded.

Block sources (every sensor in one chunk, one clock) share one offset; a reset or jump of
their clock re-synchronises every sensor at once. A block costs a few numpy operations over
its sensors, no Python per sensor: the per-sensor state is held in (S,) arrays.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from margtrack.live.protocol import Chunk

Array = NDArray[np.float64]

__all__ = ["SensorClocks", "rows_of"]


def rows_of(sensors: NDArray[np.intp], n_sensors: int) -> slice | NDArray[np.intp]:
    """An index for the (S,) arrays of a chunk's ``sensors``: ``slice(None)`` when the chunk
    holds every sensor in order (the block sources' case: a slice costs no gather)."""
    if sensors.shape[0] == n_sensors and (
            n_sensors == 0 or (sensors[0] == 0 and sensors[-1] == n_sensors - 1
                               and np.array_equal(sensors, np.arange(n_sensors)))):
        return slice(None)
    return sensors


class SensorClocks:
    """Device to session time for S sensors (module docstring).

    Parameters
    ----------
    n_sensors : S.
    rate_hz : nominal sample rate, Hz, or None (then each sensor's period is learned from
        its own steps).
    jump_s : the largest forward step of a clock that is not a jump, s.

    Per-sensor state is (S,) arrays (``offset_s``, ``last_session_s`` ...); ``restarts`` is
    a list of ``(sensors, session time)`` with ``sensors`` an index array.
    """

    def __init__(self, n_sensors: int, rate_hz: float | None, jump_s: float = 1.0) -> None:
        if not (math.isfinite(jump_s) and jump_s > 0):
            raise ValueError(f"clock jump_s must be a finite number > 0, got {jump_s}")
        self.n_sensors = n_sensors
        self.jump_s = float(jump_s)
        nominal = 1.0 / rate_hz if rate_hz else math.nan
        self.nominal_period_s = nominal
        self.period_s = np.full(n_sensors, nominal)
        self.origin_s = math.nan  # device time of the session's first sample
        self.offset_s = np.full(n_sensors, np.nan)
        self.last_device_s = np.full(n_sensors, np.nan)
        self.last_session_s = np.full(n_sensors, np.nan)
        self.last_arrival_s = np.full(n_sensors, np.nan)
        self.last_seq = np.full(n_sensors, -1, dtype=np.int64)
        #: arrival (perf_counter) of each sensor's latest chunk of any kind (suspects too)
        self.heard_s = np.full(n_sensors, -np.inf)
        self._suspect: list[Chunk | None] = [None] * n_sensors
        self._received = np.zeros(n_sensors, dtype=np.int64)
        self.lost = np.zeros(n_sensors, dtype=np.int64)
        self.gaps = np.zeros(n_sensors, dtype=np.int64)
        self.resyncs = np.zeros(n_sensors, dtype=np.int64)
        self.bad_time = np.zeros(n_sensors, dtype=np.int64)
        #: (sensors, session time) of samples at which sensors' filters must restart
        self.restarts: list[tuple[NDArray[np.intp], float]] = []
        self._block_last_s = math.nan

    def map(self, chunks: list[Chunk]) -> list[Chunk]:
        """The chunks with session times, suspects held back, bad stamps left out."""
        out: list[Chunk] = []
        for chunk in chunks:
            if chunk.n_sensors == 1 and chunk.n_frames == 1:
                out.extend(self._line(chunk))
            else:
                mapped = self._block(chunk)
                if mapped is not None:
                    out.append(mapped)
        return out

    @property
    def received(self) -> NDArray[np.int64]:
        """(S,) samples received per sensor (held-back and discarded ones included)."""
        return self._received.copy()

    def pending_suspects(self) -> int:
        """Samples held back as suspect (their sensor's next sample decides)."""
        return sum(c is not None for c in self._suspect)

    # -- block sources --------------------------------------------------------------------
    def _block(self, chunk: Chunk) -> Chunk | None:
        n = chunk.n_frames
        if n == 0:
            return None
        t = chunk.t_s
        sensors = chunk.sensors
        rows = rows_of(sensors, self.n_sensors)
        self._received[rows] += n
        if math.isnan(self.origin_s):
            self.origin_s = float(t[0])
            self.offset_s[:] = self.origin_s
        offset = float(self.offset_s[sensors[0]])
        first = float(t[0]) - offset
        last = self._block_last_s
        if math.isfinite(last) and not (last < first <= last + self.jump_s):
            step = float(np.median(np.diff(t))) if t.size > 1 else self.nominal_period_s
            step = step if math.isfinite(step) and step > 0 else 0.01
            offset = float(t[0]) - (last + step)
            self.offset_s[rows] = offset
            self.resyncs[rows] += 1
            self.gaps[rows] += 1
            self.restarts.append((np.array(sensors, dtype=np.intp), last + step))
        session = t - offset
        self._block_last_s = float(session[-1])
        self.last_session_s[rows] = float(session[-1])
        self.last_device_s[rows] = float(t[-1])
        self.last_arrival_s[rows] = float(chunk.arrival_s[-1])
        return dataclasses.replace(chunk, t_s=session)

    # -- line sources ----------------------------------------------------------------------
    def _line(self, chunk: Chunk) -> list[Chunk]:
        s = int(chunk.sensors[0])
        d = float(chunk.t_s[0])
        arrival = float(chunk.arrival_s[0])
        self._received[s] += 1
        if not self.heard_s[s] >= arrival:
            self.heard_s[s] = arrival
        if chunk.seq is not None:
            seq = int(chunk.seq[0])
            last_seq = int(self.last_seq[s])
            if last_seq >= 0 and seq > last_seq + 1:
                self.lost[s] += seq - last_seq - 1
                self.gaps[s] += 1
            self.last_seq[s] = seq
        if math.isnan(self.origin_s):
            self.origin_s = d
        if math.isnan(self.offset_s[s]):
            return self._first(s, d, chunk)
        step = d - float(self.last_device_s[s])
        suspect = self._suspect[s]
        waited = arrival - float(self.last_arrival_s[s])
        if 0.0 < step <= self.jump_s or (
                step > 0.0 and abs(step - waited) <= 0.1 + 0.1 * waited):  # a silence
            if suspect is not None:  # the old clock goes on: the suspect was a bad stamp
                self._suspect[s] = None
                self.bad_time[s] += 1
            self._count_time_loss(s, step, chunk.seq is None)
            return [self._emit(s, d, chunk)]
        if suspect is None:
            self._suspect[s] = chunk
            return []
        d_suspect = float(suspect.t_s[0])
        step2 = d - d_suspect
        if not 0.0 < step2 <= self.jump_s:  # no clock to follow yet: this one is suspect now
            self._suspect[s] = chunk
            self.bad_time[s] += 1
            return []
        self._suspect[s] = None
        self._resync(s, d, step2, arrival)
        self.resyncs[s] += 1
        self.gaps[s] += 1
        self.restarts.append((np.array([s], dtype=np.intp),
                              d_suspect - float(self.offset_s[s])))
        return [self._emit(s, d_suspect, suspect), self._emit(s, d, chunk)]

    def _first(self, s: int, d: float, chunk: Chunk) -> list[Chunk]:
        session = d - self.origin_s
        frontier = float(np.max(self.last_session_s, initial=-np.inf,
                                where=np.isfinite(self.last_session_s)))
        if math.isfinite(frontier) and abs(session - frontier) > self.jump_s:
            # a clock of its own: align by arrival
            self._resync(s, d, math.nan, float(chunk.arrival_s[0]))
            self.resyncs[s] += 1
            return [self._emit(s, d, chunk)]
        self.offset_s[s] = self.origin_s
        return [self._emit(s, d, chunk)]

    def _count_time_loss(self, s: int, step: float, no_seq: bool) -> None:
        period = float(self.period_s[s])
        if math.isnan(self.nominal_period_s):
            # no nominal rate: learn the period from the smallest steps seen
            period = step if math.isnan(period) else min(period, step)
            self.period_s[s] = period
        if no_seq and self.last_seq[s] < 0:
            missing = math.floor(step / period + 0.5) - 1
            if missing >= 1:
                self.lost[s] += missing
                self.gaps[s] += 1

    def _resync(self, s: int, d: float, step2: float, arrival: float) -> None:
        """New offset of sensor ``s`` whose sample at device time ``d`` arrived at ``arrival``."""
        period = float(self.period_s[s])
        if not (period > 0):
            period = step2 if step2 > 0 else 0.01
        arrivals = np.where(np.isfinite(self.last_arrival_s), self.last_arrival_s, -np.inf)
        arrivals[s] = -np.inf
        p = int(np.argmax(arrivals))  # the other sensor heard last (the first of equals)
        if math.isfinite(arrivals[p]):
            ref_session, ref_arrival = float(self.last_session_s[p]), float(arrivals[p])
        else:
            ref_session = float(self.last_session_s[s])
            ref_arrival = float(self.last_arrival_s[s])
        if not math.isfinite(ref_session):
            ref_session, ref_arrival = 0.0, arrival
        session = ref_session + round(max(arrival - ref_arrival, 0.0) / period) * period
        own = float(self.last_session_s[s])
        if math.isfinite(own):
            floor = own + period + (step2 if step2 > 0 else 0.0)
            session = max(session, floor)
        self.offset_s[s] = d - session

    def _emit(self, s: int, d: float, chunk: Chunk) -> Chunk:
        session = d - float(self.offset_s[s])
        self.last_device_s[s] = d
        self.last_session_s[s] = session
        self.last_arrival_s[s] = float(chunk.arrival_s[0])
        return Chunk(np.array([session]), chunk.sensors, chunk.gyr, chunk.acc, chunk.mag,
                     chunk.arrival_s, chunk.seq)
