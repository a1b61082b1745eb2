"""The real-time engine: filters for every sensor, the body model, poses at the display rate.

Threading model: one worker thread per engine (:meth:`Engine.start`) polls the source,
assembles frames (:class:`~margtrack.live.assembler.FrameAssembler`) and processes them;
nothing else runs the filters. Whatever arrived while a batch was processed is processed as
the next batch of N frames in *one* call of the estimator's multi-sensor ``run`` on
(S, N, 3) arrays, so a slow moment costs latency, not samples. Other threads (the viewer,
tests) talk to the engine through thread-safe methods: :meth:`set_params`,
:meth:`request_calibration`, :meth:`start_recording`/:meth:`stop_recording`,
:meth:`subscribe`, :meth:`stats`. :meth:`stop` (or leaving the ``with`` block) ends and
joins the worker and closes the source. Without :meth:`start`, :meth:`process` runs the same
work synchronously (tests, offline use). No module-level state: engines are independent.

Per batch: pending parameter changes are applied (they take effect at the batch's first
sample, the next sample after the call), the filters run, frames are recorded and fed to
a pending calibration, and if the batch's last frame crosses a tick of the display clock
(data time, ``display_hz``) its pose is computed (000, eqs. 7, 11) and published to every
subscriber: callbacks run on the worker thread (keep them short), queues drop their oldest
pose when full.

Field faults stay with their sensor: each sensor's clock is mapped to session time (0 at
the first frame) on its own, resets and jumps re-synchronise it, losses are counted from
sequence numbers or timestamp gaps (:mod:`~margtrack.live.clocks`); a sensor silent for
``stale_after_s`` stops integrating (:mod:`~margtrack.live.assembler`); bad samples are
flagged by the estimator's input policy and a failing filter is re-initialised for that
sensor alone (:mod:`~margtrack.live.filtering`). The engine stops only when asked or on
its own bug or a broken source: then :attr:`Engine.error` says why, and the headless
summary (:meth:`Engine.summary`, written to ``summary_path`` when the worker ends) too.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import queue
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import methods
from margtrack.body.offsets import Heading
from margtrack.estimators.base import Estimator, Params
from margtrack.live.assembler import FrameAssembler, Frames, concatenate
from margtrack.live.avatars import Avatars
from margtrack.live.clocks import SensorClocks
from margtrack.live.filtering import SensorFilters
from margtrack.live.protocol import Chunk, Source, SourceInfo
from margtrack.live.recording import LiveRecording
from margtrack.live.reference_pose import CalibrationRequest
from margtrack.live.stats import EngineStats, StatsMeter, summary_dict, write_summary

Array = NDArray[np.float64]

__all__ = ["Engine", "Pose"]


@dataclass(frozen=True, eq=False)
class Pose:
    """One published pose.

    index : frame number since the engine started (0-based); t_s : its sample time, s.
    q_sensor : (S, 4) sensor to earth. q_segment (A, K, 4), joints_m / ends_m (A, K, 3) m:
    the body models' segments and joints, or None without a body model.
    arrival_s / published_s : perf_counter times of the frame's arrival and of publishing.
    """

    index: int
    t_s: float
    q_sensor: Array
    q_segment: Array | None
    joints_m: Array | None
    ends_m: Array | None
    arrival_s: float
    published_s: float

    @property
    def latency_s(self) -> float:
        """End-to-end latency of this pose, s."""
        return self.published_s - self.arrival_s


class Engine:
    """Filters, body model and publishing for the sensors of one source (module docstring).

    Parameters
    ----------
    info : what the source delivers (``source.info``).
    method : registered method name (``"default"``: :data:`margtrack.methods.DEFAULT_METHOD`).
    params : method parameters, a mapping or ``name=value`` strings.
    avatars : body models; ``"auto"`` builds them from the sensor names
        (:meth:`Avatars.from_names`), None for none.
    height_m : body height for ``"auto"`` avatars, m.
    display_hz : rate of published poses, Hz (000's display ran at 25 Hz).
    heading, forward_axis : heading choice of calibrations (:func:`margtrack.body.calibrate`).
    calibrate_at_start : request a calibration on the first still second.
    late_after_s : a frame processed later than this after its arrival counts as late, s.
    max_wait_s, tick_hz : frame assembly (:class:`FrameAssembler`).
    stale_after_s : a sensor without samples for this long (session time) is stale: it
        stops integrating and restarts when samples return, s (default five sample
        periods, 0.1 s without a nominal rate).
    clock_jump_s : a sensor clock step beyond this (or back) is a jump or reset
        (:class:`~margtrack.live.clocks.SensorClocks`), s.
    summary_path : where the worker writes the headless summary JSON when it stops
        (:meth:`summary`; atomically, replacing an older file: check it first).
    """

    def __init__(
        self,
        info: SourceInfo,
        method: str = "default",
        params: Mapping[str, Any] | Iterable[str] = (),
        *,
        avatars: Avatars | str | None = "auto",
        height_m: float = 1.75,
        display_hz: float = 25.0,
        heading: Heading = "north",
        forward_axis: ArrayLike | None = None,
        calibrate_at_start: bool = False,
        late_after_s: float = 0.1,
        max_wait_s: float = 0.05,
        tick_hz: float | None = None,
        stale_after_s: float | None = None,
        clock_jump_s: float = 1.0,
        summary_path: str | None = None,
    ) -> None:
        if not (math.isfinite(display_hz) and display_hz > 0):
            raise ValueError(f"display_hz must be a finite number > 0, got {display_hz}")
        self.info = info
        self.method = methods.get(method).name
        self._estimator: Estimator = methods.create(method, params, rate_hz=info.rate_hz)
        if not info.has_mag and not type(self._estimator).mag_optional:
            raise ValueError(f"method {self.method!r} needs a magnetometer; the source has none")
        frame = self._estimator.params.frame
        if isinstance(avatars, str):
            if avatars != "auto":
                raise ValueError(f"avatars must be 'auto', None or Avatars, got {avatars!r}")
            avatars = Avatars.from_names(info.sensor_names, height_m, frame)
        if avatars is not None and avatars.skeleton.frame != frame:
            raise ValueError(f"avatars are in {avatars.skeleton.frame} but the filter in {frame}")
        self.avatars = avatars
        self.display_hz = float(display_hz)
        self.heading: Heading = heading
        self.forward_axis = forward_axis
        self.late_after_s = float(late_after_s)
        self._calibrations = avatars.identity() if avatars is not None else []
        self._offsets = Avatars.offsets(self._calibrations) if avatars is not None else None
        if stale_after_s is None:
            stale_after_s = 5.0 / info.rate_hz if info.rate_hz else 0.1
        self.stale_after_s = float(stale_after_s)
        self._assembler = FrameAssembler(info.n_sensors, info.has_mag, max_wait_s, tick_hz,
                                         stale_after_s=self.stale_after_s)
        self._clocks = SensorClocks(info.n_sensors, info.rate_hz, clock_jump_s)
        self._assembler.heard_s = self._clocks.heard_s  # one array: held-back samples count
        self._filters = SensorFilters(self._estimator, info.n_sensors)
        self.summary_path = summary_path
        self._fatal: str | None = None
        self._meter = StatsMeter(info.sensor_names)
        self._lock = threading.Lock()
        self._pending: Params | None = None
        self._subscribers: list[Callable[[Pose], None]] = []
        self._recording: list[tuple[Array, Array]] | None = None
        self._request: CalibrationRequest | None = None
        #: (first, last) time of the frames of the last successful calibration, s
        self.calibration_window_s: tuple[float, float] | None = None
        self._calibration_status = "not calibrated (identity offsets)"
        self._last_tick = -math.inf
        self._frame_index = -1
        self._latest: Pose | None = None
        self._source: Source | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._done = threading.Event()
        self._error = ""
        #: hooks called with every batch of frames before / after it is processed (on the
        #: worker thread): raw recording (:class:`~margtrack.live.recording.RawRecorder`) and
        #: the replay of its events (:class:`~margtrack.live.replay.LiveReplaySource`); a
        #: ``before_batch`` hook may return replacement frames (None: keep them)
        self.before_batch: list[Callable[[Frames], Frames | None]] = []
        self.after_batch: list[Callable[[Frames], None]] = []
        if calibrate_at_start:
            self.request_calibration()

    # -- parameters -------------------------------------------------------------------
    @property
    def params(self) -> Params:
        """The filter parameters in force, or the pending ones once :meth:`set_params` ran."""
        with self._lock:
            return self._pending if self._pending is not None else self._estimator.params

    @property
    def active_params(self) -> Params:
        """The parameters the filters ran the last sample with."""
        return self._estimator.params

    @property
    def frame(self) -> str:
        """Earth frame of every orientation."""
        return self._estimator.params.frame

    def set_params(self, **values: Any) -> Params:
        """Change filter parameters; validated now, in force from the next processed sample.

        Raises ``ValueError`` (naming the parameter) for a bad value; returns the new params.
        """
        with self._lock:
            base = self._pending if self._pending is not None else self._estimator.params
            new = dataclasses.replace(base, **values)
            if new.frame != self._estimator.params.frame:
                raise ValueError("frame cannot change while running")
            self._pending = new
        return new

    # -- calibration and recording ----------------------------------------------------------
    def request_calibration(self, duration_s: float = 1.0, max_motion_deg: float = 2.0,
                            timeout_s: float = 10.0) -> None:
        """Calibrate on the next ``duration_s`` of data in which no sensor turns more than
        ``max_motion_deg`` (000, eq. 10); gives up after ``timeout_s`` of data time
        (:class:`~margtrack.live.reference_pose.CalibrationRequest`)."""
        if self.avatars is None:
            raise ValueError("no body model: the sensor names name no skeleton segments")
        request = CalibrationRequest(duration_s, max_motion_deg, timeout_s)
        with self._lock:
            self._request = request
            self._calibration_status = "waiting for a still second in the reference pose"

    @property
    def calibration_status(self) -> str:
        """What the last calibration request did."""
        with self._lock:
            return self._calibration_status

    @property
    def calibrations(self) -> list[Any]:
        """Per person, the :class:`margtrack.body.Calibration` in force."""
        with self._lock:
            return list(self._calibrations)

    def set_calibrations(self, calibrations: Sequence[Any]) -> None:
        """Put per-person body calibrations in force (a replayed or saved calibration)."""
        if self.avatars is None or len(calibrations) != self.avatars.n_people:
            raise ValueError(f"need one calibration per person of the body model, got "
                             f"{len(calibrations)}")
        with self._lock:
            self._calibrations = list(calibrations)
            self._offsets = Avatars.offsets(self._calibrations)

    def start_recording(self) -> None:
        """Record every processed frame from now on (replaces an unfinished recording)."""
        with self._lock:
            self._recording = []

    @property
    def recording(self) -> bool:
        """Whether a recording is running."""
        with self._lock:
            return self._recording is not None

    def stop_recording(self) -> LiveRecording:
        """Stop recording and return what was recorded (``ValueError`` if none was started)."""
        with self._lock:
            parts, self._recording = self._recording, None
            calibrations = tuple(self._calibrations)
        if parts is None:
            raise ValueError("no recording is running; call start_recording() first")
        t = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0)
        empty = np.zeros((0, self.info.n_sensors, 4))
        q = np.concatenate([p[1] for p in parts]) if parts else empty
        return LiveRecording(t, q, self.info.sensor_names, self.frame, self.avatars, calibrations)

    # -- subscribers -----------------------------------------------------------------------
    def subscribe(self, callback: Callable[[Pose], None]) -> Callable[[], None]:
        """Call ``callback(pose)`` for every published pose; returns an unsubscribe function."""
        with self._lock:
            self._subscribers.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._subscribers:
                    self._subscribers.remove(callback)

        return unsubscribe

    def subscribe_queue(self, maxsize: int = 64) -> queue.Queue[Pose]:
        """A queue receiving every published pose; when full, its oldest pose is dropped."""
        q: queue.Queue[Pose] = queue.Queue(maxsize=maxsize)

        def put(pose: Pose) -> None:
            while True:
                try:
                    q.put_nowait(pose)
                    return
                except queue.Full:
                    with contextlib.suppress(queue.Empty):  # emptied meanwhile
                        q.get_nowait()

        self.subscribe(put)
        return q

    @property
    def data_time_s(self) -> float:
        """Session time of the last processed frame, s (``-inf`` before the first)."""
        return self._assembler.last_time_s

    @property
    def session_time_s(self) -> float:
        """Session time of the last processed frame, s (0 at the first frame, 0 before it)."""
        t = self._assembler.last_time_s
        return t if math.isfinite(t) else 0.0

    @property
    def session_origin_s(self) -> float:
        """Device time of the session's first sample, s (``nan`` before it): session 0."""
        return self._clocks.origin_s

    @property
    def error(self) -> str | None:
        """Why the worker stopped on its own (its bug, a broken source), else None."""
        return self._fatal

    @property
    def latest(self) -> Pose | None:
        """The last published pose."""
        return self._latest

    # -- processing ------------------------------------------------------------------------
    def push(self, chunks: Sequence[Chunk], now_s: float | None = None, flush: bool = False
             ) -> Pose | None:
        """Assemble ``chunks`` and process the frames that are ready; returns a published pose."""
        t0 = time.perf_counter()
        now = t0 if now_s is None else now_s
        mapped = self._clocks.map(list(chunks))
        if self._clocks.restarts:
            for sensor, t_s in self._clocks.restarts:
                self._assembler.request_restart(sensor, t_s)
            self._clocks.restarts.clear()
        frames = self._assembler.push(mapped, now)
        if flush:
            frames += self._assembler.expire(now, flush=True)
        self._meter.time_assemble_s += time.perf_counter() - t0
        return self.process(concatenate(frames)) if frames else None

    def process(self, frames: Frames) -> Pose | None:
        """Filters, recording, calibration and publishing for one batch of complete frames."""
        t0 = time.perf_counter()
        for hook in tuple(self.before_batch):
            frames = hook(frames) or frames  # a hook may return the frames to process
        with self._lock:
            if self._pending is not None:
                self._estimator.params, self._pending = self._pending, None
            recording, request = self._recording, self._request
        q, _flags = self._filters.run(frames)  # (S, N, 4): per-sensor faults isolated
        t1 = time.perf_counter()
        n = frames.n_frames
        self._frame_index += n
        if recording is not None or request is not None:
            q_frames = np.swapaxes(q, 0, 1)  # (N, S, 4)
            if recording is not None:
                recording.append((frames.t_s.copy(), q_frames.copy()))
            if request is not None:
                self._calibrate(request, frames.t_s, q_frames)
        tick = math.floor(frames.t_s[-1] * self.display_hz + 1e-6)
        pose = None
        if tick > self._last_tick:
            self._last_tick = tick
            pose = self._pose(frames, q[:, -1])
        t2 = time.perf_counter()
        if pose is not None:
            self._publish(pose)
        t3 = time.perf_counter()
        late = int(np.sum(t3 - frames.arrival_s > self.late_after_s))
        meter = self._meter
        meter.time_filter_s += t1 - t0
        meter.time_body_s += t2 - t1
        meter.time_publish_s += t3 - t2
        meter.batch(frames.t_s, frames.held, frames.mag, t3 - t0, late)
        for hook in tuple(self.after_batch):
            hook(frames)
        return pose

    def _pose(self, frames: Frames, q_last: Array) -> Pose:
        q_segment = joints = ends = None
        if self.avatars is not None:
            with self._lock:
                offsets = self._offsets
            q_segment, joints, ends = self.avatars.pose(q_last, offsets)
        return Pose(self._frame_index, float(frames.t_s[-1]), q_last.copy(), q_segment, joints,
                    ends, float(frames.arrival_s[-1]), math.nan)

    def _publish(self, pose: Pose) -> None:
        pose = dataclasses.replace(pose, published_s=time.perf_counter())
        self._latest = pose
        self._meter.published(pose.latency_s)
        with self._lock:
            subscribers = list(self._subscribers)
        for callback in subscribers:
            try:
                callback(pose)
            except Exception as exc:  # a broken subscriber must not stop tracking
                self._meter.subscriber_errors += 1
                self._error = f"subscriber {callback!r} raised {exc!r}"

    def _calibrate(self, request: CalibrationRequest, t: Array, q: Array) -> None:
        if self.avatars is None:
            return
        outcome = request.feed(self.avatars, t, q, self.heading, self.forward_axis)
        if outcome is None:
            return
        with self._lock:
            if self._request is request:
                self._request = None
            if outcome.calibrations is not None:
                self._calibrations = outcome.calibrations
                self._offsets = Avatars.offsets(outcome.calibrations)
                self.calibration_window_s = outcome.window_s
            self._calibration_status = outcome.status

    # -- statistics ------------------------------------------------------------------------
    def stats(self) -> EngineStats:
        """A snapshot of timing, latency, losses and sensor health."""
        a = self._assembler
        malformed = self._source.stats.malformed if self._source is not None else 0
        dropped = a.dropped.copy()
        c, f = self._clocks, self._filters
        counts = {
            "received": c.received.copy(), "processed": f.processed.copy(),
            "lost": c.lost.copy(), "gaps": c.gaps + a.resumed, "resyncs": c.resyncs.copy(),
            "flagged": f.flagged.copy(), "reinitialised": f.reinitialised.copy(),
            "held": dropped - a.discarded_by_sensor, "late": a.late_by_sensor.copy(),
            "duplicates": a.duplicates_by_sensor.copy(), "bad_time": c.bad_time.copy(),
            "discarded": a.discarded_by_sensor.copy(),
        }
        stale = a.stale
        stats = self._meter.snapshot(self.info.n_sensors, dropped, a.late, malformed,
                                     self.calibration_status, self._error, counts=counts,
                                     stale=stale, stale_s=a.stale_s.copy(),
                                     errors=tuple(f.errors))
        return dataclasses.replace(stats, session_s=self.session_time_s,
                                   engine_error=self._fatal,
                                   lost_samples=int(c.lost.sum()),
                                   stale_sensors=int(stale.sum()))

    def summary(self) -> dict[str, Any]:
        """The headless summary (:func:`margtrack.live.stats.summary_dict`) now."""
        return summary_dict(self.stats(), method=self.method, running=self.running,
                            stale_after_s=self.stale_after_s)

    def write_summary(self, path: str) -> None:
        """Write :meth:`summary` to ``path`` as JSON, atomically (replaces an older file)."""
        write_summary(self.summary(), path, force=True)

    # -- the worker thread -------------------------------------------------------------------
    def start(self, source: Source, poll_timeout_s: float = 0.02) -> Engine:
        """Run the engine on ``source`` in a worker thread (opened here, closed at the end)."""
        if self._thread is not None:
            raise ValueError("this engine was already started; build a new one")
        if tuple(source.info.sensor_names) != self.info.sensor_names:
            raise ValueError("the source's sensors differ from the ones the engine was built for")
        self._source = source
        attach = getattr(source, "attach_engine", None)  # a replay that re-applies events
        if attach is not None:
            attach(self)
        self._thread = threading.Thread(target=self._run, args=(source, poll_timeout_s),
                                        name="margtrack-live-engine", daemon=True)
        self._thread.start()
        return self

    def _run(self, source: Source, poll_timeout_s: float) -> None:
        try:
            source.open()
            while not self._stop.is_set():
                chunks = source.poll(poll_timeout_s)
                end = source.finished and not chunks
                self.push(chunks, flush=end)
                if end:
                    break
            else:  # stopped: what the source already holds (up to 0.25 s of work) and the
                # frames still waiting for samples are processed, so they are counted
                deadline = time.perf_counter() + 0.25
                while time.perf_counter() < deadline:
                    chunks = source.poll(0.0)
                    if not chunks:
                        break
                    self.push(chunks)
                self.push([], flush=True)
        except Exception as exc:  # reported by stats().error, .error and the summary
            self._fatal = f"engine stopped: {exc!r}"
            self._error = self._fatal
        finally:
            with contextlib.suppress(Exception):
                source.close()
            if self.summary_path is not None:
                try:
                    self.write_summary(self.summary_path)
                except Exception as exc:  # the session's result stays in stats()
                    self._error = f"could not write the summary {self.summary_path}: {exc!r}"
            self._done.set()

    @property
    def running(self) -> bool:
        """Whether the worker thread is alive."""
        return self._thread is not None and self._thread.is_alive()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until the source is exhausted (or the engine stopped); True if it ended."""
        return self._done.wait(timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the worker, close the source and join the thread (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise RuntimeError(f"the engine's worker did not stop within {timeout_s} s")

    def __enter__(self) -> Engine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
