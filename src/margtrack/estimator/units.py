"""Unit checks on every path: deg/s gyroscopes, g accelerometers and timestamps in ms (µs,
ns) are refused with the fix.

The heuristics (``units.check_unit_magnitudes``): a gyroscope in deg/s read as rad/s
exceeds any MEMS range (40 rad/s) on a good share of a moving recording's samples, while
a spike or two does not; an accelerometer in g has a median norm near 1 instead of 9.81;
timestamps in ms read as s advance by a second or more per sample while the gyroscope
turns. Whole series are checked at once; ``update`` checks a running window of its first
samples (:class:`UnitProbe`, which reads the estimator's clock for the intervals: its
``dt`` in ms is the same mistake). The message names the option of the path the user is on.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from margtrack import units

Array = NDArray[np.float64]

__all__ = ["UnitProbe", "check_series_times", "check_series_units", "scale_to_si"]


def _update_fix(signal: str, unit: str) -> str:
    """How a caller of ``update`` fixes a unit: convert the sample, or give dt in s."""
    if signal == "gyr":
        return "convert to rad/s before update() (multiply deg/s by pi/180)"
    if signal == "acc":
        return "convert to m/s² before update() (multiply g by 9.80665)"
    return f"give update() dt in s (divide dt in {unit} by {round(1 / units.TIME_UNITS[unit]):g})"


_FIXES: dict[str, Callable[[str, str], str]] = {
    "arrays": units.unit_fix_keyword("run()"),
    "recording": lambda signal, unit: (
        f"convert it with rec.with_units({signal}={unit!r}) or read it with "
        f"margtrack.io.read(..., {signal}_unit={unit!r}) (or run(..., check_units=False))"
    ),
    "update": _update_fix,
}


def scale_to_si(signal: str, unit: str) -> float:
    """Factor taking ``signal`` ("gyr" or "acc") from ``unit`` to rad/s or m/s²."""
    return units.unit_factor(signal, unit)


def check_series_units(
    gyr: Array | None, acc: Array, path: str, t: Array | None = None
) -> None:
    """Raise ``units.UnitError`` if gyr looks like deg/s, acc like g or the timestamps ``t``
    (N,) like ms: (N, 3) series, or (S, N, 3) for S sensors (each judged on its own; the
    message names the sensor).

    ``path`` ("arrays", "recording", "update") chooses the fix the message names.
    Non-finite samples are left out (the screening flags them).
    """
    units.check_unit_magnitudes(
        np.zeros((0, 3)) if gyr is None else gyr, acc, fix=_FIXES[path], t_s=t
    )


def check_series_times(t: Array, gyr: Array | None, path: str) -> None:
    """Raise ``units.UnitError`` if timestamps ``t`` (N,) look like ms, µs or ns read as s
    while the rates ``gyr`` ((N, 3) or (S, N, 3), rad/s) turn; ``path`` as
    :func:`check_series_units`. Shapes the estimator refuses anyway are not judged."""
    if gyr is None or np.ndim(gyr) not in (2, 3) or np.shape(gyr)[-1] != 3:
        return
    units.check_unit_magnitudes(gyr, np.zeros((0, 3)), fix=_FIXES[path], t_s=t)


class UnitProbe:
    """The running unit check of ``update``: over its first samples, refuse deg/s, g and ms.

    The accelerometer is judged after ``N_ACC`` samples by their median norm; the
    gyroscope by how many of the first ``N_GYR`` samples exceed 40 rad/s; the intervals
    by :class:`~margtrack.units.IntervalProbe` on the updates' times.
    """

    N_ACC = 25
    N_GYR = 500
    GYR_HITS = 5

    def __init__(self) -> None:
        self.count = 0
        self.acc_norms: list[float] = []
        self.gyr_hits = 0
        self.done = False
        self.intervals = units.IntervalProbe(_FIXES["update"], "update")

    def add(self, gyr: Array | None, acc: Array, t_s: float) -> None:
        """Take one update's samples ((S, 1, 3) arrays) and its time (s, the estimator's
        clock); raise UnitError when they look wrong."""
        self.count += 1
        a = np.asarray(acc).reshape(-1, 3)
        norms = np.linalg.norm(a, axis=1)
        if self.count <= self.N_ACC:
            self.acc_norms.extend(float(v) for v in norms if np.isfinite(v) and v > 0)
            if self.count == self.N_ACC and self.acc_norms:
                median = float(np.median(self.acc_norms))
                if units._ACC_G_LIKELY[0] < median < units._ACC_G_LIKELY[1]:
                    fix = _FIXES["update"]("acc", "g")
                    raise units.UnitError(
                        f"acc has a median norm of {median:.3f} over the first {self.N_ACC} "
                        f"updates, about 1 g rather than 9.81 m/s²; {fix}",
                        signal="acc", suspected="g", fix=fix,
                    )
        rate = math.nan
        if gyr is not None:
            g = np.abs(np.asarray(gyr).reshape(-1, 3))
            rate = float(np.max(np.sqrt(np.sum(g * g, axis=1)), initial=0.0))
            if np.any(g > units._GYR_RAD_S_IMPLAUSIBLE):
                self.gyr_hits += 1
                if self.gyr_hits >= self.GYR_HITS:
                    fix = _FIXES["update"]("gyr", "deg/s")
                    raise units.UnitError(
                        f"gyr exceeded {units._GYR_RAD_S_IMPLAUSIBLE:g} rad/s on "
                        f"{self.gyr_hits} of the first {self.count} updates, more than any "
                        f"MEMS gyroscope measures: probably deg/s; {fix}",
                        signal="gyr", suspected="deg/s", fix=fix,
                    )
        if not self.intervals.done:
            self.intervals.add(t_s, rate)
        if self.count >= max(self.N_ACC, self.N_GYR) and self.intervals.done:
            self.done = True


