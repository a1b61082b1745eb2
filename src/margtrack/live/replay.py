"""Replay of recorded MARG data as a live source, at real speed, faster, or unpaced.

:class:`ReplaySource` plays arrays ``gyr``/``acc``/``mag`` (S, N, 3) on timestamps ``t``
(N,): frame ``i`` becomes due at wall-clock time ``start + (t_i - t_0) / speed``
(:class:`~margtrack.live.protocol.Pacer`), and each poll returns every frame due by then as
one chunk, so a consumer that falls behind gets larger chunks instead of losing frames.
``speed=math.inf`` delivers chunks of ``chunk_frames`` as fast as they are polled.

:class:`LiveReplaySource` (:mod:`margtrack.live.live_replay`, re-exported here) plays a raw
live recording (``margtrack live --record``) with the session's events: its poses come back
exactly.

:func:`replay_path` reads what :mod:`margtrack.io` reads: a raw live recording, a BROAD
trial or a margtrack HDF5/CSV file (one sensor), an x-IMU3 sensor folder, or an x-IMU3
body folder such as ../shared/data/xio_lower_body (one folder per sensor, each on its own
clock): its sensors are resampled linearly onto one time base at their median rate over the
span they share, which is what lets the engine run them as one (S, N, 3) batch.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import time_base
from margtrack.io.live_hdf5 import is_live_recording, read_live_recording
from margtrack.live.live_replay import LiveReplaySource
from margtrack.live.protocol import BaseSource, Chunk, Pacer, SourceInfo
from margtrack.recording import Recording, resample

Array = NDArray[np.float64]

__all__ = ["LiveReplaySource", "ReplaySource", "common_time_base", "replay_path",
           "replay_recordings"]

#: Samples (frames x sensors) per chunk when unpaced: large enough to amortise the
#: per-call overhead of the filters, small enough to keep memory and latency bounded.
_UNPACED_SAMPLES = 1 << 16


def _stacked(value: ArrayLike, name: str, shape: tuple[int, int] | None) -> Array:
    arr = np.ascontiguousarray(value, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (S, N, 3) or (N, 3), got {arr.shape}")
    if shape is not None and arr.shape[:2] != shape:
        raise ValueError(f"{name} has shape {arr.shape} but gyr has {(*shape, 3)}")
    if not np.all(np.isfinite(arr)):
        s, i, _ = (int(v) for v in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"{name} has a non-finite value at sensor {s}, sample {i}")
    return arr


class ReplaySource(BaseSource):
    """Recorded frames replayed in time (module docstring).

    Parameters
    ----------
    t_s : (N,) s, strictly increasing.
    gyr, acc : (S, N, 3) rad/s and m/s² (or (N, 3) for one sensor).
    mag : (S, N, 3) any unit, or None.
    sensor_names : S names (default ``sensor0`` ...).
    speed : playback speed factor > 0 (1 real time, 10 ten times faster, ``math.inf``
        unpaced).
    chunk_frames : frames per chunk when unpaced (default: about 65536 samples per chunk).
    loop : start again after the last frame, timestamps continuing (for demos and soak runs).
    description : label shown by the viewer.
    """

    def __init__(
        self,
        t_s: ArrayLike,
        gyr: ArrayLike,
        acc: ArrayLike,
        mag: ArrayLike | None = None,
        sensor_names: Sequence[str] | None = None,
        speed: float = 1.0,
        chunk_frames: int | None = None,
        loop: bool = False,
        description: str = "replay",
    ) -> None:
        t = np.ascontiguousarray(t_s, dtype=np.float64)
        if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)):
            raise ValueError(f"t_s must be a finite (N,) array with N >= 2, got shape {t.shape}")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            i = int(bad[0]) + 1
            raise ValueError(
                f"t_s must increase strictly: t[{i - 1}] = {t[i - 1]}, t[{i}] = {t[i]}")
        # stored frames-first, so that a chunk of one frame is a contiguous (S, 1, 3) view
        gyr_a = _stacked(gyr, "gyr", None)
        if gyr_a.shape[1] != t.size:
            raise ValueError(f"gyr has {gyr_a.shape[1]} samples but t_s has {t.size}")
        shape = gyr_a.shape[:2]
        self.gyr = np.ascontiguousarray(np.swapaxes(gyr_a, 0, 1)).swapaxes(0, 1)
        self.acc = np.ascontiguousarray(np.swapaxes(_stacked(acc, "acc", shape), 0, 1)
                                        ).swapaxes(0, 1)
        self.mag = None if mag is None else np.ascontiguousarray(
            np.swapaxes(_stacked(mag, "mag", shape), 0, 1)).swapaxes(0, 1)
        self.t_s = t
        n_sensors = shape[0]
        names = tuple(sensor_names) if sensor_names is not None else tuple(
            f"sensor{s}" for s in range(n_sensors)
        )
        if len(names) != n_sensors:
            raise ValueError(f"sensor_names has {len(names)} names for {n_sensors} sensors")
        rate = float(1.0 / np.median(np.diff(t)))
        super().__init__(SourceInfo(names, rate, self.mag is not None, description))
        if chunk_frames is None:
            chunk_frames = max(1, _UNPACED_SAMPLES // n_sensors)
        if int(chunk_frames) < 1:
            raise ValueError(f"chunk_frames must be >= 1, got {chunk_frames}")
        self.chunk_frames = int(chunk_frames)
        self.loop = bool(loop)
        self._pacer = Pacer(t[0], speed)
        self._cursor = 0
        self._lap = 0
        self._period_s = float(t[-1] - t[0]) + 1.0 / rate

    @property
    def speed(self) -> float:
        """Playback speed factor."""
        return self._pacer.speed

    @property
    def started_s(self) -> float | None:
        """perf_counter time at which playback started (None before :meth:`open`)."""
        return self._pacer.start_s

    def open(self) -> None:
        """Start the playback clock (idempotent)."""
        if not self._opened:
            self._pacer.start()
        super().open()

    def _slice(self, i: int, j: int, arrival: Array) -> Chunk:
        self._stats.samples += (j - i) * self.info.n_sensors
        return Chunk(
            t_s=self.t_s[i:j] + self._lap * self._period_s,
            sensors=np.arange(self.info.n_sensors, dtype=np.intp),
            gyr=self.gyr[:, i:j],
            acc=self.acc[:, i:j],
            mag=None if self.mag is None else self.mag[:, i:j],
            arrival_s=arrival,
        )

    def _advance(self, j: int) -> None:
        self._cursor = j
        if j >= self.t_s.size:
            if self.loop:
                self._cursor = 0
                self._lap += 1
            else:
                self._finished = True

    def poll(self, timeout_s: float) -> list[Chunk]:
        """Frames due now as one chunk; waits up to ``timeout_s`` s for the next one."""
        if self._finished:
            return []
        if not self._opened:
            self.open()
        i = self._cursor
        if self._pacer.unpaced:
            j = min(i + self.chunk_frames, self.t_s.size)
            chunk = self._slice(i, j, np.full(j - i, self._pacer.now()))
            self._advance(j)
            return [chunk]
        offset = self._lap * self._period_s
        next_due = float(self._pacer.due_time(self.t_s[i] + offset))
        wait = next_due - self._pacer.now()
        if wait > timeout_s:
            _sleep(timeout_s)
            return []
        _sleep(wait)
        due_t = self._pacer.data_time_now() - offset
        j = int(np.searchsorted(self.t_s, due_t, side="right"))
        j = max(j, i + 1)
        chunk = self._slice(i, j, self._pacer.due_time(self.t_s[i:j] + offset))
        self._advance(j)
        return [chunk]


def _sleep(seconds: float) -> None:
    if seconds > 0:
        time.sleep(seconds)


def common_time_base(recordings: Sequence[Recording], rate_hz: float | None = None) -> Array:
    """Timestamps over the span all recordings share, at ``rate_hz`` (default: median rate)
    (:func:`margtrack.time_base.common_time_base`, the sensors named by position)."""
    if not recordings:
        raise ValueError("no recordings given")
    if rate_hz is None:
        rate_hz = float(np.median([1.0 / np.median(np.diff(r.t)) for r in recordings]))
    t, _ = time_base.common_time_base(
        {f"sensor{i}" + (f" ({r.name})" if r.name else ""): r
         for i, r in enumerate(recordings)}, rate_hz)
    return t


def replay_recordings(
    recordings: Sequence[Recording],
    names: Sequence[str] | None = None,
    speed: float = 1.0,
    rate_hz: float | None = None,
    loop: bool = False,
    description: str = "replay",
) -> ReplaySource:
    """A source playing several recordings as one body of sensors.

    Recordings with identical timestamps are used as they are; otherwise every signal is
    resampled linearly (:func:`margtrack.recording.resample`) onto :func:`common_time_base`.
    The magnetometer is kept only if every recording has one.
    """
    recs = list(recordings)
    if not recs:
        raise ValueError("no recordings given")
    same = all(r.t.shape == recs[0].t.shape and np.array_equal(r.t, recs[0].t) for r in recs)
    with_mag = all(r.mag is not None for r in recs)
    if same and rate_hz is None:
        t = recs[0].t
        gyr = np.stack([r.gyr for r in recs])
        acc = np.stack([r.acc for r in recs])
        mag = np.stack([r.mag for r in recs]) if with_mag else None
    else:
        t = common_time_base(recs, rate_hz)
        gyr = np.stack([resample(r.t, r.gyr, t) for r in recs])
        acc = np.stack([resample(r.t, r.acc, t) for r in recs])
        mag = np.stack([resample(r.t, r.mag, t) for r in recs]) if with_mag else None
    labels = list(names) if names is not None else [r.name or f"sensor{i}"
                                                     for i, r in enumerate(recs)]
    return ReplaySource(t, gyr, acc, mag, labels, speed=speed, loop=loop, description=description)


def replay_path(
    path: str | Path, speed: float = 1.0, rate_hz: float | None = None, loop: bool = False
) -> ReplaySource | LiveReplaySource:
    """A source replaying a file or folder (module docstring lists what is read).

    An x-IMU3 body folder gives one sensor per subfolder, named after it (``pelvis``,
    ``left_upper_leg``...), which the engine maps onto the body model's segments.
    """
    from margtrack import io

    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"no such file or folder: {p}")
    if p.is_file() and is_live_recording(p):
        if loop or rate_hz is not None:
            raise ValueError(f"{p} is a raw live recording: it replays as recorded, without "
                             "--loop or a new rate")
        return LiveReplaySource(read_live_recording(p), speed)
    description = f"replay {p.name}"
    if p.is_dir() and not (p / "Inertial.csv").is_file():
        if any((d / "Inertial.csv").is_file() for d in p.iterdir() if d.is_dir()):
            body = io.read_xio_body(p)
            return replay_recordings(list(body.values()), list(body), speed, rate_hz, loop,
                                     description)
        trials = sorted(p.glob("*.hdf5"))
        hint = f"; e.g. {trials[0]}" if trials else ""
        raise ValueError(f"{p} is a folder of neither x-IMU3 sensors nor one sensor: "
                         f"give one recording file{hint}")
    rec = io.read(p)
    return replay_recordings([rec], [rec.name or p.stem], speed, rate_hz, loop, description)
