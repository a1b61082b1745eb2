"""The unit of each series an estimate file holds, from its name (units live in the names).

margtrack names per-sample series with their unit (DESIGN.md: ``gyr_bias_rad_s``,
``lin_acc_earth_m_s2``, ``euler_rad``), so a file can state the unit of every column or
dataset without a table per method: :func:`output_unit` reads it from the name's suffix.
Written as the ``# units`` line of an estimate CSV and the ``unit`` attribute of each
dataset of an estimate HDF5 file. Unit strings hold no spaces.

- ``t``/``t_s``: ``s``; ``quat`` (and ``quat6d``): ``1`` (unit quaternion ``[w, x, y, z]``);
  ``flags``: ``bits`` (of :class:`margtrack.estimator.Flag`);
- suffixes: ``_rad_s`` rad/s, ``_deg_s`` deg/s, ``_m_s2`` m/s^2, ``_rad2_s2`` rad^2/s^2,
  ``_rad`` rad, ``_deg`` deg, ``_ut`` uT, ``_hz`` Hz, ``_s`` s;
- ``cov_diag``: ``mixed`` (its elements have the units of the method's state, listed by
  ``margtrack methods METHOD``);
- booleans: ``0/1``; whole numbers (codes, counts) and the known dimensionless criteria
  (``phi``, ``criterion``): ``1``; any other name: ``unstated``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["column_units", "output_unit"]

_EXACT = {
    "t": "s", "t_s": "s", "quat": "1", "quat6d": "1", "flags": "bits", "cov_diag": "mixed",
    "phi": "1", "criterion": "1",
}
# longest first: "_rad2_s2" before "_s2"-like endings, "_rad_s" before "_s"
_SUFFIXES = (
    ("_rad2_s2", "rad^2/s^2"), ("_rad_s", "rad/s"), ("_deg_s", "deg/s"), ("_m_s2", "m/s^2"),
    ("_rad", "rad"), ("_deg", "deg"), ("_ut", "uT"), ("_hz", "Hz"), ("_s", "s"),
)


def output_unit(name: str, dtype: Any = np.float64) -> str:
    """The unit of the series ``name`` (dtype ``dtype``), as the module docstring lists."""
    if name in _EXACT:
        return _EXACT[name]
    lower = name.lower()
    for suffix, unit in _SUFFIXES:
        if lower.endswith(suffix):
            return unit
    kind = np.dtype(dtype).kind
    if kind == "b":
        return "0/1"
    if kind in "iu":
        return "1"
    return "unstated"


def column_units(
    names: list[str], owners: list[str], dtypes: list[Any]
) -> dict[str, str]:
    """``{column: unit}`` for CSV columns, each the column of series ``owners[k]``."""
    return {
        col: output_unit(owner, dtype)
        for col, owner, dtype in zip(names, owners, dtypes, strict=True)
    }
