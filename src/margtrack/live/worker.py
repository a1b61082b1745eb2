"""The live engine's worker thread: poll the source, push what arrived, end cleanly.

One worker per engine runs every filter call (nothing else does). It opens the source,
polls it (``poll_timeout_s`` at a time, so a stop request is seen within that) and pushes
the chunks; when the source is exhausted it flushes the frames still waiting for samples
and ends. Asked to stop, it first processes what the source already holds (up to 0.25 s
of work) and the waiting frames, so they are counted. An exception (the engine's bug or a
broken source) ends the worker with a message instead of escaping the thread. In every
case the source is closed and ``finish(message or None)`` runs last on the worker thread.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from margtrack.live.protocol import Chunk, Source

__all__ = ["Worker"]


class Worker:
    """A worker thread around ``push(chunks, flush=...)`` (module docstring).

    ``finish(fatal)`` is called when the thread ends: ``fatal`` says why if it stopped on
    its own (an exception), else None.
    """

    def __init__(self, push: Callable[..., Any], finish: Callable[[str | None], None]) -> None:
        self._push = push
        self._finish = finish
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._done = threading.Event()

    @property
    def started(self) -> bool:
        """Whether :meth:`start` ran."""
        return self._thread is not None

    def start(self, source: Source, poll_timeout_s: float) -> None:
        """Run on ``source`` in a new daemon thread (opened there, closed at the end)."""
        self._thread = threading.Thread(target=self._run, args=(source, poll_timeout_s),
                                        name="margtrack-live-engine", daemon=True)
        self._thread.start()

    def _run(self, source: Source, poll_timeout_s: float) -> None:
        fatal: str | None = None
        try:
            source.open()
            while not self._stop.is_set():
                chunks: Sequence[Chunk] = source.poll(poll_timeout_s)
                end = source.finished and not chunks
                self._push(chunks, flush=end)
                if end:
                    break
            else:  # stopped: what the source already holds (up to 0.25 s of work) and the
                # frames still waiting for samples are processed, so they are counted
                deadline = time.perf_counter() + 0.25
                while time.perf_counter() < deadline:
                    chunks = source.poll(0.0)
                    if not chunks:
                        break
                    self._push(chunks)
                self._push([], flush=True)
        except Exception as exc:  # reported by the engine's error, stats and summary
            fatal = f"engine stopped: {exc!r}"
        finally:
            with contextlib.suppress(Exception):
                source.close()
            try:
                self._finish(fatal)
            finally:
                self._done.set()

    @property
    def running(self) -> bool:
        """Whether the thread is alive."""
        return self._thread is not None and self._thread.is_alive()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until the thread ended (source exhausted or stopped); True if it did."""
        return self._done.wait(timeout_s)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Ask the thread to stop and join it (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise RuntimeError(f"the engine's worker did not stop within {timeout_s} s")
