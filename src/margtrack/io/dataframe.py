"""A Recording from a pandas DataFrame (pandas optional: nothing here imports it).

Columns are mapped as for a CSV (:func:`margtrack.io.read_csv`), or guessed from the
column names when they are unambiguous (``gx, gy, gz``, ``gyr_x``, ``Gyroscope x (rad/s)``...).
A ``DatetimeIndex`` serves as the time column when none is mapped.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from margtrack.io.csv_layout import guess_columns, mapping_hint, normalise_columns
from margtrack.io.mapped import build_recording
from margtrack.recording import Recording

__all__ = ["from_dataframe"]


def from_dataframe(
    df: Any,
    columns: Mapping[str, Sequence[str] | str] | None = None,
    *,
    gyr_unit: str | None = None,
    acc_unit: str | None = None,
    mag_unit: str | None = None,
    time_unit: str | None = None,
    rate_hz: float | None = None,
    frame: str = "ENU",
    name: str = "DataFrame",
    check_units: bool = True,
) -> Recording:
    """Build a Recording from the columns of a pandas DataFrame.

    Parameters
    ----------
    df : a ``pandas.DataFrame`` (anything with ``columns``, ``__getitem__`` and ``index``).
    columns : field -> column name(s), as in :func:`margtrack.io.read_csv` (``"t"``,
        ``"gyr"``, ``"acc"``, ``"mag"``, ``"quat_true"`` with NaN rows as truth holes,
        ``"movement"``). None guesses it from the names and refuses, listing the columns
        and the map to pass, when gyr or acc cannot be placed.
    gyr_unit, acc_unit, mag_unit, time_unit : the units of the mapped values (default
        rad/s, m/s², the field as it is, s).
    rate_hz : the sampling rate when there is no time column and no ``DatetimeIndex``.
    check_units : refuse gyr that looks like deg/s and acc like g, naming the keyword.

    Returns
    -------
    The Recording (SI units); NaN gyr/acc/mag values are held and listed in
    ``meta["invalid_samples"]`` (see :mod:`margtrack.io.mapped`).
    """
    if not hasattr(df, "columns") or not hasattr(df, "index"):
        raise TypeError(f"from_dataframe needs a pandas DataFrame, got {type(df).__name__}")
    header = [str(c) for c in df.columns]
    if columns is None:
        mapping = guess_columns(header)
        if not ("gyr" in mapping and "acc" in mapping):
            raise ValueError(
                f"cannot tell the DataFrame's gyr and acc columns; it has columns {header}; "
                f"pass columns=... ({mapping_hint(header).python})"
            )
    else:
        mapping = normalise_columns(columns)
    missing = [c for cols in mapping.values() for c in cols if c not in header]
    if missing:
        raise ValueError(
            f"the DataFrame has no column {missing[0]!r}; it has columns {header}; "
            + mapping_hint(header).python
        )
    data: dict[str, Any] = {}
    for field, cols in mapping.items():
        try:
            block = np.asarray(df[cols].to_numpy(dtype=np.float64, na_value=np.nan))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"DataFrame columns {cols} are not numeric: {exc}") from None
        data[field] = block[:, 0] if len(cols) == 1 else block
    units = {"gyr": gyr_unit, "acc": acc_unit, "mag": mag_unit, "time": time_unit}
    index = df.index
    if "t" not in mapping and rate_hz is None and hasattr(index, "asi8") and str(
        getattr(index, "dtype", "")
    ).startswith("datetime64"):
        ns = np.asarray(index.asi8, dtype=np.int64)
        data["t"] = (ns - ns[0]) / 1e9 if ns.size else ns.astype(np.float64)
        units["time"] = "s"
    meta: dict[str, Any] = {"source": "DataFrame", "columns": mapping}
    if "t" in data and "t" not in mapping:
        meta["t0_ns"] = int(index.asi8[0])  # the index's first instant, ns since the epoch
    return build_recording(
        "DataFrame", data, units, rate_hz=rate_hz, frame=frame, name=name, meta=meta,
        check_units=check_units, fix_where="from_dataframe", columns=mapping,
    )
