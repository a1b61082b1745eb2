"""Methods whose whole per-sample path is compiled: one call per ``update``, one per ``run``.

A :class:`CompiledEstimator` keeps each sensor's state as one flat row (the contract's
slots, ``estimator/skeleton.py``, then the method's own, named by ``state_layout``) and a
shared clock. Its kernel module has the entry points ``contract.entry_points`` generates
from its step (``run``, ``lanes`` for many sensors in lockstep, ``start``), so the
screening, the (re)starts and the method's step are one compiled call, and ``update`` is
``run`` over one sample: N updates equal one run. Several sensors are shared among threads
(:mod:`~margtrack.estimator.sensor_threads`). ``coefs`` is the screening's
coefficients followed by the method's (:meth:`CompiledEstimator._coefficients`).
"""

from __future__ import annotations

from collections.abc import Mapping
from types import ModuleType
from typing import Any, ClassVar, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.estimator import lockstep as kcl
from margtrack.estimator import screening
from margtrack.estimator import skeleton as kc
from margtrack.estimator.compiled_state import CompiledState
from margtrack.estimator.contract import Estimator
from margtrack.estimator.estimate import Estimate
from margtrack.estimator.flags import first_problem
from margtrack.estimator.outputs import Deferred, Outputs
from margtrack.estimator.params import Params
from margtrack.estimator.sensor_threads import run_threaded
from margtrack.estimator.units import UnitProbe

Array = NDArray[np.float64]

__all__ = ["UNRUN", "CompiledEstimator", "CompiledState"]


P = TypeVar("P", bound=Params)

#: several sensors are shared among threads (:mod:`~margtrack.estimator.sensor_threads`)
#: from this many samples in all: below it starting the threads costs more than they save
PARALLEL_MIN_SAMPLES = 100_000
#: from this many sensors, a kernel module with a lockstep entry point (``run_lanes``)
#: runs them in blocks vectorised across the sensors (``estimator/lockstep.py``), with
#: the same results; fewer fill too few vector lanes
LANES_MIN_SENSORS = 16


class CompiledEstimator(Estimator[P, CompiledState]):  # type: ignore[type-var]
    """Base of the methods with a compiled per-sample path (module docstring).

    Subclasses set ``kernel`` (the module with ``run``, ``lanes`` (or None), ``start``,
    ``N_ROW`` and ``N_X``: ``contract.entry_points``), ``state_layout`` (the method's named
    row slots), ``outputs_layout``
    (names and widths of the per-sample extra outputs) and implement
    :meth:`_coefficients` (the kernel's coefficient vector from the parameters).

    A kernel module that also has ``expand(coefs, q, kept, out)`` keeps only ``N_X`` values
    per sample in ``run``; ``expand`` computes the extra outputs from them
    and the orientations when ``Estimate.outputs`` is first read
    (:class:`~margtrack.estimator.outputs.Outputs`).
    """

    kernel: ClassVar[ModuleType]
    state_layout: ClassVar[Mapping[str, tuple[int, int]]] = {}
    outputs_layout: ClassVar[tuple[tuple[str, int], ...]] = ()

    def __init__(
        self, params: P | None = None, *, rate_hz: float | None = None, **param_values: Any
    ) -> None:
        super().__init__(params, rate_hz=rate_hz, **param_values)
        self._buffers: tuple[Array, Array, NDArray[np.uint16]] | None = None
        #: one sensor's update buffers once its units are checked (:meth:`update`)
        self._lean: tuple[Any, ...] | None = None
        self._has_gyr_bit = 2 if self.uses_gyr else 0
        self._derive()

    # -- coefficients, computed once per parameter change -----------------------------------
    def _coefficients(self) -> Array:
        """The kernel's coefficient vector (SI units) from ``self.params``."""
        return np.zeros(1)

    def _derive(self) -> None:
        screen_part = np.zeros(kc.N_SCOEF)
        screen_part[: screening.kernel.N_COEF] = self._screen_coef
        screen_part[kc.C_NED] = 1.0 if self._params.frame == "NED" else 0.0
        screen_part[kc.C_MAG_REQUIRED] = 0.0 if self.mag_optional else 1.0
        own = np.asarray(self._coefficients(), dtype=np.float64).ravel()
        self._coefs = np.ascontiguousarray(np.concatenate([screen_part, own]))
        self._dt_default = None if self.rate_hz is None else 1.0 / self.rate_hz

    @Estimator.params.setter  # type: ignore[attr-defined]
    def params(self, value: P) -> None:
        Estimator.params.fset(self, value)  # type: ignore[attr-defined]
        self._derive()
        self._lean = None

    @property
    def flags(self) -> NDArray[np.uint16] | None:
        """(S,) health flags of the last processed sample (:class:`Flag` bits)."""
        return None if self._last_flags is None else self._last_flags.copy()

    # -- state ----------------------------------------------------------------------------
    def _has_bits(self, has: int) -> int:
        """The ``has`` bits the kernel gets (1: a field is given, 2: a rate is given); a
        method that ignores a given field clears bit 1 here."""
        return has

    def _in_lanes(self, n_sensors: int) -> bool:
        """Whether ``n_sensors`` run in lockstep blocks (``estimator/lockstep.py``)."""
        return n_sensors >= LANES_MIN_SENSORS and self.kernel.lanes is not None

    def takes_frames(self, n_sensors: int) -> bool:
        """Whether :meth:`run_into` reads frame-major inputs of ``n_sensors`` sensors where
        they are (lockstep blocks), rather than from a per-sensor copy."""
        return self._in_lanes(n_sensors)

    def _run_kernel(
        self, rows: Array, clock: Array, t: Array, gyr: Array, acc: Array, mag: Array, has: int,
        q_out: Array, x_out: Array, flags_out: NDArray[np.uint16], *, parallel: bool,
        frame_major: bool = False,
    ) -> None:
        """The kernel over S sensors' N samples: the clock read once, then the sensors in
        lockstep blocks (:meth:`_in_lanes`) or one after the other, shared among threads
        when ``parallel``; ``frame_major``: inputs (N, S, 3) (lockstep blocks only)."""
        kernel, coefs = self.kernel, self._coefs
        has = self._has_bits(has)
        n_sensors = rows.shape[0]
        n_threads = None if parallel and n_sensors > 1 else 1
        if not self._in_lanes(n_sensors):  # each part reads its own copy of the clock
            clocks: dict[int, Array] = {}

            def run_part(a: int, b: int) -> None:
                clocks[a] = part_clock = clock.copy()
                kernel.run(rows[a:b], part_clock, coefs, t, gyr[a:b], acc[a:b], mag[a:b], has,
                           q_out[a:b], x_out[a:b], flags_out[a:b])

            try:
                run_threaded(run_part, n_sensors, align=1, n_threads=n_threads)
            finally:
                clock[:] = clocks.get(0, clock)
            return
        dts, ks, tflags = kc.clock_series(clock, coefs[screening.kernel.C_MAX_GAP], t)
        width = kernel.N_ROW + kcl.N_B + kernel.N_X

        def lanes_part(a: int, b: int) -> None:
            scratch = np.empty(width * kcl.LANES)
            if frame_major:  # the inputs whole, the part's first sensor given
                kernel.lanes(scratch, rows[a:b], coefs, dts, ks, tflags, gyr, acc, mag, has,
                             q_out[a:b], x_out[a:b], flags_out[a:b], True, a)
            else:
                kernel.lanes(scratch, rows[a:b], coefs, dts, ks, tflags, gyr[a:b], acc[a:b],
                             mag[a:b], has, q_out[a:b], x_out[a:b], flags_out[a:b], False, 0)

        run_threaded(lanes_part, n_sensors, align=kcl.LANES, n_threads=n_threads)

    def _new_rows(self, n_sensors: int) -> CompiledState:
        rows = np.zeros((n_sensors, self.kernel.N_ROW))
        rows[:, kc.K_Q] = 1.0
        screening.kernel.fresh(rows[:, kc.K_SCREEN : kc.K_SCREEN + screening.kernel.N_SCREEN])
        return CompiledState(rows, np.array([np.nan]), self.state_layout)

    def _new_state(self, quat0: Array) -> CompiledState:
        state = self._new_rows(quat0.shape[0])
        self.kernel.start(state.rows, self._coefs, np.ascontiguousarray(quat0))
        return state

    def _process(self, *args: Any) -> Any:  # pragma: no cover - the compiled path replaces it
        raise TypeError(f"{type(self).__name__} runs through its compiled kernel")

    def reset(self, q0: ArrayLike | None = None) -> None:
        """Forget the state; with ``q0`` ((4,) or (S, 4)) start from that orientation."""
        self._probe = UnitProbe()
        self._last_flags = None
        self._buffers = None
        self._lean = None
        if q0 is None:
            self._state = None
            return
        q = quat.normalize(np.asarray(q0, dtype=np.float64).reshape(-1, 4))
        self._state = self._new_state(q)

    # -- entry points ------------------------------------------------------------------------
    def update(
        self,
        gyr: ArrayLike | None,
        acc: ArrayLike,
        mag: ArrayLike | None = None,
        dt: float | None = None,
    ) -> Array:
        """Process one sample ((3,), or (S, 3) for S sensors); return the orientation.

        ``dt`` is the time since the previous sample in s (default ``1 / rate_hz``). The
        sample is screened like any other (:attr:`flags` says what was done); over the
        first samples the units are checked. One call of the kernel ``run`` over one
        sample, so N updates equal one ``run``.
        """
        state, lean = self._state, self._lean
        if (lean is not None and getattr(acc, "ndim", 0) == 1 and state is not None
                and state.rows.shape[0] == 1 and self._probe.done):
            # one sensor past its unit check: the sample into the kernel's buffers, one call
            if dt is None:
                dt = self._dt_default
                if dt is None:
                    raise ValueError("update() needs dt (s) or an estimator built with rate_hz")
            t, g, a, m, q_out, x_out, flags, views = lean
            a[:] = acc  # (3,) views of the (1, 1, 3) inputs
            g[:] = acc if gyr is None else gyr
            m[:] = acc if mag is None else mag
            clock = state.clock
            t[0] = clock[0] + dt
            has = self._has_bits((mag is not None) | (self._has_gyr_bit if gyr is not None else 0))
            self.kernel.run(state.rows, clock, self._coefs, t, views[0], views[1], views[2], has,
                            q_out, x_out, flags)
            self._last_flags = flags[:, 0]
            return q_out[0, 0].copy()
        acc = np.asarray(acc, dtype=np.float64)
        one = acc.ndim == 1
        a = acc.reshape(-1, 3)
        g = a if gyr is None else np.asarray(gyr, dtype=np.float64).reshape(-1, 3)
        m = a if mag is None else np.asarray(mag, dtype=np.float64).reshape(-1, 3)
        if state is None:
            if self.uses_gyr and gyr is None:
                raise ValueError(f"method {self.name!r} needs gyroscope data (gyr)")
            if mag is None and not self.mag_optional:
                raise ValueError(f"method {self.name!r} needs a magnetometer (mag)")
            state = self._state = self._new_rows(a.shape[0])
        n_sensors = state.rows.shape[0]
        if a.shape[0] != n_sensors or g.shape != a.shape or m.shape != a.shape:
            raise ValueError(
                f"update() takes gyr, acc, mag of shape (3,) or (S, 3) for the S = {n_sensors} "
                f"sensor(s) the state holds; got {np.shape(gyr)}, {np.shape(acc)}, "
                f"{np.shape(mag)} (reset() first to change the number of sensors)"
            )
        clock = state.clock[0]
        if dt is None:
            if np.isfinite(clock):
                if self._dt_default is None:
                    raise ValueError("update() needs dt (s) or an estimator built with rate_hz")
                dt = self._dt_default
            else:
                dt = 0.0
        t = np.array([0.0 if not np.isfinite(clock) else clock + float(dt)])
        if not self._probe.done:
            self._probe.add(g[:, None] if self.uses_gyr else None, a[:, None], float(t[0]))
        buffers = self._buffers
        if buffers is None or buffers[0].shape[0] != n_sensors:
            buffers = self._buffers = (
                np.empty((n_sensors, 1, 4)),
                np.empty((n_sensors, 1, self.run_width)),
                np.empty((n_sensors, 1), dtype=np.uint16),
            )
        q_out, x_out, flags = buffers
        has = (mag is not None) | (self._has_gyr_bit if gyr is not None else 0)
        inputs = [np.ascontiguousarray(x[:, None]) for x in (g, a, m)]
        self._run_kernel(state.rows, state.clock, t, *(_read_only(x) for x in inputs), has,
                         q_out, x_out, flags, parallel=False)
        self._last_flags = flags[:, 0].copy()
        if n_sensors == 1 and self._probe.done:  # the lean path's own buffers from now on
            own = [np.zeros((1, 1, 3)) for _ in range(3)]
            views = tuple(_read_only(x) for x in own)
            self._lean = (t, *(x[0, 0] for x in own), q_out, x_out, flags, views)
        return q_out[0, 0].copy() if one else q_out[:, 0].copy()

    def _run_arrays(
        self,
        gyr: ArrayLike | None,
        acc: ArrayLike,
        mag: ArrayLike | None,
        t: Array,
        *,
        check_units: bool,
    ) -> Estimate:
        x = self._validated(gyr, acc, mag, t, check_units=check_units)
        n_sensors, n = x.acc.shape[0], x.acc.shape[1]
        state = self._state
        if state is not None and state.rows.shape[0] != n_sensors:
            raise ValueError(
                f"the state holds {state.rows.shape[0]} sensor(s) but the data has {n_sensors}; "
                "reset() first"
            )
        work = self._new_rows(n_sensors) if state is None else state.copy()
        # a kernel with ``expand`` keeps N_X values per sample, its outputs made on read
        lean = hasattr(self.kernel, "expand")
        q = np.empty((n_sensors, n, 4))
        extra = np.empty((n_sensors, n, self.run_width))
        flags = np.empty((n_sensors, n), dtype=np.uint16)
        has = (x.mag is not None) | (self._has_gyr_bit if x.gyr is not None else 0)
        # several sensors: shared among threads
        parallel = n_sensors > 1 and n_sensors * n >= PARALLEL_MIN_SAMPLES
        self._run_kernel(
            work.rows, work.clock, _read_only(np.ascontiguousarray(x.t)),
            _read_only(x.acc if x.gyr is None else x.gyr), _read_only(x.acc),
            _read_only(x.acc if x.mag is None else x.mag), has, q, extra, flags,
            parallel=parallel,
        )
        if self._params.strict:
            problem = first_problem(flags)
            if problem is not None:
                raise ValueError(f"{problem} (strict=True; strict=False flags and skips it)")
        self._state = work
        self._last_flags = flags[:, -1].copy()
        outputs: Mapping[str, NDArray[Any]]
        if lean:
            outputs = _deferred_outputs(self, q, extra)
        else:
            parts: dict[str, NDArray[Any]] = {}
            offset = 0
            for name, w in self.outputs_layout:
                parts[name] = extra[:, :, offset : offset + w]
                offset += w
            outputs = parts
        return Estimate(
            quat=q,
            t=x.t.copy(),
            frame=self._params.frame,
            method=self.name,
            params=dict(self._params_dict),
            outputs=outputs,
            flags=flags,
        )

    @property
    def run_width(self) -> int:
        """Values per sample the ``run`` kernel writes (``kernel.N_X``, at least 1): those of
        ``outputs_layout``, or fewer for a kernel that computes them on read (``expand``)."""
        return max(self.kernel.N_X, 1)

    def run_into(
        self,
        t: Array,
        gyr: Array | None,
        acc: Array,
        mag: Array | None,
        q_out: Array,
        x_out: Array,
        flags_out: NDArray[np.uint16],
        clock_before: Array | None = None,
        parallel: bool | None = None,
        frame_major: bool = False,
    ) -> None:
        """:meth:`run` for the live engine: the state advanced in place, results in buffers.

        ``t`` (N,) s; ``gyr``, ``acc``, ``mag`` (S, N, 3) C-contiguous float64 (rad/s, m/s²,
        any field unit; ``gyr``/``mag`` None as for ``run``); ``q_out`` (S, N, 4), ``x_out``
        (S, N, :attr:`run_width`) (the kernel's per-sample values), or (S, N, 0) when they
        are not wanted (the lockstep blocks then do not write them; the per-sensor kernels
        write them to a scratch array), ``flags_out``
        (S, N) uint16, C-contiguous, overwritten. The kernel call of :meth:`run` on the
        same state (the same results to the bit) without its copies: O(1) checks (shapes,
        dtypes, layout; values are the screening's), no allocation, no state copy, no
        unit check. So a kernel that raises leaves the state part-way: ``flags_out`` is
        filled with :data:`UNRUN` first, so a sensor whose last sample is not UNRUN
        finished, one whose first sample is UNRUN was not touched, the others stopped in
        the middle; the shared clock has moved to the batch's end (``clock_before`` (1,),
        if given, receives it from before the call: what untouched sensors need to run
        again). With ``strict=True`` a flagged sample raises once every sensor finished.
        ``parallel``: sensors shared among threads (None: from PARALLEL_MIN_SAMPLES samples).
        ``frame_major``: ``gyr``, ``acc``, ``mag`` are (N, S, 3) C-contiguous, a frame's
        sensors together as the live sources deliver them; the lockstep blocks read them
        where they are (:meth:`takes_frames`), other kernels from a per-sensor copy.
        """
        n_sensors, n = (q_out if frame_major else acc).shape[0], t.shape[0]
        width = self.run_width
        x_width = 0 if x_out.shape[2:] == (0,) else width  # (S, N, 0): not wanted
        if self.uses_gyr and gyr is None:
            raise ValueError(f"method {self.name!r} needs gyroscope data (gyr)")
        gyr = gyr if self.uses_gyr else None  # ignored, as by run
        if mag is None and not self.mag_optional:
            raise ValueError(f"method {self.name!r} needs a magnetometer (mag)")
        signals = [(nm, a) for nm, a in (("acc", acc), ("gyr", gyr), ("mag", mag)) if a is not None]
        in_shape = (n, n_sensors, 3) if frame_major else (n_sensors, n, 3)
        for name, arr, shape, dtype in (
            *((nm, a, in_shape, np.float64) for nm, a in signals),
            ("q_out", q_out, (n_sensors, n, 4), np.float64),
            ("x_out", x_out, (n_sensors, n, x_width), np.float64),
            ("flags_out", flags_out, (n_sensors, n), np.uint16),
        ):
            if arr.shape != shape or arr.dtype != dtype or not arr.flags.c_contiguous:
                layout = " (frame-major)" if frame_major and shape == in_shape else ""
                raise ValueError(f"run_into: {name} must be C-contiguous {np.dtype(dtype)} of "
                                 f"shape {shape}{layout}, got {arr.dtype} {arr.shape}")
        if frame_major and not self.takes_frames(n_sensors):  # a per-sensor copy
            gyr, acc, mag = (None if v is None else np.ascontiguousarray(np.swapaxes(v, 0, 1))
                             for v in (gyr, acc, mag))
            frame_major = False
        if t.dtype != np.float64 or t.ndim != 1 or n == 0:
            raise ValueError(f"run_into: t must be float64 of shape (N,) N > 0, got {t.shape}")
        state = self._state
        if state is None:
            state = self._state = self._new_rows(n_sensors)
        elif state.rows.shape[0] != n_sensors:
            raise ValueError(
                f"the state holds {state.rows.shape[0]} sensor(s) but the data has {n_sensors}; "
                "reset() first"
            )
        if clock_before is not None:
            clock_before[:] = state.clock
        flags_out.fill(UNRUN)
        has = (mag is not None) | (self._has_gyr_bit if gyr is not None else 0)
        if parallel is None:
            parallel = n_sensors * n >= PARALLEL_MIN_SAMPLES
        if x_width != width and not self._in_lanes(n_sensors):
            x_out = np.empty((n_sensors, n, width))  # the per-sensor kernels write them all
        self._run_kernel(
            state.rows, state.clock, _read_only(np.ascontiguousarray(t)),
            _read_only(acc if gyr is None else gyr), _read_only(acc),
            _read_only(acc if mag is None else mag), has, q_out, x_out, flags_out,
            parallel=parallel, frame_major=frame_major,
        )
        if self._params.strict:
            problem = first_problem(flags_out)
            if problem is not None:
                raise ValueError(f"{problem} (strict=True; strict=False flags and skips it)")
        self._last_flags = flags_out[:, -1].copy()


#: ``flags_out`` of :meth:`CompiledEstimator.run_into` before the kernel writes a sample: no
#: sample's flags have every bit set, so it marks the samples the kernel never finished
UNRUN = np.uint16(0xFFFF)


def _deferred_outputs(est: CompiledEstimator[Any], q: Array, kept: Array) -> Outputs:
    """``outputs_layout``'s series, each computed on first read by ``kernel.expand`` from
    the orientations q (S, N, 4) and what the kernel kept per sample (one expansion for
    all of them)."""
    kernel, coefs, layout = est.kernel, est._coefs.copy(), est.outputs_layout
    width = sum(w for _, w in layout)
    full: list[Array] = []

    def expanded() -> Array:
        if not full:
            out = np.empty(q.shape[:2] + (width,))
            kernel.expand(coefs, q, kept, out)
            full.append(out)
        return full[0]

    def part(offset: int, w: int) -> Deferred:
        return Deferred(lambda: expanded()[:, :, offset : offset + w])

    values: dict[str, Array | Deferred] = {}
    offset = 0
    for name, w in layout:
        values[name] = part(offset, w)
        offset += w
    return Outputs(values)


def _read_only(arr: Array) -> Array:
    """A read-only view: inputs reach the kernels with one type (a Recording's arrays are
    read-only, the user's usually not), so each kernel compiles once, not twice."""
    view = arr.view()
    view.flags.writeable = False
    return view
