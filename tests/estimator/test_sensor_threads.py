"""Sensors shared among threads (``estimator/sensor_threads.py``): every sensor once, in
contiguous aligned parts, on several threads, errors raised once all parts ended."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from margtrack.estimator.sensor_threads import run_threaded


@pytest.mark.parametrize(("n_sensors", "n_threads", "align", "sizes"), [
    (5, 3, 1, [1, 2, 2]),  # uneven: the parts differ by one sensor at most
    (5, 2, 1, [2, 3]),
    (70, 2, 32, [32, 38]),  # lockstep blocks: no bound inside a block
    (70, 3, 32, [32, 32, 6]),
    (40, 4, 32, [32, 8]),  # fewer blocks than threads: a thread per block
    (1, 2, 1, [1]),
])
def test_parts_cover_every_sensor_once_on_aligned_bounds(n_sensors, n_threads, align, sizes):
    seen = np.zeros(n_sensors, dtype=int)
    calls: list = []
    barrier = threading.Barrier(len(sizes)) if len(sizes) > 1 else None

    def part(a: int, b: int) -> None:
        if barrier is not None:
            barrier.wait(timeout=10)  # every part runs at the same time, or this times out
        calls.append((threading.get_ident(), a, b))
        seen[a:b] += 1

    run_threaded(part, n_sensors, align=align, n_threads=n_threads)
    assert sorted(b - a for _, a, b in calls) == sorted(sizes)
    bounds = sorted((a, b) for _, a, b in calls)
    assert [a for a, _ in bounds] == list(np.cumsum([0, *sizes])[:-1])  # contiguous
    assert all(a % align == 0 for a, _ in bounds)  # no bound inside a block
    assert len({ident for ident, _, _ in calls}) == len(sizes)  # each part on its own thread
    np.testing.assert_array_equal(seen, 1)  # every sensor exactly once


def test_an_error_in_one_part_is_raised_after_the_others_finish():
    done = np.zeros(6, dtype=int)

    def part(a: int, b: int) -> None:
        if a == 0:
            raise ValueError("sensor 0: broken")
        done[a:b] = 7

    with pytest.raises(ValueError, match="sensor 0: broken"):
        run_threaded(part, 6, n_threads=2)
    np.testing.assert_array_equal(done[3:], 7)  # the other part finished
    np.testing.assert_array_equal(done[:3], 0)
