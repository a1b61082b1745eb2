"""The estimator contract: parameters, state, ``update``/``run`` and the ``Estimate`` they return.

Every estimator and filter in margtrack subclasses :class:`Estimator` so the CLI, the
benchmarks and the live engine can swap them:

- parameters are a frozen dataclass validated at construction (:class:`Params`);
- state is separate, complete, readable and settable (``state``, ``reset(q0=None)``);
- ``update(gyr, acc, mag=None, dt=None)`` processes one sample (or one per sensor);
- ``run(recording_or_arrays)`` processes a series, for S sensors at once, in one kernel call.

``update`` is ``run`` on one sample: one implementation, so N updates equal one run.

Timing rule: the first sample after :meth:`Estimator.reset` yields the initial orientation
(``q0`` or the one measured by accelerometer and magnetometer); every later sample ``i``
is propagated over ``dt_i = t_i - t_{i-1}`` with gyro sample ``i`` (it covers
``(t_{i-1}, t_i]``). Sample times are never assumed: they come from timestamps,
an explicit ``dt`` or the ``rate_hz`` given to the constructor.
"""

from __future__ import annotations

import copy
import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Generic, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.frames import Frame
from margtrack.kernels import triad as triad_kernel
from margtrack.recording import Recording, check_unit_magnitudes

Array = NDArray[np.float64]

__all__ = ["Estimate", "Estimator", "Params", "State", "initial_orientation"]


@dataclass(frozen=True)
class Params:
    """Parameters shared by every method.

    frame : earth frame of the output orientation, "NED" or "ENU" (default "ENU", the frame
        of BROAD and most robotics data; the seeds use NED).
    """

    frame: Frame = "ENU"

    def __post_init__(self) -> None:
        object.__setattr__(self, "frame", frames.check_frame(self.frame))

    def as_dict(self) -> dict[str, Any]:
        """Parameters as a plain dict (arrays as lists), for reports and JSON."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            out[f.name] = value.tolist() if isinstance(value, np.ndarray) else value
        return out


@dataclass
class State:
    """State shared by every method: the orientation of each sensor and the clock.

    quat : (S, 4) orientation after the last processed sample.
    t_last_s : time of the last processed sample, s (``nan`` before the first sample).
    """

    quat: Array
    t_last_s: float = float("nan")

    def copy(self) -> State:
        """An independent copy (the kernels update state arrays in place).

        Arrays and nested state dataclasses are copied (the latter by their own
        ``copy()``), containers deep-copied, scalars shared; cheaper than a generic
        deep copy, which ``update`` would otherwise pay on every sample.
        """
        values = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray) or dataclasses.is_dataclass(value):
                value = value.copy()  # a nested state dataclass provides its own copy()
            elif isinstance(value, (list, dict, set)):
                value = copy.deepcopy(value)
            values[f.name] = value
        return type(self)(**values)


@dataclass(frozen=True)
class Estimate:
    """The orientation series an estimator produced, and what else it knows.

    quat : (N, 4) or (S, N, 4) orientation of the body in ``frame``, [w, x, y, z].
    t : (N,) sample times, s.
    frame : earth frame of ``quat``.
    method : registered method name.
    params : the parameters used, as a dict.
    outputs : further per-sample series with units in their names (for example
        ``gyr_bias_rad_s`` (…, N, 3) or ``degenerate`` (…, N) flags).
    """

    quat: Array
    t: Array
    frame: Frame
    method: str
    params: Mapping[str, Any]
    outputs: Mapping[str, NDArray[Any]] = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.shape[0])

    def euler(self) -> Array:
        """ZYX Euler angles [yaw, pitch, roll] in rad, shape of ``quat`` with 3 last."""
        return quat.to_euler(self.quat)

    def in_frame(self, frame: str) -> Estimate:
        """The same estimate with orientations expressed in another earth frame."""
        target = frames.check_frame(frame)
        if target == self.frame:
            return self
        return dataclasses.replace(
            self, quat=frames.convert(self.quat, self.frame, target), frame=target
        )


def initial_orientation(acc: ArrayLike, mag: ArrayLike | None, frame: str) -> Array:
    """Orientation measured from one accelerometer (and magnetometer) sample per sensor.

    acc (S, 3) any units, mag (S, 3) or None; returns (S, 4) body-to-``frame``. With a
    magnetometer this is TRIAD (heading from the horizontal field); without one it is the
    shortest arc taking the measured acceleration to up (heading left as it falls).
    Raises ``ValueError`` for a zero accelerometer vector or one parallel to the field.
    """
    acc = np.ascontiguousarray(acc, dtype=np.float64).reshape(-1, 3)
    up = frames.up(frame)
    norms = np.linalg.norm(acc, axis=1)
    if np.any(~(norms > 0)):
        s = int(np.flatnonzero(~(norms > 0))[0])
        raise ValueError(
            f"cannot initialise sensor {s}: its first accelerometer sample is zero; "
            "pass q0 to reset() or drop the leading samples"
        )
    if mag is None:
        return quat.shortest_arc(acc, up)
    mag = np.ascontiguousarray(mag, dtype=np.float64).reshape(-1, 3)
    north = frames.mag_reference(frame, dip_deg=0.0)
    out = np.empty((acc.shape[0], 4))
    flags = np.empty(acc.shape[0], dtype=np.int8)
    triad_kernel.triad(acc, mag, up, north, out, flags)
    if np.any(flags != triad_kernel.OK):
        s = int(np.flatnonzero(flags != triad_kernel.OK)[0])
        why = {
            triad_kernel.ZERO_MAG: "its magnetometer sample is zero",
            triad_kernel.PARALLEL: "its accelerometer and magnetometer are parallel",
        }.get(int(flags[s]), "its sample is degenerate")
        raise ValueError(
            f"cannot initialise sensor {s} from its first sample: {why}; "
            "pass q0 to reset() or drop the leading samples"
        )
    return out


P = TypeVar("P", bound=Params)
S = TypeVar("S", bound=State)


@dataclass
class _Inputs:
    t: Array  # (N,)
    gyr: Array | None  # (S, N, 3)
    acc: Array  # (S, N, 3)
    mag: Array | None  # (S, N, 3)


class Estimator(ABC, Generic[P, S]):
    """Base of every margtrack estimator: validation, timing, state and the Estimate.

    Subclasses set ``name`` and ``params_type`` and implement :meth:`_new_state` and
    :meth:`_process`, which runs the method's kernel over S sensors and N samples.

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
        if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz}")
        self.rate_hz = rate_hz
        self._state: S | None = None

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

    def reset(self, q0: ArrayLike | None = None) -> None:
        """Forget the state; with ``q0`` ((4,) or (S, 4)) start from that orientation.

        Without ``q0`` the next sample's accelerometer and magnetometer set it.
        """
        if q0 is None:
            self._state = None
            return
        q = quat.normalize(np.asarray(q0, dtype=np.float64).reshape(-1, 4))
        self._state = self._new_state(q)

    # -- method-specific ----------------------------------------------------------------
    @abstractmethod
    def _new_state(self, quat0: Array) -> S:
        """Fresh state for S sensors starting at ``quat0`` (S, 4)."""

    @abstractmethod
    def _process(
        self, state: S, gyr: Array | None, acc: Array, mag: Array | None, dt: Array
    ) -> tuple[Array, dict[str, NDArray[Any]]]:
        """Run the kernel: arrays (S, N, 3), ``dt`` (N,) with dt[0] = 0 after a reset.

        Updates ``state`` in place; returns quat (S, N, 4) and outputs with (S, N, ...) arrays.
        """

    def _initial_quat(self, acc0: Array, mag0: Array | None) -> Array:
        """Initial orientation (S, 4) from the first sample of each sensor."""
        return initial_orientation(acc0, mag0, self._params.frame)

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
        at construction is used. Returns (4,) or (S, 4).
        """
        one = np.asarray(acc).ndim == 1

        def lift(x: ArrayLike | None) -> ArrayLike | None:
            return None if x is None else np.asarray(x, dtype=np.float64).reshape(-1, 1, 3)

        fresh = self._state is None or not np.isfinite(self._state.t_last_s)
        if dt is None and not fresh:
            if self.rate_hz is None:
                raise ValueError("update() needs dt (s) or an estimator built with rate_hz")
            dt = 1.0 / self.rate_hz
        t_prev = 0.0 if fresh else self._state.t_last_s
        t = np.array([t_prev + (0.0 if fresh else float(dt))])
        est = self._run_arrays(lift(gyr), lift(acc), lift(mag), t, check_units=False)
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
        check_units: bool = True,
    ) -> Estimate:
        """Process a whole series in compiled code and return an :class:`Estimate`.

        Give a :class:`Recording`, a list of Recordings with equal timestamps (S sensors),
        or arrays ``gyr``/``acc``/``mag`` of shape (N, 3) or (S, N, 3) in rad/s, m/s² and
        any field unit, with timestamps ``t`` (N,) s or ``rate_hz`` (or the constructor's).
        Continues from the current state, so two half runs equal one whole run.
        """
        if data is not None:
            if any(x is not None for x in (gyr, acc, mag, t, rate_hz)):
                raise ValueError("give either a Recording or arrays, not both")
            recs = [data] if isinstance(data, Recording) else list(data)
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
            if isinstance(data, Recording):
                return dataclasses.replace(
                    est, quat=est.quat[0], outputs={k: v[0] for k, v in est.outputs.items()}
                )
            return est
        if acc is None:
            raise ValueError("run() needs a Recording or at least acc (and gyr) arrays")
        one = np.asarray(acc).ndim == 2
        n = np.asarray(acc).shape[-2] if np.asarray(acc).ndim >= 2 else 0
        times = self._timestamps(t, rate_hz, n)

        def lift(x: ArrayLike | None) -> ArrayLike | None:
            if x is None:
                return None
            arr = np.asarray(x, dtype=np.float64)
            return arr[None] if arr.ndim == 2 else arr

        est = self._run_arrays(lift(gyr), lift(acc), lift(mag), times, check_units=check_units)
        if one:
            return dataclasses.replace(
                est, quat=est.quat[0], outputs={k: v[0] for k, v in est.outputs.items()}
            )
        return est

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
        self, gyr: ArrayLike | None, acc: ArrayLike, mag: ArrayLike | None, t: Array
    ) -> _Inputs:
        acc_a = _signal(acc, "acc")
        n = acc_a.shape[1]
        if n == 0:
            raise ValueError("no samples to process (acc has N = 0)")
        gyr_a = None
        if self.uses_gyr:
            if gyr is None:
                raise ValueError(f"method {self.name!r} needs gyroscope data (gyr)")
            gyr_a = _signal(gyr, "gyr", acc_a.shape)
        mag_a = None
        if mag is not None:
            mag_a = _signal(mag, "mag", acc_a.shape)
        elif not self.mag_optional:
            raise ValueError(
                f"method {self.name!r} needs a magnetometer; give mag or choose a method "
                "that supports 6-D (accelerometer + gyroscope) estimation"
            )
        if t.shape != (n,):
            raise ValueError(f"t must have shape ({n},), got {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ValueError(f"t has a non-finite value at sample {int(np.argmin(np.isfinite(t)))}")
        steps = np.diff(t) if n > 1 else t[:0]
        if np.any(steps <= 0):
            i = int(np.flatnonzero(steps <= 0)[0]) + 1
            raise ValueError(
                f"timestamps must increase strictly: t[{i - 1}] = {float(t[i - 1])!r}, "
                f"t[{i}] = {float(t[i])!r}"
            )
        return _Inputs(t=t, gyr=gyr_a, acc=acc_a, mag=mag_a)

    def _run_arrays(
        self,
        gyr: ArrayLike | None,
        acc: ArrayLike,
        mag: ArrayLike | None,
        t: Array,
        *,
        check_units: bool,
    ) -> Estimate:
        x = self._validated(gyr, acc, mag, t)
        if check_units:
            for s in range(x.acc.shape[0]):
                check_unit_magnitudes(x.gyr[s] if x.gyr is not None else np.zeros((0, 3)), x.acc[s])
        n_sensors = x.acc.shape[0]
        dt = np.empty_like(x.t)
        if dt.shape[0] > 1:
            dt[1:] = np.diff(x.t)
        state = self._state
        if state is not None and state.quat.shape[0] != n_sensors:
            raise ValueError(
                f"the state holds {state.quat.shape[0]} sensor(s) but the data has {n_sensors}; "
                "reset() first"
            )
        if state is None:
            q0 = self._initial_quat(x.acc[:, 0], None if x.mag is None else x.mag[:, 0])
            state = self._new_state(q0)
        if np.isfinite(state.t_last_s):
            dt[0] = x.t[0] - state.t_last_s
            if not dt[0] > 0:
                raise ValueError(
                    f"the first timestamp {float(x.t[0])!r} is not after the last processed one "
                    f"{state.t_last_s!r}; timestamps must increase across runs"
                )
        else:
            dt[0] = 0.0
        # work on a copy so a failing kernel call leaves the estimator as it was
        work = state.copy()
        q, outputs = self._process(work, x.gyr, x.acc, x.mag, dt)
        work.t_last_s = float(x.t[-1])
        self._state = work
        return Estimate(
            quat=q,
            t=x.t.copy(),
            frame=self._params.frame,
            method=self.name,
            params=dict(self._params_dict),
            outputs=outputs,
        )


def _signal(value: ArrayLike, name: str, like: tuple[int, ...] | None = None) -> Array:
    """(S, N, 3) float64 contiguous, finite, with a message naming the bad sample."""
    try:
        arr = np.ascontiguousarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    if arr.ndim != 3 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (N, 3) or (S, N, 3), got {arr.shape}")
    if like is not None and arr.shape != like:
        raise ValueError(f"{name} has shape {arr.shape} but acc has {like}")
    finite = np.isfinite(arr)
    if not finite.all():
        s, i, _ = (int(v) for v in np.argwhere(~finite)[0])
        where = f"sample {i}" if arr.shape[0] == 1 else f"sensor {s}, sample {i}"
        raise ValueError(
            f"{name} has a non-finite value (NaN or inf) at {where}: {arr[s, i]}; "
            "remove or interpolate the gap first"
        )
    return arr
