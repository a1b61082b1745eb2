"""Compile the methods' kernels into numba's cache before they are needed, once per machine.

numba compiles a kernel on its first call in a process that finds no valid entry in its
cache (a fresh install, a new numba, an edited source) and writes the result beside the
kernel's source (``cache=True``); every later process loads it in milliseconds. A method's
kernels take from a few seconds (triad) to about a minute (ekf) to compile, and processes
started together (Dask workers on one machine, a test suite spread over the cores) each
compile the same kernels at the same time. :func:`precompile` compiles them once instead:
each method in one process of a pool, the methods shared among the processes.

A method is compiled by using it the way programs do, on a simulated recording: ``run``
on one sensor (and, for a method with lockstep kernels, ``estimator/lockstep.py``, on
enough sensors for those), and ``update`` sample by sample on one sensor (past the unit
check, so the one-sample kernel too) and on several. Several sensors over threads take
the same kernels (``estimator/sensor_threads.py``). A method's parameters that select other
kernels (its ``compile_variants``: ekf's ``bias_states``) are used the same way. Kernels
called with other argument types (float32 arrays straight into a kernel, say) still compile
on first use.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

import numpy as np

__all__ = ["precompile"]

#: samples of the simulated recording
_SAMPLES = 400
#: a method's name and the parameters it is used with
Unit = tuple[str, dict[str, object]]


def precompile(
    names: Iterable[str] | None = None,
    *,
    jobs: int | None = None,
    progress: Callable[[str, float], None] | None = None,
) -> dict[str, float]:
    """Compile the kernels of the methods ``names`` (default: all) into numba's cache.

    ``jobs`` processes share the methods (default: the machine's CPUs, at most one per
    kernel module; 1 compiles in this process). ``progress(name, seconds)`` is called as
    each method is done. Returns the seconds each method took (its default parameters and its
    ``compile_variants``, which may run in different processes): compilation on a cold cache,
    loading from the cache otherwise (a fraction of a second). Nothing is
    compiled with ``NUMBA_DISABLE_JIT=1`` (the kernels then run as Python): returns {}.
    A method that fails raises its error, after the others have finished.
    """
    from margtrack import methods

    chosen = list(methods.available() if names is None else names)
    for name in chosen:
        methods.get(name)  # an unknown name raises here, before any process starts
    if jobs is None:
        jobs = os.cpu_count() or 1
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0") or not chosen:
        return {}
    # a method and each of its compile_variants is a unit; units on the same kernels
    # (bachmann and bachmann-accmag, robust and smoother) go to one process, one after
    # the other: the second loads what the first compiled
    groups: dict[str, list[Unit]] = {}
    pending = dict.fromkeys(chosen, 0)  # a method's units not finished yet
    for name in chosen:
        for params in ({}, *getattr(methods.get(name), "compile_variants", ())):
            kernel = getattr(methods.create(name, params), "kernel", None)
            groups.setdefault(kernel.__name__ if kernel is not None else name, []).append(
                (name, params))
            pending[name] += 1
    # the longest compilations first (methods with lockstep blocks compile those too), so
    # that no process is left with one of them alone at the end
    tasks = sorted(groups.values(), key=lambda units: not _has_lanes(units[0][0]))
    jobs = min(jobs, len(tasks))
    seconds = dict.fromkeys(chosen, 0.0)
    failures: dict[str, BaseException] = {}

    def finished(units: list[Unit], outcome: list[float] | BaseException) -> None:
        if isinstance(outcome, BaseException):
            failures[units[0][0]] = outcome
            return
        for (name, _), took in zip(units, outcome, strict=True):
            seconds[name] += took
            pending[name] -= 1
            if progress is not None and pending[name] == 0:
                progress(name, seconds[name])

    if jobs == 1:
        for units in tasks:
            finished(units, _compile_group(units))
    else:
        # spawn: a fresh interpreter (forking a process with numba's threads is unsafe)
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
            futures = {pool.submit(_compile_group, units): units for units in tasks}
            for future in as_completed(futures):
                try:
                    outcome: list[float] | BaseException = future.result()
                except Exception as exc:  # reported below, once every method has finished
                    outcome = exc
                finished(futures[future], outcome)
    if failures:
        name, exc = next(iter(failures.items()))
        others = f" (and {', '.join(sorted(failures)[1:])})" if len(failures) > 1 else ""
        raise RuntimeError(f"compiling method {name!r} failed{others}: {exc}") from exc
    return seconds


def _compile_group(units: list[Unit]) -> list[float]:
    """:func:`_compile_unit` for each of ``units`` in turn: the seconds each took."""
    return [_compile_unit(name, params) for name, params in units]


def _compile_method(name: str) -> float:
    """Use method ``name`` as programs do (module docstring), with its default parameters
    and each of its ``compile_variants``; the seconds it took."""
    from margtrack import methods

    variants = ({}, *getattr(methods.get(name), "compile_variants", ()))
    return sum(_compile_unit(name, params) for params in variants)


def _compile_unit(name: str, params: dict[str, object]) -> float:
    """:func:`_use_variant` on a simulated recording; the seconds it took."""
    from margtrack.sim import simulate_motion

    start = time.perf_counter()
    rec = simulate_motion("random", duration_s=_SAMPLES / 100.0, rate_hz=100.0, seed=1)
    _use_variant(name, params, rec.gyr[:_SAMPLES], rec.acc[:_SAMPLES], rec.mag[:_SAMPLES])
    return time.perf_counter() - start


def _has_lanes(name: str) -> bool:
    """Whether the method's kernel has lockstep blocks (``contract.entry_points``)."""
    from margtrack import methods

    return getattr(getattr(methods.get(name), "kernel", None), "lanes", None) is not None


def _use_frames(est: Any, lanes: list[np.ndarray]) -> None:
    """The live engine's call: ``run_into`` on frame-major inputs (the lockstep blocks'
    frame entry, when the method has one)."""
    n_sensors, n = lanes[0].shape[:2]
    if not est.takes_frames(n_sensors):
        return
    frames = [np.ascontiguousarray(np.swapaxes(x, 0, 1)) for x in lanes]
    est.run_into(np.arange(n) / 100.0, *frames, np.empty((n_sensors, n, 4)),
                 np.empty((n_sensors, n, 0)), np.empty((n_sensors, n), dtype=np.uint16),
                 frame_major=True)


def _use_variant(name: str, params: dict[str, object], gyr: np.ndarray, acc: np.ndarray,
                 mag: np.ndarray) -> None:
    """``run`` and ``update`` of method ``name`` with ``params``, as the module says."""
    from margtrack import methods
    from margtrack.estimator.compiled import LANES_MIN_SENSORS

    methods.create(name, params).run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    if _has_lanes(name):
        lanes = [np.tile(x, (LANES_MIN_SENSORS, 1, 1)) for x in (gyr, acc, mag)]
        methods.create(name, params).run(gyr=lanes[0], acc=lanes[1], mag=lanes[2],
                                         rate_hz=100.0)
        _use_frames(methods.create(name, params), lanes)
    many = [np.stack([x, x]) for x in (gyr, acc, mag)]
    if not getattr(methods.get(name), "offline", False):
        one = methods.create(name, params, rate_hz=100.0)
        for i in range(_SAMPLES):
            one.update(gyr[i], acc[i], mag[i])
        several = methods.create(name, params, rate_hz=100.0)
        for i in range(3):
            several.update(many[0][:, i], many[1][:, i], many[2][:, i])
