"""Units: the one table of the units a signal may be given in, conversion, and unit checks.

Inside margtrack: rad/s, m/s², µT (the field may be any unit) and s. A signal declared in
another unit is converted with :func:`convert_unit`; :func:`check_unit_magnitudes`
refuses data whose magnitudes betray a unit mix-up (gyr in deg/s, acc in g, timestamps in
ms, µs or ns read as s) with a :class:`UnitError` whose message names the fix on the
caller's path; :class:`IntervalProbe` applies the timestamp rule to a stream, sample by
sample.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.frames import STANDARD_GRAVITY_M_S2

Array = NDArray[np.float64]

__all__ = [
    "ACC_UNITS",
    "GYR_UNITS",
    "MAG_UNITS",
    "SI_UNITS",
    "TIME_UNITS",
    "UNITS",
    "IntervalProbe",
    "UnitError",
    "check_unit_magnitudes",
    "convert_unit",
    "unit_factor",
    "unit_fix_api",
    "unit_fix_keyword",
]

# The one declaration of every unit a signal can be given in: value in the library's unit =
# value in the declared unit * factor. gyr -> rad/s, acc -> m/s², mag -> µT, time -> s.
GYR_UNITS: Mapping[str, float] = {"rad/s": 1.0, "deg/s": np.pi / 180.0}
ACC_UNITS: Mapping[str, float] = {
    "m/s2": 1.0, "m/s^2": 1.0, "m/s²": 1.0, "g": STANDARD_GRAVITY_M_S2,
}
MAG_UNITS: Mapping[str, float] = {
    "uT": 1.0, "µT": 1.0, "nT": 1e-3, "mT": 1e3, "G": 100.0, "mG": 0.1, "T": 1e6,
}
TIME_UNITS: Mapping[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}
UNITS: Mapping[str, Mapping[str, float]] = {
    "gyr": GYR_UNITS, "acc": ACC_UNITS, "mag": MAG_UNITS, "time": TIME_UNITS,
}
SI_UNITS: Mapping[str, str] = {"gyr": "rad/s", "acc": "m/s2", "mag": "uT", "time": "s"}

# Above this many rad/s on any axis a MEMS gyroscope (ranges up to ±2000 deg/s = 34.9 rad/s)
# cannot have measured it; the numbers are almost certainly deg/s.
_GYR_RAD_S_IMPLAUSIBLE = 40.0
# A recording's median acceleration norm is about 9.8 in m/s²; between these bounds it is in g.
_ACC_G_LIKELY = (0.5, 2.0)
# A median sample interval of this many s or more, on a recording whose gyroscope turns, is no
# MARG sensor's (they sample at 10 Hz to a few kHz): timestamps in ms, µs or ns read as s.
_INTERVAL_S_IMPLAUSIBLE = 1.0
# A rate above this (rad/s, 11.5 deg/s) is motion, beyond any gyroscope's bias and noise at
# rest; a few such samples (a spike or two is a glitch) show that the sensor turns.
_GYR_MOTION_RAD_S = 0.2
_MOTION_HITS = 3
# Of ms, us and ns, the timestamps are suspected in the one giving the rate nearest this
# (on a log scale: 1000 s-units apart are 10 Hz in ms or 10 kHz in us).
_TYPICAL_RATE_HZ = 100.0


def unit_factor(signal: str, unit: str) -> float:
    """The factor taking ``signal`` values in ``unit`` to rad/s, m/s², µT or s.

    ``signal`` is "gyr", "acc", "mag" or "time". An unknown unit raises ``ValueError``
    listing the valid ones, e.g. ``gyr_unit must be one of ['deg/s', 'rad/s'], got 'rpm'``.
    """
    if signal not in UNITS:
        raise ValueError(f"signal must be one of {sorted(UNITS)}, got {signal!r}")
    table = UNITS[signal]
    if unit not in table:
        raise ValueError(f"{signal}_unit must be one of {sorted(table)}, got {unit!r}")
    return table[unit]


def convert_unit(values: ArrayLike, signal: str, unit: str) -> Array:
    """``values`` (any shape) of ``signal`` in ``unit``, converted to rad/s, m/s², µT or s.

    Decimal sub-units (ms, nT, mG...) are divided by the exact power of ten (1e3) rather
    than multiplied by its inexact reciprocal (1e-3): one rounding instead of two, so
    ``t_ms / 1e3`` reproduces the seconds a file was written from whenever ``t_s * 1e3``
    was exact.
    """
    factor = unit_factor(signal, unit)
    arr = np.asarray(values, dtype=np.float64)
    if factor < 1.0:
        inverse = float(round(1.0 / factor))
        if 1.0 / inverse == factor:  # factor is the double nearest 1/inverse: 1e-3, 1e-9...
            return arr / inverse
    return arr * factor


class UnitError(ValueError):
    """Magnitudes that betray a unit mix-up: gyr in deg/s, acc in g, time in ms (µs, ns).

    Attributes
    ----------
    signal : "gyr", "acc" or "time".
    suspected : the unit the data is probably in, "deg/s", "g", "ms", "us" or "ns".
    fix : the sentence of the message that says how to declare the unit on the caller's
        path ("" if none): a front end on another path (the command line) replaces it
        with its own (``--time-unit ms``) in the message, prefixes and all.
    """

    def __init__(self, message: str, *, signal: str, suspected: str, fix: str = "") -> None:
        super().__init__(message)
        self.signal = signal
        self.suspected = suspected
        self.fix = fix

    def prefixed(self, prefix: str) -> UnitError:
        """The same error with ``prefix`` (a file, a sensor) in front of its message."""
        return UnitError(f"{prefix}{self}", signal=self.signal, suspected=self.suspected,
                         fix=self.fix)


def unit_fix_api(signal: str, suspected: str) -> str:
    """The fix sentence for Python callers of the estimators (``check_unit_magnitudes``' default).

    ``unit_fix_api("gyr", "deg/s")`` is ``"pass gyr_unit='deg/s' to run() or convert with
    Recording.with_units(gyr='deg/s')"``.
    """
    return (
        f"pass {signal}_unit={suspected!r} to run() or convert with "
        f"Recording.with_units({signal}={suspected!r})"
    )


def unit_fix_keyword(where: str) -> Callable[[str, str], str]:
    """A fix naming the ``<signal>_unit`` keyword of ``where`` (a function that has it).

    ``unit_fix_keyword("read_csv")("acc", "g")`` is ``"pass acc_unit='g' to read_csv (or
    check_units=False if it really is m/s2)"``.
    """

    def fix(signal: str, suspected: str) -> str:
        return (
            f"pass {signal}_unit={suspected!r} to {where} "
            f"(or check_units=False if it really is {SI_UNITS[signal]})"
        )

    return fix


def _gyr_hits_needed(n: int) -> int:
    """Samples beyond 40 rad/s that betray deg/s in a series of n: 0.1 % and at least 3
    (fewer in very short series, down to 1 of 1)."""
    return max(min(3, -(-n // 10)), -(-n // 1000), 1)


def check_unit_magnitudes(
    gyr_rad_s: Array,
    acc_m_s2: Array,
    *,
    fix: Callable[[str, str], str] | None = None,
    t_s: ArrayLike | None = None,
) -> None:
    """Raise :class:`UnitError` if gyr looks like deg/s, acc like g or t like ms (µs, ns).

    Parameters
    ----------
    gyr_rad_s : (N, 3) angular rate that should be rad/s (may be empty), or (S, N, 3) for S
        sensors, each judged on its own. Refused if a share of samples (0.1 %, at least 3)
        exceeds 40 rad/s, more than any MEMS gyroscope measures (±2000 deg/s is 34.9); a
        single spike is a glitch, not a unit.
    acc_m_s2 : (N, 3) or (S, N, 3) specific force that should be m/s² (may be empty).
        Refused if its median norm lies between 0.5 and 2 (about 1 g rather than 9.81 m/s²).
    fix : ``fix(signal, suspected)`` returns the sentence telling the caller how to declare
        the unit on its own path (an option, a keyword); default :func:`unit_fix_api`.
    t_s : (N,) the timestamps that should be s, shared by the sensors (None: not checked).
        Refused if their median interval is 1 s or more while the gyroscope turns (3
        samples beyond 0.2 rad/s): no MARG sensor samples that slowly, the timestamps are
        ms (µs, ns) read as s. Without a gyroscope there is no evidence of motion.

    The message names the offending sample (gyr, t) or the median norm (acc), the sensor
    when there are several, the suspected unit and the fix. Non-finite samples are left out
    (a sensor with no finite sample is no evidence). The sensors are checked together (a
    few numpy passes, no loop over them).
    """
    fix = unit_fix_api if fix is None else fix
    gyr = np.asarray(gyr_rad_s, dtype=np.float64)
    acc = np.asarray(acc_m_s2, dtype=np.float64)
    if gyr.size:
        _check_gyr(gyr.reshape(-1, *gyr.shape[-2:]), gyr.ndim > 2, fix)
    if acc.size:
        _check_acc(acc.reshape(-1, *acc.shape[-2:]), acc.ndim > 2, fix)
    if t_s is not None and gyr.size:
        _check_time(np.asarray(t_s, dtype=np.float64), gyr.reshape(-1, *gyr.shape[-2:]), fix)


def _sensor(s: int, several: bool) -> str:
    """The message's prefix naming sensor s when a call checks several."""
    return f"sensor {s}: " if several else ""


def _check_gyr(gyr: Array, several: bool, fix: Callable[[str, str], str]) -> None:
    """:func:`check_unit_magnitudes` for the rates (S, N, 3)."""
    # first a bound without temporaries (fmax/fmin skip nan): most data never nears 40 rad/s
    if max(np.fmax.reduce(gyr, axis=None), -np.fmin.reduce(gyr, axis=None)) <= (
        _GYR_RAD_S_IMPLAUSIBLE
    ):
        return
    # samples beyond any MEMS range; a spike or two is a glitch (the estimators flag and skip
    # it), a share of a recording is a unit
    over = np.any(np.abs(gyr) > _GYR_RAD_S_IMPLAUSIBLE, axis=-1)  # (S, N)
    bad = np.flatnonzero(over.sum(axis=1) >= _gyr_hits_needed(gyr.shape[1]))
    if bad.size:
        s = int(bad[0])
        magnitude = np.abs(gyr[s])
        peak = float(magnitude.max())
        i = int(np.argwhere(magnitude == peak)[0][0])
        hits = np.flatnonzero(over[s])
        fix_text = fix("gyr", "deg/s")
        raise UnitError(
            f"{_sensor(s, several)}gyr reaches {peak:.1f} rad/s at sample {i} and exceeds "
            f"{_GYR_RAD_S_IMPLAUSIBLE:g} rad/s on {hits.size} of {gyr.shape[1]} samples "
            f"(first at sample {int(hits[0])}), more than any MEMS gyroscope measures; "
            f"the data is probably in deg/s: {fix_text}",
            signal="gyr", suspected="deg/s", fix=fix_text,
        )


def _check_acc(acc: Array, several: bool, fix: Callable[[str, str], str]) -> None:
    """:func:`check_unit_magnitudes` for the specific force (S, N, 3)."""
    # the median of an evenly strided subsample, as telling and cheap on long series: about
    # 20,000 samples in all, at least 256 per sensor
    per_sensor = max(256, 20_000 // acc.shape[0])
    sub = acc[:, :: max(1, -(-acc.shape[1] // per_sensor))]
    norms = np.sqrt(np.einsum("snk,snk->sn", sub, sub))
    medians = np.median(norms, axis=1)
    partial = np.isnan(medians)
    if partial.any():
        # a sensor with missing samples: the median of the others (all missing: no evidence)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # (an all-nan sensor)
            medians[partial] = np.nanmedian(norms[partial], axis=1)
    bad = np.flatnonzero((_ACC_G_LIKELY[0] < medians) & (medians < _ACC_G_LIKELY[1]))
    if bad.size:
        s = int(bad[0])
        fix_text = fix("acc", "g")
        raise UnitError(
            f"{_sensor(s, several)}acc has a median norm of {medians[s]:.3f}, about 1 g rather "
            f"than 9.81 m/s²; the data is probably in g: {fix_text}",
            signal="acc", suspected="g", fix=fix_text,
        )


def suspected_time_unit(median_interval: float) -> tuple[str, float]:
    """The unit timestamps advancing by ``median_interval`` per sample are probably in, of
    ms, us and ns (the one giving the rate nearest 100 Hz), and the rate in Hz it gives."""
    rates = {unit: 1.0 / (median_interval * TIME_UNITS[unit]) for unit in ("ms", "us", "ns")}
    unit = min(rates, key=lambda u: abs(np.log10(rates[u] / _TYPICAL_RATE_HZ)))
    return unit, rates[unit]


def _hz(rate: float) -> str:
    return f"{rate:.3g} Hz"


def time_unit_error(
    median_interval: float,
    lead: str,
    gyr_peak: float,
    where_gyr: str,
    fix_of: Callable[[str, str], str],
    detail: str = "",
) -> UnitError:
    """The :class:`UnitError` of timestamps advancing by ``median_interval`` (s-units) per
    sample while the gyroscope turns: ``lead`` says so ("t advances by a median of 10 s per
    sample"; ``detail`` adds to the rate in parentheses), ``gyr_peak`` rad/s ``where_gyr``
    ("at sample 12") is where it turns."""
    unit, rate = suspected_time_unit(median_interval)
    fix = fix_of("time", unit)
    return UnitError(
        f"{lead} ({_hz(1 / median_interval)}{detail}) while the gyroscope turns "
        f"({gyr_peak:.2f} rad/s {where_gyr}): no MARG sensor samples that slowly; the "
        f"timestamps are probably in {unit} ({_hz(rate)} then): {fix}",
        signal="time", suspected=unit, fix=fix,
    )


def _check_time(t: Array, gyr: Array, fix: Callable[[str, str], str]) -> None:
    """:func:`check_unit_magnitudes` for the timestamps (N,) and the rates (S, N, 3)."""
    n = t.shape[0]
    if t.ndim != 1 or n < 2 or gyr.shape[1] != n:
        return  # no interval, or shapes the caller's own checks refuse
    # the median of up to 20,000 intervals spread over the recording
    start = np.arange(0, n - 1, max(1, (n - 1) // 20_000))
    steps = t[start + 1] - t[start]
    steps = steps[np.isfinite(steps)]
    if steps.size == 0:
        return
    median = float(np.median(steps))
    if not median >= _INTERVAL_S_IMPLAUSIBLE:
        return
    norms = np.sqrt(np.einsum("snk,snk->sn", gyr, gyr))
    moving = norms > _GYR_MOTION_RAD_S  # False on nan
    hits = moving.sum(axis=1)
    turning = np.flatnonzero(hits >= min(_MOTION_HITS, n))
    if turning.size == 0:
        return  # a slow log of a still sensor: no evidence
    s = int(turning[0])
    i = int(np.flatnonzero(moving[s])[0])
    sensor = f" (sensor {s})" if gyr.shape[0] > 1 else ""
    raise time_unit_error(
        median, f"t advances by a median of {median:.6g} s per sample", float(norms[s, i]),
        f"at sample {i}{sensor}", fix, detail=f"; t[1] - t[0] = {t[1] - t[0]:.6g}",
    )


class IntervalProbe:
    """The timestamp rule of :func:`check_unit_magnitudes` on a stream, sample by sample.

    :meth:`add` takes each sample's time (s-units, ``nan`` when unknown) and the largest
    rate norm among its sensors (rad/s, ``nan`` without a gyroscope). After
    ``N_INTERVALS`` intervals it judges their median: below 1 s it is ``done``; at 1 s or
    more it keeps watching for motion (``_MOTION_HITS`` samples beyond 0.2 rad/s) and
    raises the :class:`UnitError` when it sees it, until ``LIMIT`` samples.

    Parameters
    ----------
    fix : ``fix("time", suspected)``, the sentence naming the fix on the caller's path.
    what : how the message names the samples and their times: ``"update"`` (times from
        ``dt``), ``"line of sensor s0"``...
    """

    N_INTERVALS = 10
    LIMIT = 5000

    def __init__(self, fix: Callable[[str, str], str], what: str = "sample") -> None:
        self.fix = fix
        self.what = what
        self.count = 0
        self.times: list[float] = []
        self.moving = 0
        self.first_motion: tuple[int, float] | None = None
        self.median: float | None = None
        self.done = False

    def add(self, t: float, gyr_norm: float) -> None:
        """Take one sample; raise :class:`UnitError` when the stream is refused."""
        index = self.count
        self.count += 1
        if gyr_norm > _GYR_MOTION_RAD_S:
            self.moving += 1
            if self.first_motion is None:
                self.first_motion = (index, float(gyr_norm))
        if self.median is None:
            if math.isfinite(t) and (not self.times or t != self.times[-1]):
                self.times.append(float(t))
            if len(self.times) > self.N_INTERVALS:
                self.median = float(np.median(np.diff(self.times)))
                self.done = not self.median >= _INTERVAL_S_IMPLAUSIBLE
        if self.median is not None and not self.done and self.moving >= _MOTION_HITS:
            assert self.first_motion is not None
            at, peak = self.first_motion
            n = self.N_INTERVALS
            lead = (
                f"dt has a median of {self.median:.6g} s over the first {n} intervals"
                if self.what == "update" else
                f"t advances by a median of {self.median:.6g} s per {self.what} over the "
                f"first {n + 1}"
            )
            raise time_unit_error(self.median, lead, peak, f"at {self.what} {at}", self.fix)
        if self.count >= self.LIMIT:
            self.done = True
