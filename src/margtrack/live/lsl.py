"""Lab Streaming Layer source (``pylsl``, whose wheel carries liblsl): one stream, many sensors.

The stream (type ``"IMU"`` or ``"MARG"``, a numeric channel format) carries one frame of all
its sensors per LSL sample, with channel labels saying which is which::

    <sensor>/gx <sensor>/gy <sensor>/gz <sensor>/ax <sensor>/ay <sensor>/az
    [<sensor>/mx <sensor>/my <sensor>/mz]        ... for every sensor, in any order

(a one-sensor stream may drop the ``<sensor>/`` prefix). Units: each channel's ``unit``
in the stream description (``rad/s`` or ``deg/s``; ``m/s^2`` or ``g``; any unit for the
field, µT preferred); without one, SI. The sample time is the LSL time stamp, s
(:func:`pylsl.local_clock` of the sender). Sensors are named after the prefixes in their
first appearance order; all of them need the magnetometer, or none.

The stream is found by name (:func:`pylsl.resolve_byprop`, which uses LSL's multicast and
broadcast discovery; on this machine's loopback it resolves within milliseconds) when the
source is built, so that its sensors are known before the engine is; ``ValueError`` if
none answers within ``timeout_s`` or its channels do not follow the layout above.

Bad input never raises: a sensor whose values in a sample are not finite is left out of that
frame (counted as rejected with the sensor and time; the engine holds its previous sample),
and a frame whose time is not after the previous one is delivered (a restarted sender) and
counted in :attr:`LslSource.non_monotonic`.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from margtrack.live.protocol import BaseSource, Chunk, SourceInfo

__all__ = ["LslSource", "imu_stream_info"]

_AXES = ("gx", "gy", "gz", "ax", "ay", "az", "mx", "my", "mz")
_SCALE = {"rad/s": 1.0, "deg/s": math.pi / 180.0, "m/s^2": 1.0, "m/s2": 1.0,
          "g": 9.80665}
_MAX_SAMPLES_PER_POLL = 65536


def _pylsl() -> Any:
    try:
        import pylsl
    except ImportError as exc:  # pragma: no cover - pylsl is in the live extra
        raise ImportError("the LSL source needs pylsl: pip install 'margtrack[live]'") from exc
    return pylsl


def _channels(info: Any) -> list[tuple[str, str]]:
    out = []
    ch = info.desc().child("channels").child("channel")
    while not ch.empty():
        out.append((ch.child_value("label"), ch.child_value("unit")))
        ch = ch.next_sibling()
    return out


def _layout(name: str, channels: list[tuple[str, str]], n_channels: int
            ) -> tuple[tuple[str, ...], bool, np.ndarray, np.ndarray]:
    """Sensor names, has_mag, (S, 9) channel index per axis (-1: absent), (S, 9) scale."""
    if len(channels) != n_channels:
        raise ValueError(f"LSL stream {name!r} describes {len(channels)} channels but has "
                         f"{n_channels}; label every channel <sensor>/gx ... <sensor>/mz")
    sensors: list[str] = []
    index: dict[tuple[str, str], int] = {}
    units: dict[tuple[str, str], str] = {}
    for i, (label, unit) in enumerate(channels):
        sensor, _, axis = label.rpartition("/")
        if axis not in _AXES:
            raise ValueError(f"LSL stream {name!r}: channel {i} label {label!r} is not "
                             f"<sensor>/<axis> with axis one of {', '.join(_AXES)}")
        if sensor not in sensors:
            sensors.append(sensor)
        if (sensor, axis) in index:
            raise ValueError(f"LSL stream {name!r}: channel label {label!r} appears twice")
        index[(sensor, axis)] = i
        units[(sensor, axis)] = unit.strip()
    has_mag = all((s, "mx") in index for s in sensors)
    needed = _AXES if has_mag else _AXES[:6]
    idx = np.full((len(sensors), 9), -1, dtype=np.intp)
    scale = np.ones((len(sensors), 9))
    for k, s in enumerate(sensors):
        for j, axis in enumerate(needed):
            if (s, axis) not in index:
                raise ValueError(f"LSL stream {name!r}: sensor {s or '(unprefixed)'!r} has no "
                                 f"channel {axis!r}; every sensor needs {', '.join(needed)}")
            idx[k, j] = index[(s, axis)]
            unit = units[(s, axis)]
            if j < 6 and unit:
                if unit not in _SCALE or (j < 3) != unit.endswith("/s"):
                    raise ValueError(f"LSL stream {name!r}: channel {s}/{axis} has unit "
                                     f"{unit!r}; use rad/s or deg/s (gyr), m/s^2 or g (acc)")
                scale[k, j] = _SCALE[unit]
    names = tuple(s if s else "sensor0" for s in sensors)
    return names, has_mag, idx, scale


class LslSource(BaseSource):
    """Frames of an LSL stream found by name (module docstring); never finishes by itself.

    Parameters
    ----------
    name : the stream's name (``StreamInfo.name()``).
    timeout_s : how long to look for it, s.
    """

    def __init__(self, name: str, timeout_s: float = 5.0) -> None:
        pylsl = _pylsl()
        found = pylsl.resolve_byprop("name", name, timeout=timeout_s)
        if not found:
            raise ValueError(f"no LSL stream named {name!r} answered within {timeout_s} s; "
                             "is the sender running on a reachable machine?")
        inlet = pylsl.StreamInlet(found[0], max_buflen=60)
        info = inlet.info(timeout=timeout_s)
        if info.type() not in ("IMU", "MARG"):
            raise ValueError(f"LSL stream {name!r} has type {info.type()!r}; expected IMU or "
                             "MARG")
        if info.channel_format() in (pylsl.cf_string, pylsl.cf_undefined):
            raise ValueError(f"LSL stream {name!r} carries strings; send numbers "
                             "(float32/double64)")
        names, has_mag, self._idx, self._scale = _layout(name, _channels(info),
                                                         info.channel_count())
        rate = info.nominal_srate()
        super().__init__(SourceInfo(names, rate if rate > 0 else None, has_mag,
                                    f"LSL {name}"))
        self._inlet = inlet
        self._last_t = -math.inf
        #: frames whose time was not after the previous frame's (delivered)
        self.non_monotonic = 0

    def open(self) -> None:
        """Subscribe to the stream (idempotent)."""
        if not self._opened:
            self._inlet.open_stream(timeout=5.0)
        super().open()

    def poll(self, timeout_s: float) -> list[Chunk]:
        """Every frame received so far; waits up to ``timeout_s`` s for the first one."""
        if self.finished:
            return []
        if not self._opened:
            self.open()
        samples, stamps = self._inlet.pull_chunk(timeout=max(timeout_s, 0.0),
                                                 max_samples=_MAX_SAMPLES_PER_POLL)
        if not stamps:
            return []
        return self.frames(np.asarray(samples, dtype=np.float64),
                           np.asarray(stamps, dtype=np.float64), time.perf_counter())

    def frames(self, values: np.ndarray, t_s: np.ndarray, arrival_s: float) -> list[Chunk]:
        """Chunks of N LSL samples ``values`` (N, channels) at times ``t_s`` (N,)."""
        n_sensors = self.info.n_sensors
        take = np.where(self._idx >= 0, self._idx, 0)
        data = values[:, take] * self._scale  # (N, S, 9)
        width = 9 if self.info.has_mag else 6
        ok = np.all(np.isfinite(data[:, :, :width]), axis=2)  # (N, S)
        back = np.flatnonzero(np.diff(np.concatenate([[self._last_t], t_s])) <= 0)
        self.non_monotonic += back.size
        if back.size:
            self._stats.last_error = f"LSL time went back at {t_s[back[0]]!r} s"
        self._last_t = float(t_s[-1])
        for i, s in zip(*np.nonzero(~ok), strict=True):
            self._stats.reject(f"LSL sample at {t_s[i]!r} s: sensor "
                               f"{self.info.sensor_names[s]!r} has a non-finite value")
        self._stats.samples += int(ok.sum())
        chunks = []
        all_ok = ok.all(axis=1)
        start = 0
        # runs of complete frames go out as one block; a frame with a bad sensor on its own
        for i in [*np.flatnonzero(~all_ok), len(t_s)]:
            if i > start:
                chunks.append(self._chunk(data[start:i], t_s[start:i], np.arange(n_sensors),
                                          arrival_s))
            if i < len(t_s) and ok[i].any():
                chunks.append(self._chunk(data[i:i + 1, ok[i]], t_s[i:i + 1],
                                          np.flatnonzero(ok[i]), arrival_s))
            start = i + 1
        return chunks

    def _chunk(self, data: np.ndarray, t: np.ndarray, sensors: np.ndarray,
               arrival_s: float) -> Chunk:
        d = np.ascontiguousarray(np.swapaxes(data, 0, 1))  # (K, N, 9)
        return Chunk(t_s=t.copy(), sensors=np.asarray(sensors, dtype=np.intp),
                     gyr=d[:, :, 0:3], acc=d[:, :, 3:6],
                     mag=d[:, :, 6:9] if self.info.has_mag else None,
                     arrival_s=np.full(t.size, arrival_s))

    def close(self) -> None:
        """Unsubscribe (the stream's sender is not affected)."""
        if self._opened and not self.finished:
            self._inlet.close_stream()
        super().close()


def imu_stream_info(name: str, sensor_names: list[str], rate_hz: float = 0.0,
                    with_mag: bool = True, source_id: str = "") -> Any:
    """A :class:`pylsl.StreamInfo` in this module's layout (for senders and tests)."""
    pylsl = _pylsl()
    axes = _AXES if with_mag else _AXES[:6]
    info = pylsl.StreamInfo(name, "MARG" if with_mag else "IMU",
                            len(sensor_names) * len(axes), rate_hz, pylsl.cf_double64,
                            source_id or name)
    channels = info.desc().append_child("channels")
    for s in sensor_names:
        for axis in axes:
            ch = channels.append_child("channel")
            ch.append_child_value("label", f"{s}/{axis}")
            ch.append_child_value("unit", "rad/s" if axis[0] == "g" else
                                  "m/s^2" if axis[0] == "a" else "uT")
    return info
