"""The live engine's filter step: S sensors in one estimator, each sensor's faults its own.

:class:`SensorFilters` runs one batch of :class:`~margtrack.live.assembler.Frames`
through the estimator's multi-sensor ``run`` (the input policy of
:mod:`margtrack.estimator.screening` flags and skips bad samples per sensor) and adds what a
live stream needs on top, per sensor:

- *restarts* (``Frames.restart``: a clock resync, a stale sensor coming back): the batch is
  split there and the sensor restarts from its next usable sample, keeping its gyro bias
  (:func:`~margtrack.live.isolation.restart`);
- *stale* samples (``Frames.stale``, all-zero input): the sensor's output is held at its
  last orientation instead of integrating anything;
- *failures*: a sensor whose output is not finite is re-initialised and its output held
  (``reinitialised``); if the S-sensor run raises, the batch is run sensor by sensor and
  only the sensors that raise are re-initialised (:func:`~margtrack.live.isolation.run_each`).
  The reason is kept per sensor in ``errors``.

Counted per sensor: ``processed`` (samples run, not held), ``faults`` (processed samples
with a fault flag: the input policy's or a rejected disturbance,
:data:`~margtrack.estimator.flags.FAULT_FLAGS`; rest is a state, not counted),
``reinitialised``. The checks, holds, last
orientations and counts are one compiled pass over each sensor's samples
(:func:`~margtrack.live.batch_close_kernel.close_sensors`; as numpy passes over the batch they
were 1.3 ms per frame at 195,000 sensors); Python runs per sensor only for a sensor that
failed.

The hot path: a compiled method runs through
:meth:`~margtrack.estimator.compiled.CompiledEstimator.run_into`, the same kernel call as
``run`` without its copies: the lockstep blocks read the sources' frame-major batch where
it is (``frame_major``: no copy; the copies were 1.1 of 9.4 ms per frame at 164,520
``bachmann`` sensors), other kernels get a per-sensor copy, and outputs are written
into arrays reused from batch to batch (:class:`~margtrack.live.buffers.BatchBuffers`),
the state advanced in place; the method's extra outputs, which the engine does not use,
are not asked for (the lockstep kernels then skip writing them). If that call raises, the
sensors the kernel finished keep their results, the one it stopped in fails alone and the
untouched ones run one by one (:func:`~margtrack.live.isolation.finish_raised`). Other
methods go through ``run``. The orientations returned are valid until the next batch (the
engine copies what it keeps).
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator.compiled import CompiledEstimator
from margtrack.estimator.contract import Estimator
from margtrack.estimator.flags import FAULT_FLAGS, Flag
from margtrack.estimator.sensor_threads import in_threads, thread_count
from margtrack.live.assembler import Frames
from margtrack.live.batch_close_kernel import close_sensors
from margtrack.live.buffers import BatchBuffers, frames_of
from margtrack.live.isolation import finish_raised, reinitialise, restart, run_each

Array = NDArray[np.float64]

#: the engine shares a batch's sensors among threads from this many samples a call (4 frames
#: of 5000 sensors): its batches are a few frames, far below the ``run`` threshold
#: (:data:`~margtrack.estimator.compiled.PARALLEL_MIN_SAMPLES`); starting the threads costs
#: tens of microseconds a call
LIVE_PARALLEL_MIN_SAMPLES = 20_000

#: the kernel's flag arguments and its "no array" (kernels.batch_close)
_FAULT_FLAGS, _INITIALISING = np.uint16(FAULT_FLAGS), np.uint16(Flag.INITIALISING)
_NONE = np.zeros((0, 0), dtype=np.bool_)

__all__ = ["LIVE_PARALLEL_MIN_SAMPLES", "SensorFilters"]


class SensorFilters:
    """One estimator for S sensors with per-sensor isolation (module docstring)."""

    def __init__(self, estimator: Estimator, n_sensors: int) -> None:
        self.estimator = estimator
        self.n_sensors = n_sensors
        self.q_last = np.tile([1.0, 0.0, 0.0, 0.0], (n_sensors, 1))
        self.processed = np.zeros(n_sensors, dtype=np.int64)
        self.faults = np.zeros(n_sensors, dtype=np.int64)
        self.reinitialised = np.zeros(n_sensors, dtype=np.int64)
        self.errors = [""] * n_sensors
        self._hot = isinstance(estimator, CompiledEstimator)
        self._clock = np.full(1, np.nan)  # the shared clock before the batch, s
        if self._hot:
            self._buffers = BatchBuffers(n_sensors, {
                "gyr": (3, np.float64), "acc": (3, np.float64), "mag": (3, np.float64),
                "q": (4, np.float64), "flags": (0, np.uint16),
            })

    def run(self, frames: Frames) -> tuple[Array, NDArray[np.uint16]]:
        """Orientations (S, N, 4) and flags (S, N) of one batch (module docstring)."""
        n = frames.n_frames
        cuts = [0]
        if frames.restart is not None:
            cuts += [int(k) for k in np.flatnonzero(frames.restart.any(axis=0)) if k > 0]
        cuts.append(n)
        q_parts, flag_parts = [], []
        for a, b in itertools.pairwise(cuts):
            if frames.restart is not None:
                restart(self.estimator, np.flatnonzero(frames.restart[:, a]).tolist())
            q, flags = self._segment(frames, a, b)
            if len(cuts) > 2:  # the next segment reuses the buffers
                q, flags = q.copy(), flags.copy()
            q_parts.append(q)
            flag_parts.append(flags)
        q = q_parts[0] if len(q_parts) == 1 else np.concatenate(q_parts, axis=1)
        flags = flag_parts[0] if len(flag_parts) == 1 else np.concatenate(flag_parts, axis=1)
        return q, flags

    def _segment(self, frames: Frames, a: int, b: int) -> tuple[Array, NDArray[np.uint16]]:
        t = frames.t_s[a:b]
        gyr, acc = frames.gyr[:, a:b], frames.acc[:, a:b]
        mag = None if frames.mag is None else frames.mag[:, a:b]
        if self._hot:
            q, flags = self._run_hot(t, gyr, acc, mag)
        else:
            try:
                est = self.estimator.run(gyr=gyr, acc=acc, mag=mag, t=t, check_units=False)
                q, flags = est.quat, est.flags
                if flags is None:
                    flags = np.zeros(q.shape[:2], dtype=np.uint16)
            except Exception:  # one sensor's fault: find it, the others go on
                q, flags = run_each(self.estimator, t, gyr, acc, mag, self.q_last,
                                    lambda s, e: self._failed(s, f"filter raised {e!r}"))
            if not q.flags.writeable:  # held and failed sensors are written in place below
                q = q.copy()
        q = np.ascontiguousarray(q, dtype=np.float64)
        flags = np.ascontiguousarray(flags, dtype=np.uint16)
        bad = self._close(frames, a, b, q, flags)
        for s in bad.tolist():
            reinitialise(self.estimator, s, q[s, -1])
            self._failed(s, "non-finite orientation")
        return q, flags

    def _close(self, frames: Frames, a: int, b: int, q: Array, flags: NDArray[np.uint16]
               ) -> NDArray[np.intp]:
        """Frames a:b's orientations repaired and held, the last kept, the samples counted
        (:func:`~margtrack.live.batch_close_kernel.close_sensors`, the sensors shared among
        threads for a large batch); the sensors whose orientation was not finite."""
        stale = _NONE if frames.stale is None else np.ascontiguousarray(frames.stale[:, a:b])
        held = np.ascontiguousarray(frames.held[:, a:b])
        bad = np.zeros(self.n_sensors, dtype=np.bool_)
        n_threads = thread_count() if q.shape[0] * q.shape[1] >= LIVE_PARALLEL_MIN_SAMPLES else 1
        edges = [self.n_sensors * k // n_threads for k in range(n_threads + 1)]

        def part(k: int) -> None:
            close_sensors(q, flags, stale, held, self.q_last, self.processed, self.faults, bad,
                          _FAULT_FLAGS, _INITIALISING, edges[k], edges[k + 1])

        in_threads(part, n_threads, "margtrack-close")
        return np.flatnonzero(bad)

    def _run_hot(self, t: Array, gyr: Array, acc: Array, mag: Array | None
                 ) -> tuple[Array, NDArray[np.uint16]]:
        """The compiled method's kernel on reused buffers, the state in place (module
        docstring); a raise completed by :func:`~margtrack.live.isolation.finish_raised`."""
        buf, n = self._buffers, t.shape[0]
        est = self.estimator
        assert isinstance(est, CompiledEstimator)
        inputs = [("gyr", gyr if est.uses_gyr else None), ("acc", acc), ("mag", mag)]
        frames = [None if v is None else frames_of(v) for _, v in inputs]
        frame_major = est.takes_frames(self.n_sensors) and all(
            f is not None or v is None for f, (_, v) in zip(frames, inputs, strict=True))
        if frame_major:  # the lockstep blocks read the sources' frames where they are
            kernel_in = frames
        else:
            kernel_in = buf.contiguous_all(inputs, n_threads=thread_count())
        q, flags = buf.get("q", n), buf.get("flags", n)
        no_outputs = np.empty((self.n_sensors, n, 0))  # the method's extra outputs: unused
        try:
            est.run_into(np.ascontiguousarray(t, dtype=np.float64), *kernel_in, q, no_outputs,
                         flags, self._clock,
                         parallel=self.n_sensors * n >= LIVE_PARALLEL_MIN_SAMPLES,
                         frame_major=frame_major)
        except Exception as exc:  # one sensor's fault: it fails alone, the others go on
            finish_raised(est, t, gyr, acc, mag, self.q_last, self._clock, q, flags, exc,
                          lambda s, e: self._failed(s, f"filter raised {e!r}"))
        return q, flags

    def _failed(self, sensor: int, why: str) -> None:
        self.reinitialised[sensor] += 1
        self.errors[sensor] = why
