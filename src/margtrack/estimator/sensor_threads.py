"""Several sensors' series shared among threads, each thread running the serial kernel.

A method's series kernels (``run``, ``lanes``) release the GIL (``nogil``), so Python
threads run them at the same time on disjoint slices of the sensors. The sensors are
independent and each gets the same arithmetic as in one call, so the results are the same
to the bit; each part reads a copy of the shared clock (the same timestamps give the same
clock), or the lockstep blocks its values read once before (``skeleton.clock_series``).
No kernel is compiled for this: a ``parallel=True`` kernel (``numba.prange``) would be a
second compilation of the whole method.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

__all__ = ["in_threads", "run_threaded", "thread_count"]


def thread_count() -> int:
    """Threads for the sensors: numba's (``NUMBA_NUM_THREADS``, ``numba.set_num_threads``)."""
    import numba

    return int(numba.get_num_threads())


def run_threaded(
    part: Callable[[int, int], None],
    n_sensors: int,
    *,
    align: int = 1,
    n_threads: int | None = None,
) -> None:
    """``part(a, b)`` for sensors a .. b of ``n_sensors``, split into ``n_threads``
    contiguous parts (default :func:`thread_count`) whose bounds are multiples of ``align``
    sensors (a lockstep kernel's block), run at the same time (:func:`in_threads`).

    A part that raises leaves its sensors part-way; the others finish, then the first error
    is raised.
    """
    blocks = -(-n_sensors // align)
    n_threads = max(1, min(thread_count() if n_threads is None else n_threads, blocks))
    edges = [min(n_sensors, blocks * k // n_threads * align) for k in range(n_threads + 1)]
    if n_threads == 1:
        part(0, n_sensors)
        return
    in_threads(lambda k: part(edges[k], edges[k + 1]), n_threads, "margtrack-sensors")


def in_threads(part: Callable[[int], None], n_threads: int, name: str) -> None:
    """``part(k)`` for k = 0 .. n_threads - 1 at the same time: part 0 in the caller's
    thread, the others in threads named ``name-k``. A part that raises does not stop the
    others; once all have ended, the first error is raised."""
    errors: list[BaseException | None] = [None] * n_threads

    def guarded(k: int) -> None:
        try:
            part(k)
        except BaseException as exc:  # raised in the caller's thread below
            errors[k] = exc

    threads = [threading.Thread(target=guarded, args=(k,), name=f"{name}-{k}", daemon=True)
               for k in range(1, n_threads)]
    for thread in threads:
        thread.start()
    guarded(0)
    for thread in threads:
        thread.join()
    for exc in errors:
        if exc is not None:
            raise exc
