"""Unit checks on every path: deg/s gyroscopes and g accelerometers are refused with the fix.

The heuristics (``units.check_unit_magnitudes``): a gyroscope in deg/s read as rad/s
exceeds any MEMS range (40 rad/s) on a good share of a moving recording's samples, while
a spike or two does not; an accelerometer in g has a median norm near 1 instead of 9.81.
Whole series are checked at once; ``update`` checks a running window of its first
samples (:class:`UnitProbe`). The message names the option of the path the user is on.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from margtrack import units

Array = NDArray[np.float64]

__all__ = ["UnitProbe", "check_series_units", "scale_to_si"]

_FIXES = {
    "arrays": {
        "gyr": units.unit_fix_keyword("run()")("gyr", "deg/s"),
        "acc": units.unit_fix_keyword("run()")("acc", "g"),
    },
    "recording": {
        "gyr": "convert it with rec.with_units(gyr='deg/s') or read it with "
        "margtrack.io.read(..., gyr_unit='deg/s') (or run(..., check_units=False))",
        "acc": "convert it with rec.with_units(acc='g') or read it with "
        "margtrack.io.read(..., acc_unit='g') (or run(..., check_units=False))",
    },
    "update": {
        "gyr": "convert to rad/s before update() (multiply deg/s by pi/180)",
        "acc": "convert to m/s² before update() (multiply g by 9.80665)",
    },
}


def scale_to_si(signal: str, unit: str) -> float:
    """Factor taking ``signal`` ("gyr" or "acc") from ``unit`` to rad/s or m/s²."""
    return units.unit_factor(signal, unit)


def check_series_units(gyr: Array | None, acc: Array, path: str) -> None:
    """Raise ``units.UnitError`` if gyr looks like deg/s or acc like g: (N, 3) series, or
    (S, N, 3) for S sensors (each judged on its own; the message names the sensor).

    ``path`` ("arrays", "recording", "update") chooses the fix the message names.
    Non-finite samples are left out (the screening flags them).
    """
    fixes = _FIXES[path]
    units.check_unit_magnitudes(
        np.zeros((0, 3)) if gyr is None else gyr,
        acc,
        fix=lambda signal, suspected: fixes[signal],
    )


class UnitProbe:
    """The running unit check of ``update``: over its first samples, refuse deg/s and g.

    The accelerometer is judged after ``N_ACC`` samples by their median norm; the
    gyroscope by how many of the first ``N_GYR`` samples exceed 40 rad/s.
    """

    N_ACC = 25
    N_GYR = 500
    GYR_HITS = 5

    def __init__(self) -> None:
        self.count = 0
        self.acc_norms: list[float] = []
        self.gyr_hits = 0
        self.done = False

    def add(self, gyr: Array | None, acc: Array) -> None:
        """Take one update's samples ((S, 1, 3) arrays); raise UnitError when they look wrong."""
        self.count += 1
        a = np.asarray(acc).reshape(-1, 3)
        norms = np.linalg.norm(a, axis=1)
        if self.count <= self.N_ACC:
            self.acc_norms.extend(float(v) for v in norms if np.isfinite(v) and v > 0)
            if self.count == self.N_ACC and self.acc_norms:
                median = float(np.median(self.acc_norms))
                if units._ACC_G_LIKELY[0] < median < units._ACC_G_LIKELY[1]:
                    raise units.UnitError(
                        f"acc has a median norm of {median:.3f} over the first {self.N_ACC} "
                        f"updates, about 1 g rather than 9.81 m/s²; {_FIXES['update']['acc']}",
                        signal="acc",
                        suspected="g",
                    )
        if gyr is not None:
            g = np.abs(np.asarray(gyr).reshape(-1, 3))
            if np.any(g > units._GYR_RAD_S_IMPLAUSIBLE):
                self.gyr_hits += 1
                if self.gyr_hits >= self.GYR_HITS:
                    raise units.UnitError(
                        f"gyr exceeded {units._GYR_RAD_S_IMPLAUSIBLE:g} rad/s on "
                        f"{self.gyr_hits} of the first {self.count} updates, more than any "
                        f"MEMS gyroscope measures: probably deg/s; {_FIXES['update']['gyr']}",
                        signal="gyr",
                        suspected="deg/s",
                    )
        if self.count >= max(self.N_ACC, self.N_GYR):
            self.done = True
