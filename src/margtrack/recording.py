"""Recording: one sensor's timestamped MARG signals, optional ground truth, and their validation.

Units inside a Recording are always SI: time in s, angular rate in rad/s, specific force
in m/s², magnetic field in any consistent unit (µT preferred). :meth:`Recording.with_units`,
:meth:`Recording.from_arrays` and the readers (``margtrack.io.read(..., gyr_unit=...)``)
convert declared units (:mod:`margtrack.units`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.frames import Frame, check_frame
from margtrack.units import (
    check_unit_magnitudes,
    convert_unit,
    unit_factor,
    unit_fix_keyword,
)

Array = NDArray[np.float64]

__all__ = ["Recording", "Saturation", "find_saturation", "resample"]


def _array(
    value: ArrayLike, name: str, width: int | None, n: int | None = None, n_name: str = "t",
    nan_rows: bool = False,
) -> Array:
    try:
        arr = np.array(value, dtype=np.float64)  # a copy: the caller keeps its own array
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    if width is None:
        if arr.ndim != 1:
            raise ValueError(f"{name} must have shape (N,), got {arr.shape}")
    elif arr.ndim != 2 or arr.shape[1] != width:
        raise ValueError(
            f"{name} must have shape (N, {width}) with samples as rows, got {arr.shape}"
        )
    if n is not None and arr.shape[0] != n:
        raise ValueError(f"{name} has {arr.shape[0]} samples but {n_name} has {n}")
    bad = np.isinf(arr) if nan_rows else ~np.isfinite(arr)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        if nan_rows:
            raise ValueError(
                f"{name} has an infinite value at sample {row}: {arr[row]}; mark a sample "
                "without truth with NaN"
            )
        raise ValueError(
            f"{name} has a non-finite value (NaN or inf) at sample {row}: {arr[row]}; "
            "remove or interpolate the gap before building the Recording"
        )
    return arr


def _check_timestamps(t: Array) -> None:
    if t.shape[0] == 0:
        raise ValueError("a Recording needs at least one sample, got 0")
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0.0)
    if bad.size:
        i = int(bad[0]) + 1
        kind = "duplicate" if steps[bad[0]] == 0.0 else "non-monotonic"
        raise ValueError(
            f"{kind} timestamp at sample {i}: t[{i - 1}] = {float(t[i - 1])!r}, "
            f"t[{i}] = {float(t[i])!r}; "
            "timestamps must be strictly increasing seconds"
        )


@dataclass(frozen=True)
class Saturation:
    """Where a signal sits at its range limit: first sample, how many samples, the level."""

    first_sample: int
    n_samples: int
    level: float


def _runs(flags: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Start indices and lengths of the runs of True in ``flags``."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return starts, stops - starts


def find_saturation(
    values: Array, hold_factor: float = 4.0, peak_ratio: float = 3.0
) -> Saturation | None:
    """Samples where an axis is pinned at the signal's extreme value (a clipped sensor).

    ``values`` (N, 3). An axis counts as saturated where ``|x|`` equals its maximum over
    the recording for a run of consecutive samples at least ``hold_factor`` times as long
    as the axis' usual run of repeated values (a slower sensor resampled by holding
    repeats each value for a few samples anyway) and at least 5, and that maximum is at
    least ``peak_ratio`` times the axis' median ``|x|`` (so a quiet, quantised signal whose
    few levels repeat is not taken for a clipped one). Returns None if no axis is.
    """
    first, count, level = None, 0, 0.0
    for axis in np.asarray(values, dtype=np.float64).T:
        mag = np.abs(axis)
        peak = float(mag.max(initial=0.0))
        if peak <= 0.0 or peak < peak_ratio * float(np.median(mag)):
            continue
        at_peak = mag >= peak
        # the usual hold: median length of runs of identical values away from the peak
        repeats = np.concatenate([np.diff(axis) == 0.0, [False]]) & ~at_peak
        _, repeat_lengths = _runs(repeats)
        usual = float(np.median(repeat_lengths + 1)) if repeat_lengths.size else 1.0
        starts, lengths = _runs(at_peak)
        long = lengths >= max(5.0, hold_factor * usual)
        if long.any():
            count += int(np.sum(lengths[long]))
            start = int(starts[long][0])
            if first is None or start < first:
                first, level = start, peak
    return None if first is None else Saturation(first, count, level)


@dataclass(frozen=True, eq=False)
class Recording:
    """One MARG sensor's signals on common timestamps, with optional ground truth.

    Attributes
    ----------
    t : (N,) float64, s, strictly increasing.
    gyr : (N, 3) body angular rate, rad/s.
    acc : (N, 3) body specific force, m/s² (at rest it points up).
    mag : (N, 3) body magnetic field (µT preferred) or None.
    quat_true : (N, 4) true orientation ``[w, x, y, z]`` of the body in ``frame`` or None;
        rows with a NaN are holes in the truth (stored as all-NaN rows, skipped by the
        metrics, counted by :attr:`truth_valid`).
    movement : (N,) bool mask of samples that count for error metrics, or None (all count).
    frame : earth frame of ``quat_true`` ("NED" or "ENU").
    name : a label (trial or sensor name).
    meta : free-form provenance (source file, original units...).

    Construction validates shapes, finiteness and timestamps and raises ``ValueError``
    naming the first bad sample. Unit heuristics are applied by :meth:`from_arrays` and
    the readers, which can also convert units.
    """

    t: Array
    gyr: Array
    acc: Array
    mag: Array | None = None
    quat_true: Array | None = None
    movement: NDArray[np.bool_] | None = None
    frame: Frame = "ENU"
    name: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _array(self.t, "t", None)
        _check_timestamps(t)
        n = t.shape[0]
        set_ = object.__setattr__
        set_(self, "t", t)
        set_(self, "gyr", _array(self.gyr, "gyr", 3, n))
        set_(self, "acc", _array(self.acc, "acc", 3, n))
        if self.mag is not None:
            set_(self, "mag", _array(self.mag, "mag", 3, n))
        if self.quat_true is not None:
            # truth may have holes (an optical system losing the markers): a row with a NaN
            # is all NaN, and the metrics skip it
            q = _array(self.quat_true, "quat_true", 4, n, nan_rows=True)
            q[np.isnan(q).any(axis=1)] = np.nan
            norms = np.linalg.norm(q, axis=1)
            bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-3)  # NaN rows compare False
            if bad.size:
                raise ValueError(
                    f"quat_true is not a unit quaternion at sample {int(bad[0])} "
                    f"(norm {norms[bad[0]]:.6f})"
                )
            # rescale only rows that need it, so building a Recording from a Recording's
            # arrays (readers, slice) reproduces them bit for bit
            off = np.abs(norms - 1.0) > 1e-12  # False on NaN rows
            q[off] /= norms[off, None]
            set_(self, "quat_true", q)
        if self.movement is not None:
            m = np.array(self.movement)
            if m.shape != (n,):
                raise ValueError(f"movement must have shape ({n},), got {m.shape}")
            if m.dtype != bool:
                bad = np.flatnonzero(~np.isin(m, (0, 1)))
                if bad.size:
                    raise ValueError(
                        f"movement must be boolean (or 0/1), got {m[bad[0]]!r} at sample "
                        f"{int(bad[0])}"
                    )
            set_(self, "movement", m.astype(bool))
        set_(self, "frame", check_frame(self.frame))
        set_(self, "meta", dict(self.meta))
        for name in ("t", "gyr", "acc", "mag", "quat_true", "movement"):
            value = getattr(self, name)
            if value is not None:
                value.flags.writeable = False

    @classmethod
    def from_arrays(
        cls,
        gyr: ArrayLike,
        acc: ArrayLike,
        mag: ArrayLike | None = None,
        *,
        t: ArrayLike | None = None,
        rate_hz: float | None = None,
        gyr_unit: str = "rad/s",
        acc_unit: str = "m/s2",
        time_unit: str = "s",
        check_units: bool = True,
        **fields: Any,
    ) -> Recording:
        """Build a Recording from arrays in any supported unit.

        Give either timestamps ``t`` (in ``time_unit``: "s", "ms", "us", "ns") or a
        constant ``rate_hz``; there is no default rate. ``gyr_unit`` is "rad/s" or "deg/s",
        ``acc_unit`` "m/s2" or "g"; values are converted to SI. With ``check_units``
        (default) data whose magnitudes look like deg/s or g, or timestamps like ms read
        as s, is refused with the fix in the message. Other keyword arguments
        (``quat_true``, ``movement``, ``frame``, ``name``, ``meta``) go to the constructor.
        """
        gyr_factor, acc_factor = unit_factor("gyr", gyr_unit), unit_factor("acc", acc_unit)
        gyr_arr = _array(gyr, "gyr", 3) * gyr_factor
        acc_arr = _array(acc, "acc", 3) * acc_factor
        n = gyr_arr.shape[0]
        if (t is None) == (rate_hz is None):
            raise ValueError(
                "give exactly one of t (timestamps in s) or rate_hz; no rate is assumed"
            )
        if t is None:
            if not (rate_hz is not None and np.isfinite(rate_hz) and rate_hz > 0):
                raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz}")
            t = np.arange(n) / float(rate_hz)
            checked_t = None  # a rate is a declaration, not timestamps to judge
        else:
            t = checked_t = convert_unit(t, "time", time_unit)
        if check_units:
            check_unit_magnitudes(
                gyr_arr, acc_arr, fix=unit_fix_keyword("from_arrays"), t_s=checked_t
            )
        return cls(t=t, gyr=gyr_arr, acc=acc_arr, mag=mag, **fields)

    @property
    def truth_valid(self) -> NDArray[np.bool_] | None:
        """(N,) True where ``quat_true`` is known (not a hole); None without truth."""
        if self.quat_true is None:
            return None
        return ~np.isnan(self.quat_true).any(axis=1)

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.shape[0])

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample, s."""
        return float(self.t[-1] - self.t[0])

    @property
    def rate_hz(self) -> float:
        """Median sample rate, Hz (``nan`` for a single sample)."""
        if self.n_samples < 2:
            return float("nan")
        return float(1.0 / np.median(np.diff(self.t)))

    @property
    def dt(self) -> Array:
        """Sample intervals (N-1,), s."""
        return np.diff(self.t)

    def gaps(self, factor: float = 1.5) -> NDArray[np.intp]:
        """Indices ``i`` where ``t[i] - t[i-1]`` exceeds ``factor`` times the median interval."""
        if self.n_samples < 3:
            return np.zeros(0, dtype=np.intp)
        steps = np.diff(self.t)
        return np.flatnonzero(steps > factor * np.median(steps)) + 1

    def slice(self, start: int | None = None, stop: int | None = None) -> Recording:
        """Samples ``start:stop`` as a new Recording (timestamps kept, not shifted)."""
        s = np.s_[start:stop]
        return replace(
            self,
            t=self.t[s],
            gyr=self.gyr[s],
            acc=self.acc[s],
            mag=None if self.mag is None else self.mag[s],
            quat_true=None if self.quat_true is None else self.quat_true[s],
            movement=None if self.movement is None else self.movement[s],
        )

    def saturation(self) -> dict[str, Saturation]:
        """Signals pinned at their range limit (see :func:`find_saturation`), by name."""
        found = {}
        for name in ("gyr", "acc", "mag"):
            values = getattr(self, name)
            if values is not None:
                hit = find_saturation(values)
                if hit is not None:
                    found[name] = hit
        return found

    def without_mag(self) -> Recording:
        """The same recording with the magnetometer removed (for 6-D estimation)."""
        return replace(self, mag=None)

    def with_units(
        self,
        *,
        gyr: str | None = None,
        acc: str | None = None,
        mag: str | None = None,
        time: str | None = None,
    ) -> Recording:
        """A new Recording converted to SI (and µT) from the units its arrays are really in.

        Use it when a file or arrays hold other units than the Recording's (a logger writing
        deg/s into a column the reader takes for rad/s).

        Parameters
        ----------
        gyr : unit of ``self.gyr``: "rad/s" or "deg/s"; converted to rad/s.
        acc : unit of ``self.acc``: "m/s2" (also "m/s^2", "m/s²") or "g" (9.80665 m/s²);
            converted to m/s².
        mag : unit of ``self.mag``: "uT" ("µT"), "nT", "mT", "T", "G" (gauss) or "mG";
            converted to µT. Ignored when the recording has no magnetometer.
        time : unit of ``self.t``: "s", "ms", "us" ("µs") or "ns"; converted to s.
            None (every argument's default) means the values are already in the library's unit.

        Returns
        -------
        The converted Recording; ``meta["units_converted"]`` maps each converted signal
        ("gyr", "acc", "mag", "time") to the unit it was converted from (declarations that
        change nothing, like ``gyr="rad/s"``, are not recorded).

        Raises
        ------
        ValueError : for an unknown unit (listing the valid ones), or when a signal that
            ``meta["units_converted"]`` says was already converted is declared again in a
            non-SI unit (converting twice is always wrong).
        """
        declared = {"gyr": gyr, "acc": acc, "mag": mag, "time": time}
        done = dict(self.meta.get("units_converted") or {})
        changes: dict[str, Any] = {}
        converted: dict[str, str] = {}
        for signal, unit in declared.items():
            if unit is None:
                continue
            if unit_factor(signal, unit) == 1.0 or (signal == "mag" and self.mag is None):
                continue
            if signal in done:
                raise ValueError(
                    f"{signal} was already converted from {done[signal]} "
                    f"(meta['units_converted']); declaring {signal} in {unit} again would "
                    "convert it twice: leave the declaration out"
                )
            name = "t" if signal == "time" else signal
            changes[name] = convert_unit(getattr(self, name), signal, unit)
            converted[signal] = unit
        if not converted:
            return replace(self)
        meta = {**self.meta, "units_converted": {**done, **converted}}
        return replace(self, meta=meta, **changes)


def resample(t_src: ArrayLike, values: ArrayLike, t_dst: ArrayLike) -> Array:
    """Linear interpolation of a slower sensor's samples onto other timestamps (004, Overview).

    The way to put sensors logged at different rates on common timestamps, the gyroscope's
    (``margtrack.io.read`` does it for a folder of per-sensor files)::

        acc_on_gyr = margtrack.resample(t_acc_s, acc_m_s2, t_gyr_s)   # (N, 3)

    Parameters
    ----------
    t_src : (M,) the source timestamps, s, strictly increasing.
    values : (M, K) or (M,) the source samples, any unit (kept); finite.
    t_dst : (N,) the timestamps to interpolate at, s.

    Returns
    -------
    (N, K) float64: linear interpolation between the two source samples around each
    ``t_dst``; outside the span of ``t_src`` the nearest sample is held (no extrapolation).
    """
    ts = _array(t_src, "t_src", None)
    _check_timestamps(ts)
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    v = _array(v, "values", v.shape[1], ts.shape[0], n_name="t_src")
    td = _array(t_dst, "t_dst", None)
    return np.stack([np.interp(td, ts, v[:, k]) for k in range(v.shape[1])], axis=1)
