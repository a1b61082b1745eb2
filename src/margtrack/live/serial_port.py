"""Serial source: text lines (:mod:`margtrack.live.lines`) from a serial port, via pyserial.

The port is anything ``serial.serial_for_url`` opens: a device (``/dev/ttyUSB0``,
``COM3``), a pseudo-terminal, or pyserial's URLs (``loop://`` echoes what is written,
``socket://host:port``). pyserial is imported only when a serial source is built.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from margtrack.live.lines import LineDecoder
from margtrack.live.protocol import BaseSource, Chunk, SourceInfo

__all__ = ["SerialSource"]

_MAX_READ = 1 << 16


def _serial_module() -> Any:
    try:
        import serial
    except ImportError:
        raise ImportError(
            "the serial source needs pyserial: pip install pyserial (or margtrack[live])"
        ) from None
    return serial


class SerialSource(BaseSource):
    """Samples read as text lines from a serial port; finishes when the port closes.

    Parameters
    ----------
    port : device path or pyserial URL (``"loop://"`` for a self-test).
    sensor_names : the sensors the lines address by index or name.
    baudrate : line speed, baud (ignored by pseudo-terminals and ``loop://``).
    with_mag : whether lines carry the magnetometer (11 fields) or not (8).
    rate_hz : the device's nominal rate, Hz, if known.
    time_unit : unit of the lines' timestamps, "s" (the format's), "ms", "us" or "ns".
    """

    def __init__(
        self,
        port: str,
        sensor_names: Sequence[str],
        baudrate: int = 115200,
        with_mag: bool = True,
        rate_hz: float | None = None,
        time_unit: str = "s",
    ) -> None:
        names = tuple(str(n) for n in sensor_names)
        if not names:
            raise ValueError("sensor_names must name at least one sensor")
        if int(baudrate) <= 0:
            raise ValueError(f"baudrate must be > 0, got {baudrate}")
        super().__init__(SourceInfo(names, rate_hz, with_mag, f"serial {port}"))
        self._port_name = str(port)
        self._baudrate = int(baudrate)
        self._decoder = LineDecoder(names, with_mag, self._stats, time_unit)
        self._port: Any = None

    @property
    def port(self) -> Any:
        """The open ``serial.Serial`` (after :meth:`open`), e.g. to write to ``loop://``."""
        if self._port is None:
            raise ValueError("the serial source is not open; call open() first")
        return self._port

    def open(self) -> None:
        """Open the port (idempotent)."""
        if self._port is not None:
            return
        serial = _serial_module()
        self._port = serial.serial_for_url(self._port_name, baudrate=self._baudrate, timeout=0)
        super().open()

    def poll(self, timeout_s: float) -> list[Chunk]:
        """Lines received so far; waits up to ``timeout_s`` s for the first bytes."""
        if self._port is None and not self.finished:
            self.open()
        port = self._port
        if port is None:
            return []
        serial = _serial_module()
        try:
            port.timeout = max(timeout_s, 0.0)
            data = port.read(1)
            if data:
                port.timeout = 0
                waiting = port.in_waiting
                if waiting:
                    data += port.read(min(waiting, _MAX_READ))
        except (serial.SerialException, OSError) as exc:
            self._stats.reject(f"serial port {self._port_name} failed: {exc}")
            self.close()
            return []
        if not data:
            return []
        return self._decoder.feed(data, time.perf_counter())

    def close(self) -> None:
        """Close the port."""
        if self._port is not None:
            self._port.close()
            self._port = None
        super().close()
