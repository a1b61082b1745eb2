"""Per-sensor isolation of the live filters: restart, re-initialise or run one sensor alone.

The engine runs the S sensors of a session in one estimator (one compiled call per batch).
A fault of one sensor must stay with that sensor, so these helpers act on the rows of the
estimator's state that belong to one sensor, for both state kinds of the contract
(:class:`~margtrack.estimator.compiled.CompiledState`, ``rows`` (S, R), and the dataclass
:class:`~margtrack.estimator.estimate.State` with per-sensor arrays of first axis S):

- :func:`restart`: the sensor waits for its next usable sample and starts from it, keeping
  what the method knows of it (gyro bias), as after a gap of the input policy;
- :func:`reinitialise`: the sensor's state is replaced by a fresh one (everything
  forgotten, its output held at ``q_hold``) and it restarts at its next usable sample
  (after its filter failed: a non-finite output or an exception);
- :func:`run_each`: the batch run sensor by sensor, a sensor whose run raises is
  re-initialised and its output held; the others go on (after the S-sensor run raised);
- :func:`finish_raised`: the same outcome after the in-place run
  (:meth:`~margtrack.estimator.compiled.CompiledEstimator.run_into`) raised part-way: the
  sensors it finished keep their results, the first one it did not finish is taken for
  the one that raised (the kernel runs the sensors in order; with threads, any other one
  it left part-way too) and re-initialised, the untouched ones run one by one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator import screen_kernel, screening
from margtrack.estimator import skeleton as kc
from margtrack.estimator.compiled import UNRUN, CompiledState
from margtrack.estimator.contract import Estimator
from margtrack.estimator.flags import DATA_FLAGS, Flag

Array = NDArray[np.float64]

__all__ = ["finish_raised", "reinitialise", "restart", "run_each"]


def restart(estimator: Estimator, sensors: Sequence[int]) -> None:
    """Make ``sensors`` restart at their next usable sample (state kept otherwise)."""
    state = estimator.state
    if state is None or not len(sensors):
        return
    rows = np.asarray(sensors, dtype=np.intp)
    if isinstance(state, CompiledState):
        state.rows[rows, kc.K_READY] = 0.0
    else:
        if state.ready is None:
            state.ready = np.ones(state.quat.shape[0], dtype=bool)
        state.ready[rows] = False
    estimator.state = state


def reinitialise(estimator: Estimator, sensor: int, q_hold: Array) -> None:
    """Forget everything of ``sensor`` (output held at ``q_hold`` (4,)) until it restarts."""
    state = estimator.state
    if state is None:
        return
    q = np.asarray(q_hold, dtype=np.float64)
    if not np.all(np.isfinite(q)):
        q = np.array([1.0, 0.0, 0.0, 0.0])
    if isinstance(state, CompiledState):
        row = state.rows[sensor]
        row[:] = 0.0
        row[kc.K_Q : kc.K_Q + 4] = q
        screen_kernel.fresh(state.rows[sensor : sensor + 1,
                                       kc.K_SCREEN : kc.K_SCREEN + screen_kernel.N_SCREEN])
    else:
        fresh = type(estimator)(estimator.params)
        fresh.reset(q0=q)
        new = fresh.state
        assert new is not None
        _put_rows(state, new, sensor)
        assert state.ready is not None
        state.ready[sensor] = False
    estimator.state = state


def run_each(
    estimator: Estimator, t: Array, gyr: Array, acc: Array, mag: Array | None,
    q_hold: Array, failed: Callable[[int, Exception], None],
) -> tuple[Array, NDArray[np.uint16]]:
    """Run the batch one sensor at a time; a sensor that raises is re-initialised.

    Arrays as for ``run`` ((S, N, 3), t (N,)); ``q_hold`` (S, 4) the outputs to hold for a
    failing sensor; ``failed(sensor, exc)`` is told about each failure. Returns quat
    (S, N, 4) and flags (S, N). The estimator's state afterwards holds every sensor's.
    """
    n_sensors, n = acc.shape[0], acc.shape[1]
    q_out = np.empty((n_sensors, n, 4))
    flags = np.zeros((n_sensors, n), dtype=np.uint16)
    _run_rows(estimator, range(n_sensors), t, gyr, acc, mag, q_hold, failed, q_out, flags)
    return q_out, flags


def finish_raised(
    estimator: Estimator, t: Array, gyr: Array | None, acc: Array, mag: Array | None,
    q_hold: Array, clock_before: Array, q_out: Array, flags: NDArray[np.uint16],
    exc: Exception, failed: Callable[[int, Exception], None],
) -> None:
    """Complete a batch whose in-place run raised ``exc`` part-way (module docstring).

    ``q_out`` (S, N, 4) and ``flags`` (S, N) as the run left them (:data:`UNRUN` where it
    did not get to), completed in place; ``clock_before`` (1,) the shared clock before the
    run; ``q_hold``, ``failed`` as for :func:`run_each`. The estimator's state afterwards
    holds every sensor's, the clock at the batch's end (where the finished sensors are).
    """
    done = flags[:, -1] != UNRUN
    untouched = flags[:, 0] == UNRUN
    stopped = np.flatnonzero(~done)
    state = estimator.state
    if state is None:
        raise exc
    clock_after = state.clock.copy() if isinstance(state, CompiledState) else None
    if stopped.size:
        first = int(stopped[0])
        broken = [s for s in stopped.tolist() if s == first or not untouched[s]]
    else:  # the kernel finished: strict mode refused flagged samples: their sensors fail
        broken = np.flatnonzero((flags & np.uint16(DATA_FLAGS)).any(axis=1)).tolist()
        first = -1
        if not broken:
            raise exc
    for s in broken:
        failed(s, exc)
        q_out[s] = q_hold[s]
        flags[s] = np.uint16(Flag.INITIALISING)
        reinitialise(estimator, s, q_hold[s])
    rest = [s for s in stopped.tolist() if s != first and untouched[s]]
    if rest:
        state = estimator.state
        assert isinstance(state, CompiledState)
        state.clock[:] = clock_before  # what the untouched sensors start from
        estimator.state = state
        _run_rows(estimator, rest, t, gyr, acc, mag, q_hold, failed, q_out, flags)
    if clock_after is not None and bool(done.any() or rest):
        state = estimator.state
        assert isinstance(state, CompiledState)
        state.clock[:] = clock_after
        estimator.state = state


def _run_rows(
    estimator: Estimator, sensors: Sequence[int], t: Array, gyr: Array | None, acc: Array,
    mag: Array | None, q_hold: Array, failed: Callable[[int, Exception], None], q_out: Array,
    flags: NDArray[np.uint16],
) -> None:
    """:func:`run_each` over ``sensors``, writing their rows of ``q_out`` and ``flags``."""
    state = estimator.state  # as before the batch: every sensor starts from it
    n_sensors = acc.shape[0]
    merged = None if state is None else state.copy()  # takes the clock of the runs
    for s in sensors:
        one = type(estimator)(estimator.params, rate_hz=estimator.rate_hz)
        if state is not None:
            one.state = _take_rows(state, s)
        try:
            est = one.run(gyr=None if gyr is None else gyr[s : s + 1], acc=acc[s : s + 1],
                          mag=None if mag is None else mag[s : s + 1], t=t,
                          check_units=False)
        except Exception as exc:  # isolated: this sensor is re-initialised, the rest go on
            failed(s, exc)
            q_out[s] = q_hold[s]
            flags[s] = np.uint16(Flag.INITIALISING)
            if merged is not None:
                estimator.state = merged
                reinitialise(estimator, s, q_hold[s])
                merged = estimator.state
            continue
        q_out[s] = est.quat[0]
        flags[s] = 0 if est.flags is None else est.flags[0]
        after = one.state
        if after is not None:
            if merged is None:  # no state before this batch: build one for every sensor
                merged = _tiled(after, n_sensors)
            _put_rows(merged, after, s)
            _set_clock(merged, after)
    if merged is not None:
        estimator.state = merged


# -- state rows --------------------------------------------------------------------------
def _n_sensors(state: Any) -> int:
    return int(state.rows.shape[0] if isinstance(state, CompiledState) else state.quat.shape[0])


def _take_rows(state: Any, s: int) -> Any:
    """A one-sensor copy of sensor ``s``'s part of ``state``."""
    if isinstance(state, CompiledState):
        return CompiledState(state.rows[s : s + 1].copy(), state.clock.copy(), state.layout)
    n = _n_sensors(state)
    values = {}
    for f in dataclasses.fields(state):
        value = getattr(state, f.name)
        if isinstance(value, screening.ScreenState):
            value = screening.ScreenState(packed=value.packed[s : s + 1].copy())
        elif isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == n:
            value = value[s : s + 1].copy()
        values[f.name] = value
    return type(state)(**values)


def _tiled(state: Any, n_sensors: int) -> Any:
    """An S-sensor state whose every row is ``state``'s one row (filled in per sensor)."""
    if isinstance(state, CompiledState):
        return CompiledState(np.repeat(state.rows, n_sensors, axis=0), state.clock.copy(),
                             state.layout)
    values = {}
    for f in dataclasses.fields(state):
        value = getattr(state, f.name)
        if isinstance(value, screening.ScreenState):
            value = screening.ScreenState(packed=np.repeat(value.packed, n_sensors, axis=0))
        elif isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == 1:
            value = np.repeat(value, n_sensors, axis=0)
        values[f.name] = value
    return type(state)(**values)


def _put_rows(state: Any, one: Any, s: int) -> None:
    """Write the one-sensor ``one`` into row ``s`` of ``state`` (in place)."""
    if isinstance(state, CompiledState):
        state.rows[s] = one.rows[0]
        return
    n = _n_sensors(state)
    for f in dataclasses.fields(state):
        value, new = getattr(state, f.name), getattr(one, f.name)
        if isinstance(value, screening.ScreenState) and isinstance(new, screening.ScreenState):
            value.packed[s] = new.packed[0]
        elif (isinstance(value, np.ndarray) and isinstance(new, np.ndarray) and value.ndim >= 1
              and value.shape[0] == n and new.shape[0] == 1):
            value[s] = new[0]


def _set_clock(state: Any, one: Any) -> None:
    if isinstance(state, CompiledState):
        state.clock[:] = one.clock
    else:
        state.t_last_s = one.t_last_s
