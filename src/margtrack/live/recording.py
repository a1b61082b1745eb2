"""Recording a live session: the raw sensor stream (:class:`RawRecorder`) and orientations.

:class:`RawRecorder` keeps what the engine processed, every frame of every sensor (``t``,
gyr, acc, mag, held) in the engine's batches, plus the session's events: the filter
parameters in force and every change of them, and every body calibration, each at the frame
from which it applies. :meth:`RawRecorder.save` writes it as a margtrack live recording
(:mod:`margtrack.io.live_hdf5`, atomically); replaying that file
(:class:`margtrack.live.replay.LiveReplaySource`) through an engine with the recorded
method reproduces the session's poses exactly (stale sensors and filter restarts included:
their flags are recorded and given back to the engine), provided the recording started
with the engine (``margtrack live --record FILE``; a recording started later begins from a
fresh filter and matches once it has converged). The file's metadata also says whether the
session ran without magnetometers (``no_mag``) and, then, the lever arms in force when the
recording started (``lever_arms``: the given ones, and those estimated before a late start)
and when it stopped (``lever_arms_at_stop``); a replay runs the same way
(:class:`margtrack.live.replay.LiveReplaySource` ``no_mag``, ``lever_arms``). Memory:
about 80 bytes per sensor sample (15 sensors at 100 Hz: 430 MB per hour), written out
when the recording stops.

Orientations (:class:`LiveRecording`): the engine records every processed frame's sensor
orientations (at the sensors' rate, not the display rate); the body model is applied at
export with the calibration in force when the recording stopped, so an export is the
offline body model of the recorded orientations: BVH via :func:`margtrack.body.write_bvh`,
joint angles via :func:`margtrack.body.write_joint_angles_csv`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from margtrack import body
from margtrack.io.live_hdf5 import LiveEvent, RawLiveRecording, write_live_recording
from margtrack.live.assembler import Frames
from margtrack.live.avatars import Avatars
from margtrack.live.joint_chain import lever_arms_to_json

if TYPE_CHECKING:
    from margtrack.live.engine import Engine

Array = NDArray[np.float64]

__all__ = ["LiveRecording", "RawRecorder", "calibration_from_dict", "calibration_to_dict"]


def calibration_to_dict(cal: body.Calibration) -> dict[str, Any]:
    """A :class:`margtrack.body.Calibration` as JSON-ready values (floats round-trip exactly)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cal):
        value = getattr(cal, f.name)
        out[f.name] = value.tolist() if isinstance(value, np.ndarray) else (
            list(value) if isinstance(value, tuple) else value)
    return out


def calibration_from_dict(data: dict[str, Any]) -> body.Calibration:
    """The inverse of :func:`calibration_to_dict`."""
    return body.Calibration(
        names=tuple(data["names"]), frame=data["frame"],
        offsets=np.asarray(data["offsets"], dtype=np.float64), heading=data["heading"],
        heading_quat=np.asarray(data["heading_quat"], dtype=np.float64),
        facing_deg=float(data["facing_deg"]),
        spread_deg=np.asarray(data["spread_deg"], dtype=np.float64))


class RawRecorder:
    """Records an engine's raw stream and events (module docstring); thread-safe.

    Built once per engine (it registers itself in ``engine.after_batch``); :meth:`start`
    and :meth:`stop` may be called from any thread, any number of times.
    """

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self._lock = threading.Lock()
        self._parts: list[tuple[Any, ...]] | None = None
        self._events: list[LiveEvent] = []
        self._n = 0
        self._params: Any = None
        self._calibrations: list[Any] = []
        self._start_params: dict[str, Any] = {}
        self._started_utc = ""
        self._session: dict[str, Any] = {}
        engine.after_batch.append(self._on_batch)
        #: whether :meth:`stop` also removes the hook (a recorder made for one recording)
        self.detach_on_stop = False

    def detach(self) -> None:
        """Stop watching the engine (idempotent); a running recording gets no more frames."""
        with contextlib.suppress(ValueError):
            self.engine.after_batch.remove(self._on_batch)

    @property
    def recording(self) -> bool:
        """Whether a recording is running."""
        with self._lock:
            return self._parts is not None

    @property
    def n_frames(self) -> int:
        """Frames recorded so far."""
        with self._lock:
            return self._n

    def start(self) -> None:
        """Start recording from the next processed batch (discards an unfinished one)."""
        engine = self.engine
        with self._lock:
            self._parts, self._events, self._n = [], [], 0
            self._params = engine.active_params
            self._start_params = self._params.as_dict()
            self._calibrations = engine.calibrations
            self._started_utc = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
            self._session = {"no_mag": bool(engine.no_mag)}
            if engine.no_mag:
                self._session["lever_arms"] = lever_arms_to_json(engine.lever_arms_in_force)
            if engine.avatars is not None:
                self._events.append(self._calibration_event(0, float("nan")))

    def note(self, text: str) -> None:
        """Add a free-text event at the next frame (a marker: "subject sat down")."""
        with self._lock:
            if self._parts is not None:
                self._events.append(LiveEvent(self._n, float("nan"), "note", {"text": text}))

    def _calibration_event(self, frame: int, t_s: float) -> LiveEvent:
        cals = [calibration_to_dict(c) for c in self._calibrations]
        return LiveEvent(frame, t_s, "calibration", {"calibrations": cals})

    def _on_batch(self, frames: Frames) -> None:
        """Engine hook: keep a copy of the batch and note changes of params/calibration."""
        with self._lock:
            if self._parts is None:
                return
            engine = self.engine
            t0 = float(frames.t_s[0])
            params = engine.active_params
            if params is not self._params:  # the engine swaps in a new object on a change
                self._params = params
                self._events.append(LiveEvent(self._n, t0, "params", {
                    "method": engine.method, "params": params.as_dict()}))
            cals = engine.calibrations
            if len(cals) != len(self._calibrations) or any(
                    a is not b for a, b in zip(cals, self._calibrations, strict=True)):
                self._calibrations = cals
                self._events.append(self._calibration_event(self._n, t0))
            self._events = [  # events waiting for their frame's time get it now
                dataclasses.replace(e, t_s=t0) if e.frame == self._n and e.t_s != e.t_s else e
                for e in self._events]
            shape = frames.held.shape
            flags = [getattr(frames, k, None) for k in ("stale", "restart")]
            self._parts.append((
                frames.t_s.copy(), frames.gyr.copy(), frames.acc.copy(),
                None if frames.mag is None else frames.mag.copy(), frames.held.copy(),
                *(np.zeros(shape, bool) if f is None else np.array(f, bool) for f in flags)))
            self._n += frames.n_frames

    def stop(self) -> RawLiveRecording:
        """Stop and return what was recorded (``ValueError`` if not recording or empty)."""
        with self._lock:
            parts, self._parts = self._parts, None
            events, n, session = list(self._events), self._n, dict(self._session)
        if parts is None:
            raise ValueError("no raw recording is running; call start() first")
        if self.detach_on_stop:
            self.detach()
        if not parts:
            raise ValueError("the raw recording holds no frame: nothing arrived while it ran")
        engine = self.engine
        mags = [p[3] for p in parts]
        if engine.no_mag:
            session["lever_arms_at_stop"] = lever_arms_to_json(engine.lever_arms_in_force)
        events = [e for e in events if e.frame < n or e.kind == "note"]
        return RawLiveRecording(
            sensor_names=tuple(engine.info.sensor_names),
            t_s=np.concatenate([p[0] for p in parts]),
            batch_frames=np.array([p[0].size for p in parts], dtype=np.int64),
            gyr=np.concatenate([p[1] for p in parts], axis=1),
            acc=np.concatenate([p[2] for p in parts], axis=1),
            mag=None if any(m is None for m in mags) else np.concatenate(mags, axis=1),
            held=np.concatenate([p[4] for p in parts], axis=1),
            stale=np.concatenate([p[5] for p in parts], axis=1),
            restart=np.concatenate([p[6] for p in parts], axis=1),
            events=tuple(events), frame=engine.frame, method=engine.method,
            params=self._start_params, rate_hz=engine.info.rate_hz,
            description=engine.info.description,
            meta={"started_utc": self._started_utc,
                  # device time = t + origin for a sensor whose clock never reset
                  "session_origin_s": float(getattr(engine, "session_origin_s", 0.0)),
                  **session})

    def save(self, path: str | Path, force: bool = False) -> Path:
        """:meth:`stop` and write the file atomically; returns its path."""
        return write_live_recording(self.stop(), path, force=force)


@dataclass(frozen=True, eq=False)
class LiveRecording:
    """Recorded sensor orientations and what is needed to turn them into body motion.

    Attributes
    ----------
    t_s : (N,) s, sample times.
    q_sensor : (N, S, 4) sensor to earth (``frame``), one per source sensor.
    sensor_names : S names.
    frame : earth frame.
    avatars : the body models (None if the sensors name none).
    calibrations : per person, the offsets in force at the end of the recording.
    root_m : (N, A, 3) m, every person's root as the engine's walking root moved it (NaN
        while it stayed at the avatar's place), or None: the roots never walked.
    """

    t_s: Array
    q_sensor: Array
    sensor_names: tuple[str, ...]
    frame: str
    avatars: Avatars | None
    calibrations: tuple[body.Calibration, ...]
    root_m: Array | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames N."""
        return int(self.t_s.shape[0])

    def _check(self, person: int) -> Avatars:
        if self.avatars is None:
            raise ValueError("this recording has no body model: its sensors name no segments")
        if not 0 <= person < self.avatars.n_people:
            raise ValueError(f"person must be in 0..{self.avatars.n_people - 1}, got {person}")
        if self.n_frames < 2:
            raise ValueError(f"the recording has {self.n_frames} frame(s); record at least 2")
        return self.avatars

    def segment_orientations(self, person: int = 0) -> Array:
        """(N, K, 4) segment to earth of one person (000, eq. 7)."""
        avatars = self._check(person)
        q = self.q_sensor[:, avatars.index[person]]
        return body.segment_orientations(avatars.skeleton, self.calibrations[person], q)

    def joint_angles(self, person: int = 0) -> body.JointAngles:
        """Joint angles (N, J, 3) rad of one person."""
        avatars = self._check(person)
        return body.joint_angles(avatars.skeleton, self.segment_orientations(person))

    def frame_time_s(self) -> float:
        """Median interval between frames, s (the BVH frame time)."""
        return float(np.median(np.diff(self.t_s)))

    def root_positions_m(self, person: int = 0) -> Array:
        """(N, 3) m, one person's root at every frame: where the walking root had it, else
        (before it walked, or without it) the avatar's place."""
        avatars = self._check(person)
        place = avatars.root_positions_m[person]
        if self.root_m is None:
            return np.tile(place, (self.n_frames, 1))
        root = np.array(self.root_m[:, person], dtype=np.float64)
        still = np.isnan(root).any(axis=1)
        root[still] = place
        return root

    def write_bvh(self, path: str | Path, person: int = 0, unit: str = "cm") -> Path:
        """BVH of one person at the recording's median frame interval, the root's channels
        from :meth:`root_positions_m`, lengths in ``unit`` (cm or m, as ``margtrack body
        --bvh-unit``); returns the path."""
        avatars = self._check(person)
        body.write_bvh(path, avatars.skeleton, self.segment_orientations(person),
                       self.frame_time_s(), self.root_positions_m(person), unit)
        return Path(path)

    def write_joint_angles_csv(self, path: str | Path, person: int = 0) -> Path:
        """CSV of one person's joint angles in degrees with ``t (s)``; returns the path."""
        body.write_joint_angles_csv(path, self.t_s, self.joint_angles(person))
        return Path(path)

    def export(self, folder: str | Path, stem: str = "live", people: Sequence[int] = (0,),
               unit: str = "cm") -> list[Path]:
        """BVH (lengths in ``unit``) and joint-angle CSV of each listed person into
        ``folder``; returns the files."""
        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        files = []
        for a in people:
            suffix = "" if len(people) == 1 else f"_{a}"
            files.append(self.write_bvh(out / f"{stem}{suffix}.bvh", a, unit))
            files.append(self.write_joint_angles_csv(out / f"{stem}{suffix}_joints.csv", a))
        return files
