"""The text line format of the UDP and serial sources, and its decoder.

One sample of one sensor per line, comma separated, SI units, ``.`` as decimal point::

    t,sensor,gx,gy,gz,ax,ay,az,mx,my,mz

- ``t``: sample time, s (float; a source built with ``time_unit="ms"``, ``"us"`` or ``"ns"``
  takes it in that unit: ``margtrack live --time-unit ms``). Sensors sampled together share
  the same ``t``: the engine
  puts a frame together from the samples of all sensors with equal ``t``
  (:class:`~margtrack.live.assembler.FrameAssembler`; its ``tick_hz`` rounds the times of
  sensors on unsynchronised clocks onto one grid);
- ``sensor``: the sensor's index 0..S-1, or its name as listed by the source;
- ``gx,gy,gz``: angular rate, rad/s; ``ax,ay,az``: specific force, m/s² (about +9.81 up
  at rest); ``mx,my,mz``: magnetic field, µT (any unit: only directions and relative norms
  are used). A source built with ``with_mag=False`` takes 8 fields (no ``mx,my,mz``).

An optional last field ``seq`` (``t,sensor,gx,...,mz,seq``: 12 fields, 9 without the
magnetometer) is the sender's per-sensor sequence number, a non-negative integer that grows
by 1 with every sample the sensor sends: the engine counts lost samples from its gaps (a
datagram dropped by the network or by a full receive buffer) exactly; a smaller number
than the previous one means the sender restarted (counted as no loss). Without it, losses
are estimated from timestamp gaps.

Timestamps in ms (µs, ns) sent as s are refused: when a sensor's first lines advance by a
second or more each while its gyroscope turns, decoding raises
:class:`~margtrack.units.UnitError` naming the ``time_unit`` to declare (the engine stops
with it: a stream in the wrong unit is not a corrupt packet but a setting to fix).

Empty lines and lines starting with ``#`` are ignored. A line with another field count, a
number that does not parse or is not finite, or an unknown sensor is *rejected*: counted in
the source's :class:`~margtrack.live.protocol.SourceStats` with the reason (line text
included), never raised, so one corrupt packet does not stop a live session. Lines end with
``\\n`` (``\\r\\n`` accepted); a UDP datagram may hold several lines.

Example, sensor 2 at rest in ENU facing north: ``12.34,2,0,0,0,0,0,9.81,0,21.7,-43.3``;
the same as its 1235th sample with a sequence number: ``12.34,2,0,0,0,0,0,9.81,0,21.7,-43.3,1234``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from margtrack.live.protocol import Chunk, SourceStats
from margtrack.units import IntervalProbe, UnitError, unit_factor

__all__ = ["LineDecoder", "format_line", "parse_line", "parse_line_seq"]

_MAX_LINE_CHARS = 1024  # longer than any valid line; a stream without newlines is rejected


def format_line(t_s: float, sensor: int | str, gyr: Sequence[float], acc: Sequence[float],
                mag: Sequence[float] | None = None, seq: int | None = None) -> str:
    """One line of the format (with ``\\n``), ``repr`` precision so values round-trip exactly.

    ``seq``: the optional per-sensor sequence number (appended as the last field).
    """
    values = [*gyr, *acc, *(mag if mag is not None else ())]
    fields = [repr(float(t_s)), str(sensor), *(repr(float(v)) for v in values)]
    if seq is not None:
        if int(seq) < 0:
            raise ValueError(f"seq must be a non-negative integer, got {seq}")
        fields.append(str(int(seq)))
    return ",".join(fields) + "\n"


def parse_line(
    line: str, sensor_names: Sequence[str], with_mag: bool = True
) -> tuple[float, int, np.ndarray, np.ndarray, np.ndarray | None]:
    """Parse one line into ``(t_s, sensor_index, gyr (3,), acc (3,), mag (3,) or None)``.

    Raises ``ValueError`` saying what is wrong with the line; :class:`LineDecoder` turns it
    into a rejection count. An optional sequence number is checked and dropped
    (:func:`parse_line_seq` returns it).
    """
    return parse_line_seq(line, sensor_names, with_mag)[:5]  # type: ignore[return-value]


def parse_line_seq(
    line: str, sensor_names: Sequence[str], with_mag: bool = True
) -> tuple[float, int, np.ndarray, np.ndarray, np.ndarray | None, int | None]:
    """:func:`parse_line` plus the optional sequence number (``None`` when absent)."""
    fields = line.strip().split(",")
    expected = 11 if with_mag else 8
    seq = None
    if len(fields) == expected + 1:
        text = fields.pop().strip()
        if not text.isdigit():
            raise ValueError(
                f"the sequence number (last field) must be a non-negative integer, got "
                f"{text[:20]!r}: {line.strip()[:80]!r}"
            )
        seq = int(text)
    if len(fields) != expected:
        raise ValueError(
            f"expected {expected} comma-separated fields (t,sensor,gx,gy,gz,ax,ay,az"
            f"{',mx,my,mz' if with_mag else ''}[,seq]), got {len(fields)}: "
            f"{line.strip()[:80]!r}"
        )
    key = fields[1].strip()
    if key.isdigit():
        sensor = int(key)
        if sensor >= len(sensor_names):
            raise ValueError(
                f"sensor index {sensor} out of range 0..{len(sensor_names) - 1}: "
                f"{line.strip()[:80]!r}"
            )
    elif key in sensor_names:
        sensor = sensor_names.index(key)
    else:
        raise ValueError(f"unknown sensor {key!r}: {line.strip()[:80]!r}")
    try:
        values = [float(f) for f in (fields[0], *fields[2:])]
    except ValueError:
        raise ValueError(f"a field is not a number: {line.strip()[:80]!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"a field is not finite (nan or inf): {line.strip()[:80]!r}")
    arr = np.array(values[1:])
    return values[0], sensor, arr[0:3], arr[3:6], arr[6:9] if with_mag else None, seq


class LineDecoder:
    """Bytes in, :class:`Chunk` objects (one per valid line) out; keeps a partial last line.

    Parameters
    ----------
    sensor_names : the source's sensors (index = position).
    with_mag : whether lines carry ``mx,my,mz``.
    stats : where rejections and delivered samples are counted.
    time_unit : the unit of the lines' ``t``: "s" (the format's), "ms", "us" or "ns".
    """

    def __init__(self, sensor_names: Sequence[str], with_mag: bool, stats: SourceStats,
                 time_unit: str = "s") -> None:
        self.sensor_names = list(sensor_names)
        self.with_mag = with_mag
        self.stats = stats
        self.time_factor = unit_factor("time", time_unit)
        self._partial = b""
        #: per sensor, the check of its first lines' intervals (None once all are judged)
        self._probes: list[IntervalProbe] | None = [
            IntervalProbe(_time_fix, "line") for _ in self.sensor_names
        ]

    def feed(self, data: bytes, arrival_s: float | None = None, final: bool = False) -> list[Chunk]:
        """Decode ``data``; complete lines become chunks, a trailing partial line is kept.

        ``final=True`` (a UDP datagram) decodes the trailing line too. ``arrival_s`` is the
        perf_counter time the bytes were received (now if omitted).
        """
        arrival = time.perf_counter() if arrival_s is None else arrival_s
        buffer = self._partial + data
        lines = buffer.split(b"\n")
        self._partial = b"" if final else lines.pop()
        if len(self._partial) > _MAX_LINE_CHARS:
            self.stats.reject(f"line longer than {_MAX_LINE_CHARS} characters without newline")
            self._partial = b""
        chunks = []
        for raw in lines:
            text = raw.decode("utf-8", errors="replace").strip()
            if not text or text.startswith("#"):
                continue
            try:
                t, sensor, gyr, acc, mag, seq = parse_line_seq(
                    text, self.sensor_names, self.with_mag)
            except ValueError as exc:
                self.stats.reject(str(exc))
                continue
            if self.time_factor != 1.0:
                t *= self.time_factor
            if self._probes is not None:
                self._probe(sensor, t, gyr)
            chunks.append(
                Chunk(
                    t_s=np.array([t]),
                    sensors=np.array([sensor], dtype=np.intp),
                    gyr=gyr.reshape(1, 1, 3),
                    acc=acc.reshape(1, 1, 3),
                    mag=None if mag is None else mag.reshape(1, 1, 3),
                    arrival_s=np.array([arrival]),
                    seq=None if seq is None else np.array([seq], dtype=np.int64),
                )
            )
            self.stats.samples += 1
        return chunks

    def _probe(self, sensor: int, t: float, gyr: np.ndarray) -> None:
        """Feed sensor ``sensor``'s line to its interval check (raises UnitError)."""
        assert self._probes is not None
        try:
            self._probes[sensor].add(t, math.sqrt(float(gyr @ gyr)))
        except UnitError as exc:
            raise exc.prefixed(f"sensor {self.sensor_names[sensor]}: ") from None
        if all(p.done for p in self._probes):
            self._probes = None


def _time_fix(signal: str, unit: str) -> str:
    return (f"declare the senders' unit (margtrack live --time-unit {unit}; "
            f"time_unit={unit!r} for the source)")
