"""Raw live recordings: the multi-sensor stream of a live session and its events, in HDF5.

Written by :class:`margtrack.live.recording.RawRecorder` (``margtrack live --record FILE``
and the page's "Start recording"), read by :func:`read_live_recording` (the offline body
workflow, :func:`margtrack.io.read_any`) and replayed by
:class:`margtrack.live.replay.LiveReplaySource` (``margtrack live --replay FILE``).

Layout (format ``"margtrack-live-recording"``, version 1); float64 everywhere, SI units:

- root attributes: ``format``, ``version``, ``sensor_names`` (JSON list: the source's
  sensors in source order), ``frame`` (earth frame of the filter: ``"NED"``/``"ENU"``),
  ``method`` and ``params`` (JSON object: the method and its parameters at the start),
  ``rate_hz`` (nominal rate, Hz, ``nan`` if unknown), ``has_mag``, ``description``,
  ``started_utc`` (ISO 8601) and ``meta`` (JSON object);
- ``frames/t_s`` (N,) s: the time of every frame the engine processed, in order;
  ``frames/batch_frames`` (B,) int64: how many frames each engine batch held (their sum is
  N), which lets a replay cut the stream exactly as the session did;
- ``sensors/<name>/`` one group per sensor (attribute ``index``: its position in
  ``sensor_names``; ``frame = "sensor"``: the signals are in the sensor's own axes) with
  datasets ``t`` (N,) s (session time, 0 at the session's first sample: device time is
  ``t + meta["session_origin_s"]`` for a sensor whose clock was never re-synchronised),
  ``gyr`` (N, 3) rad/s, ``acc`` (N, 3) m/s² (specific force: at rest it points up),
  ``mag`` (N, 3) µT (only if ``has_mag``), ``held`` (N,) bool (the sensor's sample was
  missing and its previous one was held; zeros while stale), ``stale`` (N,) bool (the sensor
  was silent too long and its filter held its output) and ``restart`` (N,) bool (its filter
  restarted there: a clock resync or the end of a stale period). Each dataset has a
  ``unit`` attribute. Values are stored as the engine received them (a non-finite sample a
  sensor sent stays in the file);
- ``events``: a table (compound dataset) of ``frame`` int64 (index into ``frames/t_s`` of
  the first frame the event applies to), ``t_s`` float64, ``kind`` str and ``data`` str (a
  JSON object). Kinds: ``"params"`` (``{"method": ..., "params": {...}}``, the parameters
  in force from that frame), ``"calibration"`` (``{"calibrations": [...]}``, the body
  calibrations of every person in force from that frame, fields of
  :class:`margtrack.body.Calibration`), ``"note"`` (free text).

The file is written once, when the recording stops, to a temporary file in the target folder
that is then renamed into place (:func:`write_live_recording`), so a crash never leaves a
half-written file under the requested name.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from margtrack.io.safe_output import atomic_output, check_output
from margtrack.recording import Recording

Array = NDArray[np.float64]

__all__ = [
    "LIVE_FORMAT",
    "LiveEvent",
    "RawLiveRecording",
    "is_live_recording",
    "read_live_recording",
    "write_live_recording",
]

LIVE_FORMAT = "margtrack-live-recording"
VERSION = 1
_STR = h5py.string_dtype()
_EVENT_DTYPE = np.dtype([("frame", "<i8"), ("t_s", "<f8"), ("kind", _STR), ("data", _STR)])
EVENT_KINDS = ("params", "calibration", "note")


@dataclass(frozen=True)
class LiveEvent:
    """Something that happened in a live session: frame index, time (s), kind, JSON data."""

    frame: int
    t_s: float
    kind: str
    data: dict[str, Any]


@dataclass(frozen=True, eq=False)
class RawLiveRecording:
    """A raw live recording (layout in the module docstring).

    Attributes
    ----------
    path : the file it was read from (None when built in memory).
    sensor_names : S names, source order.
    t_s : (N,) s frame times; batch_frames : (B,) frames per engine batch.
    gyr, acc : (S, N, 3) rad/s, m/s², sensor frame; mag : (S, N, 3) µT or None.
    held, stale, restart : (S, N) bool (module docstring); events : in frame order.
    frame, method, params, rate_hz, description, meta : what the session ran with.
    """

    sensor_names: tuple[str, ...]
    t_s: Array
    batch_frames: NDArray[np.int64]
    gyr: Array
    acc: Array
    mag: Array | None
    held: NDArray[np.bool_]
    events: tuple[LiveEvent, ...]
    frame: str
    method: str
    params: dict[str, Any]
    stale: NDArray[np.bool_] | None = None
    restart: NDArray[np.bool_] | None = None
    rate_hz: float | None = None
    description: str = ""
    meta: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames N."""
        return int(self.t_s.shape[0])

    @property
    def recordings(self) -> dict[str, Recording]:
        """One :class:`Recording` per sensor, by name (for the offline workflows).

        Only the sensor's own samples go in: held ones (repeats of an earlier sample, zeros
        while stale) are left out, and so are samples with a non-finite value; the frame
        indices left out are listed in ``meta["dropped_frames"]`` (the raw arrays keep
        everything). ``meta["restart_frames"]`` lists where the live filter restarted.
        """
        out: dict[str, Recording] = {}
        for s, name in enumerate(self.sensor_names):
            arrays = [self.gyr[s], self.acc[s]] + ([self.mag[s]] if self.mag is not None else [])
            ok = np.all(np.stack([np.isfinite(a).all(axis=1) for a in arrays]), axis=0)
            ok &= ~self.held[s]
            meta: dict[str, Any] = {"source": str(self.path) if self.path else "live",
                                    "format": LIVE_FORMAT, "sensor_index": s,
                                    "held_frames": int(self.held[s].sum())}
            if not ok.all():
                meta["dropped_frames"] = np.flatnonzero(~ok).tolist()
            if self.restart is not None and self.restart[s].any():
                meta["restart_frames"] = np.flatnonzero(self.restart[s]).tolist()
            if not ok.any():
                raise ValueError(f"{self._where()}: sensor {name!r} has no sample of its own "
                                 "(all held or non-finite)")
            out[name] = Recording(
                t=self.t_s[ok], gyr=self.gyr[s][ok], acc=self.acc[s][ok],
                mag=None if self.mag is None else self.mag[s][ok],
                frame=self.frame if self.frame in ("NED", "ENU") else "ENU",  # type: ignore[arg-type]
                name=name, meta=meta)
        return out

    def _where(self) -> str:
        return str(self.path) if self.path is not None else "live recording"


def _events_array(events: Sequence[LiveEvent]) -> np.ndarray:
    out = np.zeros(len(events), dtype=_EVENT_DTYPE)
    for i, e in enumerate(events):
        if e.kind not in EVENT_KINDS:
            raise ValueError(f"event kind must be one of {EVENT_KINDS}, got {e.kind!r}")
        out[i] = (int(e.frame), float(e.t_s), e.kind, json.dumps(e.data, sort_keys=True))
    return out


def write_live_recording(rec: RawLiveRecording, path: str | Path, force: bool = False) -> Path:
    """Write ``rec`` to ``path`` atomically (:func:`margtrack.io.safe_output.atomic_output`).

    Refuses to overwrite an existing file unless ``force`` and to write over the file ``rec``
    was read from (:func:`~margtrack.io.safe_output.check_output`). Returns the path.
    """
    p = check_output(path, [rec.path] if rec.path is not None else [], force=force)
    _check_shapes(rec)
    with atomic_output(p) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = LIVE_FORMAT
            f.attrs["version"] = VERSION
            f.attrs["sensor_names"] = json.dumps(list(rec.sensor_names))
            f.attrs["frame"] = rec.frame
            f.attrs["method"] = rec.method
            f.attrs["params"] = json.dumps(rec.params, sort_keys=True)
            f.attrs["rate_hz"] = math.nan if rec.rate_hz is None else float(rec.rate_hz)
            f.attrs["has_mag"] = rec.mag is not None
            f.attrs["description"] = rec.description
            f.attrs["started_utc"] = str(rec.meta.get(
                "started_utc", _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")))
            f.attrs["meta"] = json.dumps(rec.meta, sort_keys=True, default=str)
            fr = f.create_group("frames")
            fr.create_dataset("t_s", data=rec.t_s).attrs["unit"] = "s"
            fr.create_dataset("batch_frames", data=np.asarray(rec.batch_frames, np.int64))
            sensors = f.create_group("sensors")
            for s, name in enumerate(rec.sensor_names):
                g = sensors.create_group(name)
                g.attrs["index"] = s
                g.attrs["frame"] = "sensor"
                g.create_dataset("t", data=rec.t_s).attrs["unit"] = "s"
                g.create_dataset("gyr", data=rec.gyr[s]).attrs["unit"] = "rad/s"
                g.create_dataset("acc", data=rec.acc[s]).attrs["unit"] = "m/s^2"
                if rec.mag is not None:
                    g.create_dataset("mag", data=rec.mag[s]).attrs["unit"] = "uT"
                g.create_dataset("held", data=rec.held[s]).attrs["unit"] = "bool"
                for key, flags in (("stale", rec.stale), ("restart", rec.restart)):
                    values = flags[s] if flags is not None else np.zeros(rec.t_s.size, bool)
                    g.create_dataset(key, data=values).attrs["unit"] = "bool"
            f.create_dataset("events", data=_events_array(rec.events))
    return p


def _check_shapes(rec: RawLiveRecording) -> None:
    s, n = len(rec.sensor_names), rec.t_s.shape[0]
    for name, arr in (("gyr", rec.gyr), ("acc", rec.acc), ("mag", rec.mag)):
        if arr is not None and arr.shape != (s, n, 3):
            raise ValueError(f"{name} must have shape ({s}, {n}, 3), got {arr.shape}")
    for name, flags in (("held", rec.held), ("stale", rec.stale), ("restart", rec.restart)):
        if flags is not None and flags.shape != (s, n):
            raise ValueError(f"{name} must have shape ({s}, {n}), got {flags.shape}")
    if int(np.sum(rec.batch_frames)) != n:
        raise ValueError(f"batch_frames sum to {int(np.sum(rec.batch_frames))}, not {n} frames")


def is_live_recording(path: str | Path) -> bool:
    """True if ``path`` is an HDF5 file in this format (False for anything else)."""
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("format") == LIVE_FORMAT
    except (OSError, ValueError):
        return False


def _json_attr(f: h5py.File, name: str, where: Path) -> Any:
    try:
        return json.loads(f.attrs[name])
    except KeyError:
        raise ValueError(f"{where}: attribute {name!r} is missing; the file is damaged") from None
    except (TypeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{where}: attribute {name!r} is not valid JSON: {exc}") from None


def _dataset(f: h5py.File | h5py.Group, key: str, where: str) -> np.ndarray:
    if key not in f:
        raise ValueError(f"{where}: dataset {key!r} is missing; the recording is incomplete")
    return np.asarray(f[key][()])


def read_live_recording(path: str | Path) -> RawLiveRecording:
    """Read a raw live recording (layout in the module docstring).

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` naming the path for a
    truncated or foreign file, a missing sensor group or dataset, mismatched lengths and
    frame times that do not strictly increase (with the first bad index).
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such file: {p}")
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise ValueError(f"{p} is not a readable HDF5 file (truncated or not HDF5?): {exc}"
                         ) from None
    with f:
        if f.attrs.get("format") != LIVE_FORMAT:
            raise ValueError(f"{p} is not a margtrack live recording (format attribute "
                             f"{f.attrs.get('format')!r}); read it with margtrack.io.read")
        version = int(f.attrs.get("version", -1))
        if version != VERSION:
            raise ValueError(f"{p}: live recording version {version}; this margtrack reads "
                             f"version {VERSION}")
        names = tuple(str(n) for n in _json_attr(f, "sensor_names", p))
        params = _json_attr(f, "params", p)
        meta = _json_attr(f, "meta", p)
        has_mag = bool(f.attrs.get("has_mag", False))
        t = np.asarray(_dataset(f, "frames/t_s", str(p)), dtype=np.float64)
        batches = np.asarray(_dataset(f, "frames/batch_frames", str(p)), dtype=np.int64)
        _check_time(t, f"{p}: frames/t_s")
        if int(batches.sum()) != t.size or np.any(batches < 1):
            raise ValueError(f"{p}: frames/batch_frames sums to {int(batches.sum())} but "
                             f"frames/t_s has {t.size} frames; the file is damaged")
        gyr, acc, mag, held, stale, restart = [], [], [], [], [], []
        for name in names:
            key = f"sensors/{name}"
            if key not in f:
                raise ValueError(f"{p}: sensor group {key!r} is missing (sensor_names lists "
                                 f"{list(names)}); the recording is incomplete")
            g = f[key]
            where = f"{p}: {key}"
            ts = np.asarray(_dataset(g, "t", where), dtype=np.float64)
            _check_time(ts, f"{where}/t")
            if ts.shape != t.shape:
                raise ValueError(f"{where}/t has {ts.size} samples but frames/t_s has {t.size}")
            parts = [("gyr", gyr), ("acc", acc)] + ([("mag", mag)] if has_mag else [])
            for key3, out in parts:
                arr = np.asarray(_dataset(g, key3, where), dtype=np.float64)
                if arr.shape != (t.size, 3):
                    raise ValueError(f"{where}/{key3} must have shape ({t.size}, 3), "
                                     f"got {arr.shape}")
                out.append(arr)
            h = np.asarray(_dataset(g, "held", where), dtype=bool)
            if h.shape != t.shape:
                raise ValueError(f"{where}/held must have shape ({t.size},), got {h.shape}")
            held.append(h)
            for key, out in (("stale", stale), ("restart", restart)):
                flags = np.asarray(_dataset(g, key, where), dtype=bool)
                if flags.shape != t.shape:
                    raise ValueError(f"{where}/{key} must have shape ({t.size},), got "
                                     f"{flags.shape}")
                out.append(flags)
        events = tuple(_read_events(f, p))
        rate = float(f.attrs.get("rate_hz", math.nan))
        return RawLiveRecording(
            sensor_names=names, t_s=t, batch_frames=batches,
            gyr=np.stack(gyr) if names else np.zeros((0, t.size, 3)),
            acc=np.stack(acc) if names else np.zeros((0, t.size, 3)),
            mag=np.stack(mag) if has_mag and names else None,
            held=np.stack(held) if names else np.zeros((0, t.size), bool),
            stale=np.stack(stale) if names else None,
            restart=np.stack(restart) if names else None,
            events=events, frame=str(f.attrs.get("frame", "ENU")),
            method=str(f.attrs.get("method", "default")), params=dict(params),
            rate_hz=rate if math.isfinite(rate) else None,
            description=str(f.attrs.get("description", "")), meta=dict(meta), path=p)


def _check_time(t: Array, where: str) -> None:
    if t.ndim != 1:
        raise ValueError(f"{where} must have shape (N,), got {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ValueError(f"{where}[{int(bad[0])}] is not finite ({t[bad[0]]})")
    steps = np.flatnonzero(np.diff(t) <= 0)
    if steps.size:
        i = int(steps[0]) + 1
        raise ValueError(f"{where} is not strictly increasing: t[{i - 1}] = {t[i - 1]!r}, "
                         f"t[{i}] = {t[i]!r}; the file is damaged or was edited")


def _read_events(f: h5py.File, p: Path) -> list[LiveEvent]:
    if "events" not in f:
        raise ValueError(f"{p}: the events table is missing; the recording is incomplete")
    table = f["events"][()]
    out = []
    for i, row in enumerate(table):
        kind = row["kind"].decode() if isinstance(row["kind"], bytes) else str(row["kind"])
        raw = row["data"].decode() if isinstance(row["data"], bytes) else str(row["data"])
        try:
            data = json.loads(raw)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{p}: events row {i} has invalid JSON data: {exc}") from None
        out.append(LiveEvent(int(row["frame"]), float(row["t_s"]), kind, data))
    return out

