"""UDP source: datagrams of text lines (:mod:`margtrack.live.lines`) on a local port.

Bind to ``127.0.0.1`` (default) and send lines such as
``12.34,0,0.01,0,0,0,0,9.81,0,21.7,-43.3`` to that port; several lines per datagram are
allowed. :func:`send_lines` is a minimal sender for scripts and tests.
"""

from __future__ import annotations

import select
import socket
import time
from collections.abc import Iterable, Sequence

from margtrack.live.lines import LineDecoder
from margtrack.live.protocol import BaseSource, Chunk, SourceInfo

__all__ = ["UdpSource", "send_lines"]

_MAX_DATAGRAM = 65535
_MAX_DATAGRAMS_PER_POLL = 10000  # bounds the time one poll spends draining the socket


class UdpSource(BaseSource):
    """Samples received as UDP datagrams on ``host:port``; never finishes by itself.

    Parameters
    ----------
    sensor_names : the sensors the senders address by index or name.
    port : UDP port; 0 picks a free one (read it from :attr:`address` after :meth:`open`).
    host : address to bind, default ``"127.0.0.1"`` (this machine only).
    with_mag : whether lines carry the magnetometer (11 fields) or not (8).
    rate_hz : the senders' nominal rate, Hz, if known (shown in the viewer).
    """

    def __init__(
        self,
        sensor_names: Sequence[str],
        port: int = 0,
        host: str = "127.0.0.1",
        with_mag: bool = True,
        rate_hz: float | None = None,
    ) -> None:
        names = tuple(str(n) for n in sensor_names)
        if not names:
            raise ValueError("sensor_names must name at least one sensor")
        if not 0 <= int(port) <= 65535:
            raise ValueError(f"port must be in 0..65535, got {port}")
        super().__init__(SourceInfo(names, rate_hz, with_mag, f"UDP {host}:{port}"))
        self._host, self._port = host, int(port)
        self._decoder = LineDecoder(names, with_mag, self._stats)
        self._sock: socket.socket | None = None

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` actually bound (after :meth:`open`)."""
        if self._sock is None:
            raise ValueError("the UDP source is not open; call open() first")
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
        """Every line received so far; waits up to ``timeout_s`` s for the first datagram."""
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
            chunks.extend(self._decoder.feed(data, time.perf_counter(), final=True))
        return chunks

    def close(self) -> None:
        """Close the socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        super().close()


def send_lines(lines: Iterable[str], address: tuple[str, int], per_datagram: int = 1) -> int:
    """Send text lines to ``address`` over UDP, ``per_datagram`` lines per datagram.

    Returns the number of datagrams sent.
    """
    if per_datagram < 1:
        raise ValueError(f"per_datagram must be >= 1, got {per_datagram}")
    sent = 0
    batch: list[str] = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for line in lines:
            batch.append(line if line.endswith("\n") else line + "\n")
            if len(batch) == per_datagram:
                sock.sendto("".join(batch).encode(), address)
                sent += 1
                batch = []
        if batch:
            sock.sendto("".join(batch).encode(), address)
            sent += 1
    return sent
