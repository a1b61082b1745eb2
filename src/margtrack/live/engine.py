"""The real-time engine: filters for every sensor, the body model, poses at the display rate.

Threading: one worker thread per engine (:mod:`~margtrack.live.engine_thread`: start,
wait, stop, the summary) polls the source, assembles frames
(:class:`~margtrack.live.assembler.FrameAssembler`) and processes them. What arrived while a
batch was processed is
the next batch of N frames, run in *one* multi-sensor kernel call on (S, N, 3) arrays
(reused buffers, :mod:`~margtrack.live.filtering`), so a slow moment costs latency, not
samples; a backlog is run in batches of at most ``MAX_BATCH_FRAMES`` (the kernels' best
rate per sample, and a pose published between them), not in one ever larger batch whose
fresh buffers cost page faults that put the engine further behind. Other threads talk to
the engine through thread-safe methods (:meth:`set_params`, :meth:`request_calibration`,
:meth:`start_recording`/:meth:`stop_recording`, :meth:`subscribe`, :meth:`stats`).
Without :meth:`start`, :meth:`process` runs the same work synchronously. No module-level
state: engines are independent.

Per batch: pending parameter changes are applied (in force from the batch's first sample),
the filters run, frames are recorded (:mod:`~margtrack.live.orientation_log`) and fed to a
pending calibration (:mod:`~margtrack.live.calibrations`), and if the batch's last frame
crosses a tick of the display clock (data time, ``display_hz``) the pose of every person
is computed at once (000, eqs. 7, 11) and published (:mod:`~margtrack.live.subscribers`:
callbacks on the worker thread, queues dropping their oldest pose when full). No Python
runs per sensor: the bookkeeping (clocks, frames, counts, health) is numpy over the S
sensors, the body model one compiled pass over people and segments.

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

import dataclasses
import math
import queue
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.body.offsets import Heading
from margtrack.estimator import Params
from margtrack.live.assembler import FrameAssembler, Frames, concatenate
from margtrack.live.avatars import Avatars
from margtrack.live.calibrations import Calibrations
from margtrack.live.clocks import SensorClocks
from margtrack.live.engine_setup import checked_setup
from margtrack.live.engine_thread import EngineThread
from margtrack.live.filtering import SensorFilters
from margtrack.live.joint_chain import JointChain, RecentFrames
from margtrack.live.orientation_log import OrientationLog
from margtrack.live.pose import Pose
from margtrack.live.protocol import Chunk, Source, SourceInfo
from margtrack.live.recording import LiveRecording
from margtrack.live.stats import StatsMeter
from margtrack.live.subscribers import Subscribers
from margtrack.live.walking_root import LiveRoot, WalkingRoot
from margtrack.live.worker import Worker

Array = NDArray[np.float64]

__all__ = ["MAX_BATCH_FRAMES", "Engine", "Pose"]

#: frames of all sensors run in one batch at most (module docstring): at 100,000 sensors
#: 8 frames a call run at 1.5-2.3x the rate of 1 frame (``benchmarks/live_scale.py``'s batch
#: scan); 16 frames gained at most 6 % more (``bachmann``) or lost 18 % (``robust``)
MAX_BATCH_FRAMES = 8


class Engine(EngineThread):
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
    no_mag : no magnetometer: every filter runs 6-D and, with a body model, every segment
        but each person's root is chained to its parent across the joint
        (:class:`~margtrack.live.joint_chain.JointChain`); a calibration request then waits
        until every joint has settled.
    lever_arms : with ``no_mag``, joint name -> given lever arms
        (:func:`~margtrack.live.joint_chain.read_chain_lever_arms`); others are estimated.
    walking_root : once a calibration is in force, move every person's root with the feet's
        contacts (:class:`~margtrack.live.walking_root.WalkingRoot`, ``Pose.root_m``);
        :meth:`reset_root` puts the roots back. Needs a shank or foot on both legs.
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
        no_mag: bool = False,
        lever_arms: Mapping[str, Any] | None = None,
        walking_root: bool = False,
    ) -> None:
        if not (math.isfinite(display_hz) and display_hz > 0):
            raise ValueError(f"display_hz must be a finite number > 0, got {display_hz}")
        self.info = info
        self.method, self._estimator, avatars = checked_setup(
            info, method, params, avatars, height_m, heading, no_mag, lever_arms)
        self.avatars = avatars
        self.no_mag = bool(no_mag)
        self._chain = (JointChain(avatars, info.rate_hz, lever_arms)
                       if no_mag and avatars is not None else None)
        self._root = (LiveRoot(avatars) if walking_root and avatars is not None
                      and WalkingRoot(avatars).available else None)
        self.display_hz = float(display_hz)
        self.heading: Heading = heading
        self.forward_axis = forward_axis
        self.late_after_s = float(late_after_s)
        self._body = Calibrations(avatars, heading, forward_axis)
        self._recent = RecentFrames(self._body)  # no_mag: frames kept for a calibration
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
        self._subscribers = Subscribers()
        self._log = OrientationLog(info.sensor_names, avatars)
        self._last_tick = -math.inf
        self._frame_index = -1
        self._latest: Pose | None = None
        self._source: Source | None = None
        self._worker = Worker(self.push, self._finish)  # EngineThread runs it
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
        self._body.request(duration_s, max_motion_deg, timeout_s)

    @property
    def calibration_status(self) -> str:
        """What the last calibration request did."""
        if self._chain is not None and not self._chain.settled and self._body.pending:
            return ("waiting for every joint to settle (--no-mag: walk or move every joint "
                    "for a few seconds), then for a still second in the reference pose")
        return self._body.status

    @property
    def joints(self) -> list[dict[str, Any]]:
        """With ``no_mag`` and a body model, per constrained joint: its lever arms and
        state (:meth:`~margtrack.live.joint_chain.JointChain.describe`); else empty."""
        return [] if self._chain is None else self._chain.describe()

    @property
    def lever_arms_in_force(self) -> dict[str, Any]:
        """With ``no_mag`` and a body model, joint name -> the lever arms in force
        (:meth:`~margtrack.live.joint_chain.JointChain.lever_arms_in_force`); else empty."""
        return {} if self._chain is None else self._chain.lever_arms_in_force()

    @property
    def calibration_window_s(self) -> tuple[float, float] | None:
        """(first, last) time of the frames of the last successful calibration, s."""
        return self._body.window_s

    @property
    def calibrations(self) -> list[Any]:
        """Per person, the :class:`margtrack.body.Calibration` in force."""
        return self._body.in_force

    def set_calibrations(self, calibrations: Sequence[Any]) -> None:
        """Put per-person body calibrations in force (a replayed or saved calibration)."""
        self._body.set(calibrations)

    def start_recording(self) -> None:
        """Record every processed frame from now on (replaces an unfinished recording)."""
        self._log.start()

    @property
    def recording(self) -> bool:
        """Whether a recording is running."""
        return self._log.active

    def stop_recording(self) -> LiveRecording:
        """Stop recording and return what was recorded (``ValueError`` if none was started)."""
        return self._log.stop(self.frame, self._body.in_force)

    # -- subscribers -----------------------------------------------------------------------
    def subscribe(self, callback: Callable[[Pose], None]) -> Callable[[], None]:
        """Call ``callback(pose)`` for every published pose; returns an unsubscribe function."""
        return self._subscribers.subscribe(callback)

    def subscribe_queue(self, maxsize: int = 64) -> queue.Queue[Pose]:
        """A queue receiving every published pose; when full, its oldest pose is dropped."""
        return self._subscribers.subscribe_queue(maxsize)

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
            for sensors, t_s in self._clocks.restarts:
                self._assembler.request_restart(sensors, t_s)
            self._clocks.restarts.clear()
        frames = self._assembler.push(mapped, now)
        if flush:
            frames += self._assembler.expire(now, flush=True)
        self._meter.time_assemble_s += time.perf_counter() - t0
        if not frames:
            return None
        batch = concatenate(frames)
        pose = None
        for start in range(0, batch.n_frames, MAX_BATCH_FRAMES):
            published = self.process(batch.part(start, start + MAX_BATCH_FRAMES))
            pose = published if published is not None else pose
        return pose

    def process(self, frames: Frames) -> Pose | None:
        """Filters, recording, calibration and publishing for one batch of complete frames."""
        t0 = time.perf_counter()
        for hook in tuple(self.before_batch):
            frames = hook(frames) or frames  # a hook may return the frames to process
        with self._lock:
            if self._pending is not None:
                self._estimator.params, self._pending = self._pending, None
        record, request = self._log.appender(), self._body.pending
        if self.no_mag:
            q, _flags = self._filters.run(dataclasses.replace(frames, mag=None))
            q_last = self._filters.q_last
            if self._chain is not None:
                q6 = q
                q = self._chain.run(frames, q)
                q_last = self._chain.q_last
                request = self._recent.feed(self._chain, request, frames.t_s, q6)
        else:
            q, _flags = self._filters.run(frames)  # (S, N, 4): per-sensor faults isolated
            q_last = self._filters.q_last
        t1 = time.perf_counter()
        self._frame_index += frames.n_frames
        q_frames = np.swapaxes(q, 0, 1)  # (N, S, 4), a view
        if request is not None:
            self._body.feed(request, frames.t_s, q_frames)
        tick = math.floor(frames.t_s[-1] * self.display_hz + 1e-6)
        pose = None
        if tick > self._last_tick:
            self._last_tick = tick
            # the batch's last orientations: the filters keep them contiguous (q_last);
            # q[:, -1] is a strided view (its copy 0.89 ms against 0.33 at 150,000 sensors)
            pose = Pose.of(self._frame_index, frames.t_s[-1], frames.arrival_s[-1],
                           q_last, self.avatars, self._body.offsets)
        roots = None
        if self._root is not None:  # the roots follow the feet (live/walking_root.py)
            roots = self._root.batch(frames.t_s, frames.gyr, q, self._body.offsets,
                                     self._body.count)
            pose = None if pose is None else self._root.walk(pose)
        if record is not None:
            record(frames.t_s, q_frames, roots)
        t2 = time.perf_counter()
        if pose is not None:
            self._publish(pose)
        t3 = time.perf_counter()
        late = int(np.count_nonzero(t3 - frames.arrival_s > self.late_after_s))
        meter = self._meter
        meter.time_filter_s += t1 - t0
        meter.time_body_s += t2 - t1
        meter.time_publish_s += t3 - t2
        meter.batch(frames.t_s, frames.held, frames.mag, t3 - t0, late)
        for hook in tuple(self.after_batch):
            hook(frames)
        return pose

    @property
    def walking_root(self) -> bool:
        """Whether the roots move with the feet's contacts."""
        return self._root is not None

    def reset_root(self) -> None:
        """Put every root back at its avatar's place (from the next pose on)."""
        if self._root is not None:
            self._root.request_reset()

    def _publish(self, pose: Pose) -> None:
        self._latest, failed, error = self._subscribers.publish(pose)
        self._meter.published(self._latest.latency_s)
        if failed:
            self._meter.subscriber_errors += failed
            self._error = error
