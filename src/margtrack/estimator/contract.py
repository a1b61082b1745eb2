"""The estimator contract: :class:`Estimator`, with ``update``/``run`` and restarts (its
``State`` and ``Estimate`` in :mod:`~margtrack.estimator.estimate`).

Every estimator and filter in margtrack subclasses :class:`Estimator`, so the CLI, the
benchmarks and the live engine can swap them:

- parameters are a frozen dataclass of declared fields (:mod:`margtrack.estimator.params`);
- state is separate, complete, readable and settable (``state``, ``reset(q0=None)``);
- ``update(gyr, acc, mag=None, dt=None)`` processes one sample (or one per sensor);
- ``run(recording_or_arrays)`` processes a series, for S sensors at once;
- every sample passes the input screening first (:mod:`margtrack.estimator.screening`),
  and every output carries the same health flags (:mod:`margtrack.estimator.flags`).

``update`` is ``run`` on one sample: one implementation, so N updates equal one run.

Timing rule: the first usable sample after :meth:`Estimator.reset` (or a gap) yields the
initial orientation (``q0`` or the one measured by accelerometer and magnetometer); every
later sample ``i`` is propagated over ``dt_i = t_i - t_{i-1}`` with gyro sample ``i`` (it
covers ``(t_{i-1}, t_i]``). Sample times are never assumed: they come from timestamps, an
explicit ``dt`` or the ``rate_hz`` given to the constructor.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Generic, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.estimator import screening
from margtrack.estimator.estimate import Estimate, State, rows_of, squeezed
from margtrack.estimator.flags import Flag, first_problem
from margtrack.estimator.initial import initial_orientation, usable_for_init
from margtrack.estimator.inputs import Inputs, recordings, signal_array
from margtrack.estimator.params import Params
from margtrack.estimator.units import (
    UnitProbe,
    check_series_times,
    check_series_units,
    scale_to_si,
)
from margtrack.recording import Recording
from margtrack.units import convert_unit

Array = NDArray[np.float64]

__all__ = ["Estimator"]

_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


P = TypeVar("P", bound=Params)
S = TypeVar("S", bound=State)


class Estimator(ABC, Generic[P, S]):
    """Base of every margtrack estimator: screening, timing, state and the Estimate.

    Subclasses set ``name`` and ``params_type`` and implement :meth:`_new_state` and
    :meth:`_process`, which runs the method's kernel over S sensors and N samples. The
    kernel must honour the screening's sentinels: ``dt = 0`` integrates nothing, and an
    all-zero accelerometer or magnetometer vector is no measurement (skip the correction).

    Parameters
    ----------
    params : the method's frozen parameter dataclass (defaults when omitted).
    rate_hz : sample rate used when neither timestamps nor ``dt`` are given, Hz.
    **param_values : shortcuts for fields of ``params`` (``Gradient(beta=0.1)``).
    """

    name: ClassVar[str]
    params_type: ClassVar[type[Params]]
    #: whether the method reads the gyroscope (single-frame estimators do not)
    uses_gyr: ClassVar[bool] = True
    #: whether it can run without a magnetometer (6-D estimate with free heading)
    mag_optional: ClassVar[bool] = True
    #: whether the method rejects magnetic disturbances itself (then the screening's
    #: norm/dip gate is off and the method sets MAG_DISTURBED)
    rejects_mag_disturbance: ClassVar[bool] = False
    #: state fields a restart after a gap keeps (what the method knows of the sensor)
    kept_on_restart: ClassVar[tuple[str, ...]] = ()
    #: the unit check of ``update`` (a :class:`UnitProbe` reading this estimator's clock)

    def __init__(
        self, params: P | None = None, *, rate_hz: float | None = None, **param_values: Any
    ) -> None:
        base = params if params is not None else self.params_type()
        if not isinstance(base, self.params_type):
            raise TypeError(
                f"{type(self).__name__} takes {self.params_type.__name__}, "
                f"got {type(base).__name__}"
            )
        self._params: P = dataclasses.replace(base, **param_values) if param_values else base
        self._params_dict = self._params.as_dict()
        self._screen_coef = screening.coefficients(self._params, not self.rejects_mag_disturbance)
        if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz}")
        self.rate_hz = rate_hz
        self._state: S | None = None
        self._probe = UnitProbe()
        self._last_flags: NDArray[np.uint16] | None = None

    # -- parameters and state -------------------------------------------------------------
    @property
    def params(self) -> P:
        """The parameters; assign a new instance (or use :meth:`set_params`) to retune live."""
        return self._params

    @params.setter
    def params(self, value: P) -> None:
        if not isinstance(value, self.params_type):
            raise TypeError(f"params must be {self.params_type.__name__}")
        if value.frame != self._params.frame and self._state is not None:
            raise ValueError("frame cannot change while running; reset() first")
        self._params = value
        self._params_dict = value.as_dict()
        self._screen_coef = screening.coefficients(value, not self.rejects_mag_disturbance)

    def set_params(self, **values: Any) -> None:
        """Change parameters between samples; validated, they take effect at the next sample."""
        self.params = dataclasses.replace(self._params, **values)

    @property
    def state(self) -> S | None:
        """A copy of the complete state (``None`` before the first sample)."""
        return None if self._state is None else self._state.copy()

    @state.setter
    def state(self, value: S | None) -> None:
        self._state = None if value is None else value.copy()

    @property
    def gyr_bias_rad_s(self) -> Array | None:
        """(S, 3) the current gyro bias estimate, rad/s (None before a sample or without one)."""
        return None if self._state is None else self._state.gyr_bias_rad_s()

    @property
    def gyr_bias_sd_rad_s(self) -> Array | None:
        """(S, 3) standard deviation of the bias estimate, rad/s (None: not known)."""
        return None if self._state is None else self._state.gyr_bias_sd_rad_s()

    @property
    def flags(self) -> NDArray[np.uint16] | None:
        """(S,) health flags of the last processed sample (:class:`Flag` bits)."""
        return None if self._last_flags is None else self._last_flags.copy()

    def reset(self, q0: ArrayLike | None = None) -> None:
        """Forget the state; with ``q0`` ((4,) or (S, 4)) start from that orientation.

        Without ``q0`` the next usable sample's accelerometer and magnetometer set it.
        """
        self._probe = UnitProbe()
        self._last_flags = None
        if q0 is None:
            self._state = None
            return
        q = quat.normalize(np.asarray(q0, dtype=np.float64).reshape(-1, 4))
        state = self._new_state(q)
        state.ready = np.ones(q.shape[0], dtype=bool)
        state.screen = screening.ScreenState.new(q.shape[0])
        self._state = state

    # -- method-specific ----------------------------------------------------------------
    @abstractmethod
    def _new_state(self, quat0: Array) -> S:
        """Fresh state for S sensors starting at ``quat0`` (S, 4)."""

    @abstractmethod
    def _process(
        self, state: S, gyr: Array | None, acc: Array, mag: Array | None, dt: Array
    ) -> tuple[Array, dict[str, NDArray[Any]]]:
        """Run the kernel: arrays (S, N, 3), ``dt`` (N,) (0: nothing to integrate).

        Updates ``state`` in place; returns quat (S, N, 4) and outputs with (S, N, ...)
        arrays. Screened input: acc or mag all-zero means "no measurement".
        """

    def _initial_quat(self, acc0: Array, mag0: Array | None) -> Array:
        """Initial orientation (S, 4) from one usable sample of each sensor."""
        return initial_orientation(acc0, mag0, self._params.frame)

    def _restart(self, state: S, quat0: Array, rows: NDArray[np.intp]) -> None:
        """Start sensors ``rows`` afresh at ``quat0`` (len(rows), 4), keeping ``kept_on_restart``.

        Every array field whose first axis is the sensor takes the rows of a fresh state;
        nested state dataclasses (calibration-like memory) are kept. Methods with packed
        state override this.
        """
        fresh = self._new_state(quat0)
        n_sensors = state.quat.shape[0]
        for f in dataclasses.fields(state):
            if f.name in ("t_last_s", "ready", "screen") or f.name in self.kept_on_restart:
                continue
            current, new = getattr(state, f.name), getattr(fresh, f.name)
            if (
                isinstance(current, np.ndarray)
                and isinstance(new, np.ndarray)
                and current.ndim >= 1
                and current.shape[0] == n_sensors
                and new.shape[0] == len(rows)
            ):
                current[rows] = new

    def _method_flags(self, outputs: Mapping[str, NDArray[Any]]) -> NDArray[np.uint16] | None:
        """Flags the method itself raises, from its outputs (S, N); None: none."""
        out = None
        for key, bit in (("rest", Flag.REST), ("mag_disturbed", Flag.MAG_DISTURBED)):
            if key in outputs:
                part = np.where(outputs[key], np.uint16(bit), np.uint16(0))
                out = part if out is None else out | part
        return out

    # -- public entry points ----------------------------------------------------------------
    def update(
        self,
        gyr: ArrayLike | None,
        acc: ArrayLike,
        mag: ArrayLike | None = None,
        dt: float | None = None,
    ) -> Array:
        """Process one sample (shape (3,), or (S, 3) for S sensors); return the orientation.

        ``dt`` is the time since the previous sample in s; without it the ``rate_hz`` given
        at construction is used. Returns (4,) or (S, 4). The sample is screened like any
        other (a bad value is flagged in :attr:`flags` and not used); over the first
        samples the units are checked (deg/s and g are refused with the fix).
        """
        one = np.asarray(acc).ndim == 1

        def lift(x: ArrayLike | None) -> Array | None:
            return None if x is None else np.asarray(x, dtype=np.float64).reshape(-1, 1, 3)

        fresh = self._state is None or not np.isfinite(self._state.t_last_s)
        if dt is None and not fresh:
            if self.rate_hz is None:
                raise ValueError("update() needs dt (s) or an estimator built with rate_hz")
            dt = 1.0 / self.rate_hz
        t_prev = 0.0 if fresh else self._state.t_last_s
        t = np.array([t_prev + (0.0 if fresh else float(dt))])
        gyr_a, acc_a = lift(gyr), lift(acc)
        if not self._probe.done:
            self._probe.add(gyr_a if self.uses_gyr else None, acc_a, float(t[0]))
        est = self._run_arrays(gyr_a, acc_a, lift(mag), t, check_units=False)
        return est.quat[0, 0] if one else est.quat[:, 0]

    def run(
        self,
        data: Recording | Sequence[Recording] | None = None,
        *,
        gyr: ArrayLike | None = None,
        acc: ArrayLike | None = None,
        mag: ArrayLike | None = None,
        t: ArrayLike | None = None,
        rate_hz: float | None = None,
        gyr_unit: str = "rad/s",
        acc_unit: str = "m/s2",
        time_unit: str = "s",
        check_units: bool = True,
    ) -> Estimate:
        """Process a whole series in compiled code and return an :class:`Estimate`.

        Give a :class:`Recording`, a list of Recordings with equal timestamps (S sensors),
        or arrays ``gyr``/``acc``/``mag`` of shape (N, 3) or (S, N, 3) with timestamps
        ``t`` (N,) s or ``rate_hz`` (or the constructor's). Arrays are in rad/s, m/s² and s
        unless ``gyr_unit="deg/s"`` / ``acc_unit="g"`` / ``time_unit="ms"`` (or "us",
        "ns") say otherwise; the field in any unit. Units are checked (deg/s, g and
        timestamps in ms are refused with the fix; ``check_units=False`` skips it).
        Continues from the current state, so two half runs equal one whole run.
        """
        if data is not None:
            if any(x is not None for x in (gyr, acc, mag, t, rate_hz)):
                raise ValueError("give either a Recording or arrays, not both")
            recs = [data] if isinstance(data, Recording) else recordings(data)
            if not recs:
                raise ValueError("run() got an empty list of recordings")
            for r in recs[1:]:
                if r.t.shape != recs[0].t.shape or np.any(r.t != recs[0].t):
                    raise ValueError(
                        f"recording {r.name!r} has other timestamps than {recs[0].name!r}; "
                        "resample them onto common timestamps first"
                    )
            has_mag = [r.mag is not None for r in recs]
            if any(has_mag) and not all(has_mag):
                raise ValueError("either every recording or none must have a magnetometer")
            if time_unit != "s":
                raise ValueError(
                    "time_unit applies to arrays; convert a Recording with "
                    f"rec.with_units(time={time_unit!r})"
                )
            if check_units:
                for r in recs:
                    check_series_units(r.gyr, r.acc, path="recording", t=r.t)

            def stacked(name: str) -> Array:
                # a single recording is passed as a view: no copy of long series
                if len(recs) == 1:
                    return getattr(recs[0], name)[None]
                return np.stack([getattr(r, name) for r in recs])

            est = self._run_arrays(
                stacked("gyr") if self.uses_gyr else None,
                stacked("acc"),
                stacked("mag") if all(has_mag) else None,
                recs[0].t,
                check_units=False,
            )
            return squeezed(est) if isinstance(data, Recording) else est
        if acc is None:
            raise ValueError("run() needs a Recording or at least acc (and gyr) arrays")
        one = np.asarray(acc).ndim == 2
        n = np.asarray(acc).shape[-2] if np.asarray(acc).ndim >= 2 else 0
        times = self._timestamps(
            None if t is None else convert_unit(t, "time", time_unit), rate_hz, n
        )

        def lift(x: ArrayLike | None, scale: float = 1.0) -> Array | None:
            if x is None:
                return None
            arr = np.asarray(x, dtype=np.float64)
            if scale != 1.0:
                arr = arr * scale
            return arr[None] if arr.ndim == 2 else arr

        gyr_a = lift(gyr, scale_to_si("gyr", gyr_unit))
        acc_a = lift(acc, scale_to_si("acc", acc_unit))
        if check_units and t is not None:  # timestamps given, not a rate
            check_series_times(times, gyr_a, path="arrays")
        est = self._run_arrays(gyr_a, acc_a, lift(mag), times, check_units=check_units)
        return squeezed(est) if one else est

    # -- internals ------------------------------------------------------------------------
    def _timestamps(self, t: ArrayLike | None, rate_hz: float | None, n: int) -> Array:
        if t is not None:
            if rate_hz is not None:
                raise ValueError("give t or rate_hz, not both")
            return np.asarray(t, dtype=np.float64)
        rate = rate_hz if rate_hz is not None else self.rate_hz
        if rate is None:
            raise ValueError(
                "no sample times: pass t (s) or rate_hz, or build the estimator with rate_hz"
            )
        if not (np.isfinite(rate) and rate > 0):
            raise ValueError(f"rate_hz must be a finite number > 0, got {rate}")
        start = 0.0
        if self._state is not None and np.isfinite(self._state.t_last_s):
            start = self._state.t_last_s + 1.0 / rate
        return start + np.arange(n) / rate

    def _validated(
        self,
        gyr: ArrayLike | None,
        acc: ArrayLike,
        mag: ArrayLike | None,
        t: Array,
        *,
        check_units: bool = False,
    ) -> Inputs:
        """Shapes checked, arrays (S, N, 3); with ``check_units`` also deg/s and g refused."""
        acc_a = signal_array(acc, "acc")
        n = acc_a.shape[1]
        if n == 0:
            raise ValueError("no samples to process (acc has N = 0)")
        gyr_a = None
        if self.uses_gyr:
            if gyr is None:
                raise ValueError(f"method {self.name!r} needs gyroscope data (gyr)")
            gyr_a = signal_array(gyr, "gyr", acc_a.shape)
        mag_a = None
        if mag is not None:
            mag_a = signal_array(mag, "mag", acc_a.shape)
        elif not self.mag_optional:
            raise ValueError(
                f"method {self.name!r} needs a magnetometer; give mag or choose a method "
                "that supports 6-D (accelerometer + gyroscope) estimation"
            )
        if t.shape != (n,):
            raise ValueError(f"t must have shape ({n},), got {t.shape}")
        if check_units:
            check_series_units(gyr_a, acc_a, path="arrays")
        return Inputs(t=t, gyr=gyr_a, acc=acc_a, mag=mag_a)

    def _fresh_state(self, n_sensors: int) -> S:
        state = self._new_state(np.tile(_IDENTITY, (n_sensors, 1)))
        state.ready = np.zeros(n_sensors, dtype=bool)
        state.screen = screening.ScreenState.new(n_sensors)
        return state

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
        n_sensors = x.acc.shape[0]
        state = self._state
        if state is not None and state.quat.shape[0] != n_sensors:
            raise ValueError(
                f"the state holds {state.quat.shape[0]} sensor(s) but the data has {n_sensors}; "
                "reset() first"
            )
        # work on a copy so a failing call leaves the estimator as it was
        work = self._fresh_state(n_sensors) if state is None else state.copy()
        if work.ready is None:
            work.ready = np.ones(n_sensors, dtype=bool)
        if work.screen is None:
            work.screen = screening.ScreenState.new(n_sensors)
        scr = screening.screen(
            work.screen, work.t_last_s, self._screen_coef, x.t, x.gyr, x.acc, x.mag
        )
        if self._params.strict:
            problem = first_problem(scr.flags)
            if problem is not None:
                raise ValueError(f"{problem} (strict=True; strict=False flags and skips it)")
        q, outputs = self._process_segments(work, scr)
        work.t_last_s = scr.t_last_s
        flags = scr.flags
        extra = self._method_flags(outputs)
        if extra is not None:
            flags |= extra.astype(np.uint16)
        self._state = work
        self._last_flags = flags[:, -1].copy()
        return Estimate(
            quat=q,
            t=x.t.copy(),
            frame=self._params.frame,
            method=self.name,
            params=dict(self._params_dict),
            outputs=outputs,
            flags=flags,
        )

    def _process_segments(
        self, work: S, scr: screening.Screened
    ) -> tuple[Array, dict[str, NDArray[Any]]]:
        """Run the kernel between restarts: (re)initialise each sensor at its first usable
        sample after the start or a gap; hold the output of sensors not initialised yet."""
        n = scr.acc.shape[1]
        assert work.ready is not None
        gap = (scr.flags[0] & Flag.GAP) != 0
        gap_at = np.flatnonzero(gap)
        usable: NDArray[np.bool_] | None = None
        pieces: list[tuple[Array, dict[str, NDArray[Any]]]] = []
        pos = 0
        while pos < n:
            if gap[pos]:
                work.ready[:] = False
            later_gaps = gap_at[gap_at > pos]
            end = int(later_gaps[0]) if later_gaps.size else n
            waiting = np.flatnonzero(~work.ready)
            starts: list[int] = []
            started_all = False
            if waiting.size:
                if usable is None:
                    usable = self._usable(scr)
                for s in waiting:
                    hits = np.flatnonzero(usable[s, pos:end])
                    if hits.size and hits[0] == 0:
                        starts.append(s)
                    elif hits.size:
                        end = min(end, pos + int(hits[0]))
                if starts:
                    rows = np.array(starts, dtype=np.intp)
                    mag0 = None if scr.mag is None else scr.mag[rows, pos]
                    self._restart(work, self._start_quat(scr.acc[rows, pos], mag0), rows)
                    work.ready[rows] = True
                    started_all = len(starts) == int(np.count_nonzero(work.ready))
            held = np.flatnonzero(~work.ready)
            frozen = rows_of(work, held) if held.size else {}
            seg = slice(pos, end)
            dt = scr.dt[seg].copy()
            if waiting.size and starts and started_all:
                # the measured orientation is that of this sample: nothing to integrate
                # (sensors that start while others continue integrate one interval)
                dt[0] = 0.0
            q, out = self._process(
                work,
                scr.gyr[:, seg] if self.uses_gyr else None,
                scr.acc[:, seg],
                None if scr.mag is None else scr.mag[:, seg],
                dt,
            )
            if held.size:
                # sensors not started yet went through the kernel in lockstep: their
                # output is the held orientation and their state is as it was
                for name, rows in frozen.items():
                    getattr(work, name)[held] = rows
                q[held] = work.quat[held][:, None, :]
                scr.flags[held, seg] |= np.uint16(Flag.INITIALISING)
            pieces.append((q, out))
            pos = end
        if len(pieces) == 1:
            return pieces[0]
        q = np.concatenate([p[0] for p in pieces], axis=1)
        outputs = {
            key: np.concatenate([p[1][key] for p in pieces], axis=1) for key in pieces[0][1]
        }
        return q, outputs

    def _start_quat(self, acc0: Array, mag0: Array | None) -> Array:
        """Initial orientations (k, 4); rows whose field is unusable start from acc alone."""
        if mag0 is None:
            return self._initial_quat(acc0, None)
        no_mag = ~(np.linalg.norm(mag0, axis=-1) > 0)
        if not no_mag.any():
            return self._initial_quat(acc0, mag0)
        q0 = np.empty((acc0.shape[0], 4))
        q0[no_mag] = self._initial_quat(acc0[no_mag], None)
        if (~no_mag).any():
            q0[~no_mag] = self._initial_quat(acc0[~no_mag], mag0[~no_mag])
        return q0

    def _usable(self, scr: screening.Screened) -> NDArray[np.bool_]:
        """(S, N) samples that can (re)initialise the method."""
        if scr.mag is None:
            return usable_for_init(scr.acc, None)
        with_mag = usable_for_init(scr.acc, scr.mag)
        if not self.mag_optional:
            return with_mag
        # a mag-optional method starts from the accelerometer when the field is unusable
        no_field = ~(np.linalg.norm(scr.mag, axis=-1) > 0)
        return with_mag | (usable_for_init(scr.acc, None) & no_field)


