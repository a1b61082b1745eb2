"""Who receives the live engine's poses: callbacks and bounded queues, thread-safe.

Callbacks run on the engine's worker thread (keep them short); a callback that raises is
counted and reported, never stops tracking. A queue subscriber drops its oldest pose when
full, so a slow reader never blocks the engine.
"""

from __future__ import annotations

import contextlib
import dataclasses
import queue
import threading
import time
from collections.abc import Callable

from margtrack.live.pose import Pose

__all__ = ["Subscribers"]


class Subscribers:
    """The subscribers of one engine (module docstring)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._callbacks: list[Callable[[Pose], None]] = []

    def subscribe(self, callback: Callable[[Pose], None]) -> Callable[[], None]:
        """Call ``callback(pose)`` for every published pose; returns an unsubscribe function."""
        with self._lock:
            self._callbacks.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._callbacks:
                    self._callbacks.remove(callback)

        return unsubscribe

    def subscribe_queue(self, maxsize: int = 64) -> queue.Queue[Pose]:
        """A queue receiving every published pose; when full, its oldest pose is dropped."""
        q: queue.Queue[Pose] = queue.Queue(maxsize=maxsize)

        def put(pose: Pose) -> None:
            while True:
                try:
                    q.put_nowait(pose)
                    return
                except queue.Full:
                    with contextlib.suppress(queue.Empty):  # emptied meanwhile
                        q.get_nowait()

        self.subscribe(put)
        return q

    def publish(self, pose: Pose) -> tuple[Pose, int, str]:
        """Stamp ``pose`` with the publishing time and give it to every subscriber; returns
        the stamped pose, the number of callbacks that raised and the last error."""
        pose = dataclasses.replace(pose, published_s=time.perf_counter())
        with self._lock:
            callbacks = list(self._callbacks)
        failed, error = 0, ""
        for callback in callbacks:
            try:
                callback(pose)
            except Exception as exc:  # a broken subscriber must not stop tracking
                failed += 1
                error = f"subscriber {callback!r} raised {exc!r}"
        return pose, failed, error
