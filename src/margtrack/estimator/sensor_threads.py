"""Several sensors' series shared among threads, each thread running the serial kernel.

A method's series kernels (``run``, ``run_lanes``) release the GIL (``nogil``), so Python
threads run them at the same time on disjoint slices of the sensors. The sensors are
independent and each gets the same arithmetic as in one call, so the results are the same
to the bit; the shared clock is advanced by every thread on its own copy (the same
timestamps give the same clock). No kernel is compiled for this: a ``parallel=True``
kernel (``numba.prange``) would be a second compilation of the whole method, tens of
seconds each.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["in_threads", "run_threaded", "thread_count"]


def thread_count() -> int:
    """Threads for the sensors: numba's (``NUMBA_NUM_THREADS``, ``numba.set_num_threads``)."""
    import numba

    return int(numba.get_num_threads())


def run_threaded(
    run: Callable[..., Any],
    rows: np.ndarray,
    clock: np.ndarray,
    coefs: np.ndarray,
    t: np.ndarray,
    gyr: np.ndarray,
    acc: np.ndarray,
    mag: np.ndarray,
    has: int,
    q_out: np.ndarray,
    x_out: np.ndarray,
    flags_out: np.ndarray,
    *,
    align: int = 1,
    n_threads: int | None = None,
    frame_major: bool = False,
) -> None:
    """``run(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out)`` over
    S sensors (the first axis of rows, gyr, acc, mag, q_out, x_out, flags_out), split into
    ``n_threads`` contiguous parts (default :func:`thread_count`) whose bounds are multiples
    of ``align`` sensors (a lockstep kernel's block).

    With ``frame_major`` the inputs are (N, S, 3) and ``run`` a frame-major entry
    (``run_lanes_frames``): each part gets them whole and its first sensor as a last
    argument (a slice of their middle axis would be a strided array, another compilation).

    ``clock`` (1,) ends as one call over all the sensors leaves it. A part that raises
    leaves its sensors part-way; the others finish, then the first error is raised.
    """
    n_sensors = rows.shape[0]
    blocks = -(-n_sensors // align)
    n_threads = max(1, min(thread_count() if n_threads is None else n_threads, blocks))
    edges = [min(n_sensors, blocks * k // n_threads * align) for k in range(n_threads + 1)]
    clocks = [clock] if n_threads == 1 else [clock.copy() for _ in range(n_threads)]

    def part(k: int) -> None:
        a, b = edges[k], edges[k + 1]
        if frame_major:
            run(rows[a:b], clocks[k], coefs, t, gyr, acc, mag, has, q_out[a:b], x_out[a:b],
                flags_out[a:b], a)
        else:
            run(rows[a:b], clocks[k], coefs, t, gyr[a:b], acc[a:b], mag[a:b], has, q_out[a:b],
                x_out[a:b], flags_out[a:b])

    if n_threads == 1:
        part(0)
        return

    try:
        in_threads(part, n_threads, "margtrack-sensors")
    finally:
        clock[:] = clocks[0]


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
