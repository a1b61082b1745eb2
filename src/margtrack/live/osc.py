"""OSC source: Open Sound Control messages (``python-osc``) on a local UDP port.

Two address patterns are understood, in messages or bundles (nested bundles too):

- margtrack's own, SI units, one sample of one sensor per message::

      /margtrack/<sensor>/imu  t gx gy gz ax ay az [mx my mz]

  ``<sensor>`` is the sensor's index (``0``) or name (``left_thigh``); ``t`` the sample time,
  s; ``g*`` rad/s, ``a*`` m/s² (specific force, +9.81 up at rest), ``m*`` µT; all arguments
  floats (OSC ``f`` or ``d``; ints are accepted). 7 arguments without magnetometer
  (``with_mag=False``), 10 with. Sensors sampled together share ``t``, as in the line format
  (:mod:`margtrack.live.lines`).
- x-io's NGIMU "sensors" message (an OSC device of x-io's, NGIMU/x-OSC style, sends it to
  a port of your choice; argument order and units as in the NGIMU user manual's "Sensors"
  message and the receivers built on x-io's NgimuReceive)::

      /sensors            gx gy gz ax ay az mx my mz barometer
      /<sensor>/sensors   (the same, for several devices given prefixes)

  gyroscope in °/s, accelerometer in g, magnetometer in µT, barometer in hPa (ignored);
  converted here to rad/s and m/s². The sample time is the enclosing bundle's OSC time tag
  (s since 1970) or, for a message outside a bundle, its arrival time on the
  :func:`time.perf_counter` clock. ``/sensors`` without a prefix is sensor 0 and is only
  accepted by a one-sensor source.

Phone apps differ: ZIG SIM sends ``/<uuid>/gyro`` (rad/s) and ``/<uuid>/accel`` (user
acceleration in g, gravity removed) as separate messages without sample times, which is not
a MARG sample; relay such data as ``/margtrack/<sensor>/imu``.

Bad input never raises: a packet that does not parse, an unknown address or sensor, a wrong
argument count, a string or blob argument and a non-finite value are each *rejected* and
counted (:class:`~margtrack.live.protocol.SourceStats`, the reason names the address). A
sample whose time is not after its sensor's previous one is delivered (a rebooted sensor's
clock restarts; the engine re-synchronises it) and counted in :attr:`OscSource.non_monotonic`.
The socket binds to ``127.0.0.1`` by default (this machine only).
"""

from __future__ import annotations

import math
import select
import socket
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from margtrack.live.protocol import BaseSource, Chunk, SourceInfo

__all__ = ["OscSource", "send_osc"]

_MAX_DATAGRAM = 65535
_MAX_DATAGRAMS_PER_POLL = 10000
_G_M_S2 = 9.80665
_DEG = math.pi / 180.0


class OscSource(BaseSource):
    """Samples received as OSC messages on ``host:port``; never finishes by itself.

    Parameters
    ----------
    sensor_names : the sensors the senders address by index or name.
    port : UDP port; 0 picks a free one (read it from :attr:`address` after :meth:`open`).
    host : address to bind, default ``"127.0.0.1"``.
    with_mag : whether samples carry the magnetometer.
    rate_hz : the senders' nominal rate, Hz, if known.
    """

    def __init__(self, sensor_names: Sequence[str], port: int = 0, host: str = "127.0.0.1",
                 with_mag: bool = True, rate_hz: float | None = None) -> None:
        names = tuple(str(n) for n in sensor_names)
        if not names:
            raise ValueError("sensor_names must name at least one sensor")
        if not 0 <= int(port) <= 65535:
            raise ValueError(f"port must be in 0..65535, got {port}")
        super().__init__(SourceInfo(names, rate_hz, with_mag, f"OSC {host}:{port}"))
        self._host, self._port = host, int(port)
        self._sock: socket.socket | None = None
        self._last_t = np.full(len(names), -math.inf)
        #: samples whose time was not after their sensor's previous sample (delivered)
        self.non_monotonic = 0

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` actually bound (after :meth:`open`)."""
        if self._sock is None:
            raise ValueError("the OSC source is not open; call open() first")
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    def open(self) -> None:
        """Bind the socket (idempotent)."""
        if self._sock is not None:
            return
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        sock.bind((self._host, self._port))
        sock.setblocking(False)
        self._sock = sock
        super().open()

    def poll(self, timeout_s: float) -> list[Chunk]:
        """Every sample received so far; waits up to ``timeout_s`` s for the first packet."""
        if self._sock is None and not self.finished:
            self.open()
        sock = self._sock
        if sock is None:
            return []
        ready, _, _ = select.select([sock], [], [], max(timeout_s, 0.0))
        if not ready:
            return []
        chunks: list[Chunk] = []
        for _ in range(_MAX_DATAGRAMS_PER_POLL):
            try:
                data = sock.recv(_MAX_DATAGRAM)
            except BlockingIOError:
                break
            chunks.extend(self.decode(data, time.perf_counter()))
        return chunks

    def close(self) -> None:
        """Close the socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        super().close()

    # -- decoding ---------------------------------------------------------------------------
    def decode(self, data: bytes, arrival_s: float) -> list[Chunk]:
        """Chunks of one datagram (a message or a bundle); rejections are counted."""
        from pythonosc.osc_bundle import OscBundle
        from pythonosc.osc_message import OscMessage

        try:
            if OscBundle.dgram_is_bundle(data):
                items = _flatten(OscBundle(data))
            elif OscMessage.dgram_is_message(data):
                items = [(None, OscMessage(data))]
            else:
                raise ValueError("neither an OSC message nor a bundle")
        except Exception as exc:  # python-osc raises several ParseError types
            self._stats.reject(f"OSC packet of {len(data)} bytes does not parse: {exc}")
            return []
        chunks = []
        for tag, message in items:
            try:
                chunk = self._sample(message.address, list(message.params), tag, arrival_s)
            except ValueError as exc:
                self._stats.reject(str(exc))
                continue
            chunks.append(chunk)
        return chunks

    def _sensor(self, key: str, address: str) -> int:
        if key.isdigit():
            s = int(key)
            if s >= self.info.n_sensors:
                raise ValueError(f"{address}: sensor index {s} out of range "
                                 f"0..{self.info.n_sensors - 1}")
            return s
        if key in self.info.sensor_names:
            return self.info.sensor_names.index(key)
        raise ValueError(f"{address}: unknown sensor {key!r} (known: "
                         f"{', '.join(self.info.sensor_names)})")

    def _sample(self, address: str, args: list[Any], tag: float | None, arrival_s: float
                ) -> Chunk:
        parts = address.strip("/").split("/")
        with_mag = self.info.has_mag
        if len(parts) == 3 and parts[0] == "margtrack" and parts[2] == "imu":
            s = self._sensor(parts[1], address)
            values = _floats(address, args, 10 if with_mag else 7,
                             "t gx gy gz ax ay az" + (" mx my mz" if with_mag else ""))
            t, gyr, acc = values[0], values[1:4], values[4:7]
            mag = values[7:10] if with_mag else None
        elif parts[-1] == "sensors" and len(parts) <= 2:
            if len(parts) == 1 and self.info.n_sensors != 1:
                raise ValueError(f"{address}: without a /<sensor> prefix only a one-sensor "
                                 "source can tell whose sample it is")
            s = 0 if len(parts) == 1 else self._sensor(parts[0], address)
            values = _floats(address, args, 10, "gx gy gz ax ay az mx my mz barometer")
            t = tag if tag is not None else arrival_s
            gyr, acc = values[0:3] * _DEG, values[3:6] * _G_M_S2
            mag = values[6:9] if with_mag else None
        else:
            raise ValueError(f"{address}: unknown OSC address; send /margtrack/<sensor>/imu "
                             "or /<sensor>/sensors")
        if t <= self._last_t[s]:
            self.non_monotonic += 1
            self._stats.last_error = (f"{address}: time {t!r} s is not after the sensor's "
                                      f"previous {self._last_t[s]!r} s")
        self._last_t[s] = t
        self._stats.samples += 1
        return Chunk(t_s=np.array([float(t)]), sensors=np.array([s], dtype=np.intp),
                     gyr=np.asarray(gyr, dtype=np.float64).reshape(1, 1, 3),
                     acc=np.asarray(acc, dtype=np.float64).reshape(1, 1, 3),
                     mag=None if mag is None else np.asarray(mag, np.float64).reshape(1, 1, 3),
                     arrival_s=np.array([arrival_s]))


def _flatten(bundle: Any) -> list[tuple[float | None, Any]]:
    """(time tag or None for "immediately", message) of every message in nested bundles."""
    from pythonosc.osc_bundle import OscBundle
    from pythonosc.parsing import osc_types

    tag = None if bundle.timestamp == osc_types.IMMEDIATELY else float(bundle.timestamp)
    out: list[tuple[float | None, Any]] = []
    for content in bundle:
        if isinstance(content, OscBundle):
            out.extend(_flatten(content))
        else:
            out.append((tag, content))
    return out


def _floats(address: str, args: list[Any], count: int, names: str) -> np.ndarray:
    if len(args) != count:
        raise ValueError(f"{address}: expected {count} arguments ({names}), got {len(args)}")
    for i, a in enumerate(args):
        if isinstance(a, bool) or not isinstance(a, (int, float)):
            raise ValueError(f"{address}: argument {i + 1} ({names.split()[i]}) is "
                             f"{type(a).__name__} {a!r}, not a number")
    values = np.array(args, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        i = int(np.flatnonzero(~np.isfinite(values))[0])
        raise ValueError(f"{address}: argument {i + 1} ({names.split()[i]}) is not finite "
                         f"({values[i]})")
    return values


def send_osc(address: tuple[str, int], sensor: int | str, t_s: float, gyr: Sequence[float],
             acc: Sequence[float], mag: Sequence[float] | None = None) -> None:
    """Send one ``/margtrack/<sensor>/imu`` message with double-precision (``d``) arguments
    (a minimal sender for scripts and tests; python-osc's default ``f`` is float32)."""
    from pythonosc.osc_message_builder import OscMessageBuilder
    from pythonosc.udp_client import SimpleUDPClient

    builder = OscMessageBuilder(address=f"/margtrack/{sensor}/imu")
    for v in [t_s, *gyr, *acc, *(mag if mag is not None else ())]:
        builder.add_arg(float(v), OscMessageBuilder.ARG_TYPE_DOUBLE)
    SimpleUDPClient(*address).send(builder.build())
