"""Sensors shared among threads (``estimator/sensor_threads.py``): every sensor once, in
contiguous aligned parts, on several threads, with the clock and errors as one call."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from margtrack.estimator.sensor_threads import run_threaded


def _arrays(n_sensors: int, n: int = 3):
    rows = np.zeros((n_sensors, 2))
    gyr, acc, mag = (np.arange(n_sensors * n * 3, dtype=float).reshape(n_sensors, n, 3) + k
                     for k in range(3))
    outs = np.zeros((n_sensors, n, 4)), np.zeros((n_sensors, n, 1)), np.zeros((n_sensors, n),
                                                                               np.uint16)
    return rows, gyr, acc, mag, outs


def _recording_kernel(calls, barrier=None):
    """A stand-in for a series kernel: notes its sensors and thread, writes its outputs from
    its inputs, advances the clock to the last timestamp."""

    def run(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
        if barrier is not None:
            barrier.wait(timeout=10)  # every part runs at the same time, or this times out
        calls.append((threading.get_ident(), rows.shape[0], gyr[0, 0, 0] if len(gyr) else None))
        rows[:, 0] += 1.0
        q_out[:] = gyr[..., :1] + acc[..., :1] + mag[..., :1] + coefs[0]
        flags_out[:] = has
        clock[0] = t[-1]

    return run


@pytest.mark.parametrize(("n_sensors", "n_threads", "align", "sizes"), [
    (5, 3, 1, [1, 2, 2]),  # uneven: the parts differ by one sensor at most
    (5, 2, 1, [2, 3]),
    (70, 2, 32, [32, 38]),  # lockstep blocks: no bound inside a block
    (70, 3, 32, [32, 32, 6]),
    (40, 4, 32, [32, 8]),  # fewer blocks than threads: a thread per block
    (1, 2, 1, [1]),
])
def test_parts_cover_every_sensor_once_on_aligned_bounds(n_sensors, n_threads, align, sizes):
    rows, gyr, acc, mag, (q, x, f) = _arrays(n_sensors)
    calls: list = []
    barrier = threading.Barrier(len(sizes)) if len(sizes) > 1 else None
    clock = np.array([np.nan])
    run_threaded(_recording_kernel(calls, barrier), rows, clock, np.array([0.5]),
                 np.array([0.0, 0.01, 0.02]), gyr, acc, mag, 3, q, x, f, align=align,
                 n_threads=n_threads)
    assert sorted(size for _, size, _ in calls) == sorted(sizes)
    firsts = sorted(first for _, _, first in calls)
    np.testing.assert_array_equal(firsts, gyr[np.cumsum([0, *sizes])[:-1], 0, 0])  # contiguous
    assert len({ident for ident, _, _ in calls}) == len(sizes)  # each part on its own thread
    np.testing.assert_array_equal(rows[:, 0], 1.0)  # every sensor exactly once
    np.testing.assert_array_equal(q[..., 0], gyr[..., 0] + acc[..., 0] + mag[..., 0] + 0.5)
    np.testing.assert_array_equal(f, 3)
    assert clock[0] == 0.02


def test_an_error_in_one_part_is_raised_after_the_others_finish():
    rows, gyr, acc, mag, (q, x, f) = _arrays(6)

    def run(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
        if gyr[0, 0, 0] == 0.0:  # the first part
            raise ValueError("sensor 0: broken")
        flags_out[:] = 7

    with pytest.raises(ValueError, match="sensor 0: broken"):
        run_threaded(run, rows, np.array([0.0]), np.zeros(1), np.zeros(3), gyr, acc, mag, 1, q,
                     x, f, n_threads=2)
    np.testing.assert_array_equal(f[3:], 7)  # the other part finished
    np.testing.assert_array_equal(f[:3], 0)
