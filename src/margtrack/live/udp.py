"""UDP source: datagrams of text lines (:mod:`margtrack.live.lines`) on a local port.

Bind to ``127.0.0.1`` (default) and send lines such as
``12.34,0,0.01,0,0,0,0,9.81,0,21.7,-43.3`` to that port; several lines per datagram are
allowed. :func:`send_lines` is a minimal sender for scripts and tests.

A reader thread drains the socket as fast as datagrams come (into memory, stamped with
their arrival time) and asks for a large receive buffer (``SO_RCVBUF``, 8 MiB; the system
may grant less: :attr:`UdpSource.receive_buffer_bytes`), so a burst is not lost while the
engine is busy; :meth:`UdpSource.poll` decodes what the thread collected. Datagrams the
system still drops show as gaps of the lines' sequence numbers (or timestamps), counted
as lost per sensor by the engine.
"""

from __future__ import annotations

import select
import socket
import threading
import time
from collections import deque
from collections.abc import Iterable, Sequence

from margtrack.live.lines import LineDecoder
from margtrack.live.protocol import BaseSource, Chunk, SourceInfo

__all__ = ["UdpSource", "send_lines"]

_MAX_DATAGRAM = 65535
_MAX_DATAGRAMS_PER_POLL = 2000  # bounds the time one poll spends decoding
_YIELD_TO_READER_S = 0.02  # longest wait of a poll for the reader to drain the socket
_RECEIVE_BUFFER_BYTES = 8 * 1024 * 1024


class UdpSource(BaseSource):
    """Samples received as UDP datagrams on ``host:port``; never finishes by itself.

    Parameters
    ----------
    sensor_names : the sensors the senders address by index or name.
    port : UDP port; 0 picks a free one (read it from :attr:`address` after :meth:`open`).
    host : address to bind, default ``"127.0.0.1"`` (this machine only).
    with_mag : whether lines carry the magnetometer (11 fields) or not (8).
    rate_hz : the senders' nominal rate, Hz, if known (shown in the viewer).
    time_unit : unit of the lines' timestamps, "s" (the format's), "ms", "us" or "ns".
    """

    def __init__(
        self,
        sensor_names: Sequence[str],
        port: int = 0,
        host: str = "127.0.0.1",
        with_mag: bool = True,
        rate_hz: float | None = None,
        time_unit: str = "s",
    ) -> None:
        names = tuple(str(n) for n in sensor_names)
        if not names:
            raise ValueError("sensor_names must name at least one sensor")
        if not 0 <= int(port) <= 65535:
            raise ValueError(f"port must be in 0..65535, got {port}")
        super().__init__(SourceInfo(names, rate_hz, with_mag, f"UDP {host}:{port}"))
        self._host, self._port = host, int(port)
        self._decoder = LineDecoder(names, with_mag, self._stats, time_unit)
        self._sock: socket.socket | None = None
        self._inbox: deque[tuple[bytes, float]] = deque()
        self._ready = threading.Event()
        self._idle = threading.Event()  # set while the reader waits for the socket
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None
        #: receive buffer the system granted, bytes (after :meth:`open`)
        self.receive_buffer_bytes = 0
        #: datagrams the reader thread took off the socket
        self.datagrams = 0

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
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _RECEIVE_BUFFER_BYTES)
        sock.bind((self._host, self._port))
        sock.setblocking(False)
        self.receive_buffer_bytes = int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
        self._sock = sock
        self._stop.clear()
        self._reader = threading.Thread(target=self._read, args=(sock,),
                                        name="margtrack-live-udp-reader", daemon=True)
        self._reader.start()
        super().open()

    def _read(self, sock: socket.socket) -> None:
        """Reader thread: move datagrams from the socket to the inbox until closed."""
        inbox, ready, idle = self._inbox, self._ready, self._idle
        try:
            while not self._stop.is_set():
                idle.set()
                try:
                    readable, _, _ = select.select([sock], [], [], 0.05)
                except (OSError, ValueError):  # closed under us
                    return
                if not readable:
                    continue
                idle.clear()
                n = 0
                while True:
                    try:
                        data = sock.recv(_MAX_DATAGRAM)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:
                        return
                    inbox.append((data, time.perf_counter()))
                    self.datagrams += 1
                    n += 1
                    if n % 256 == 0:
                        ready.set()
                ready.set()
        finally:
            idle.set()

    def poll(self, timeout_s: float) -> list[Chunk]:
        """Every line received so far; waits up to ``timeout_s`` s for the first datagram."""
        if self._sock is None and not self.finished:
            self.open()
        if self._sock is None:
            return []
        if not self._inbox:
            self._ready.wait(max(timeout_s, 0.0))
        elif not self._idle.is_set():
            # a backlog while the reader is draining the socket: let it finish first (this
            # thread waits without the GIL, so the reader is not starved; the system's
            # receive buffer would overflow otherwise)
            self._idle.wait(_YIELD_TO_READER_S)
        self._ready.clear()
        chunks: list[Chunk] = []
        inbox = self._inbox
        for _ in range(_MAX_DATAGRAMS_PER_POLL):
            try:
                data, arrival = inbox.popleft()
            except IndexError:
                break
            chunks.extend(self._decoder.feed(data, arrival, final=True))
        if inbox:
            self._ready.set()  # more to decode: the next poll does not wait
        return chunks

    def close(self) -> None:
        """Stop the reader thread and close the socket."""
        self._stop.set()
        if self._reader is not None:
            self._reader.join(2.0)
            self._reader = None
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
