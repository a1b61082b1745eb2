"""A Recording from mapped columns of any source (a CSV, a phone logger, a DataFrame).

The shared last step of every reader that maps someone else's columns: units converted to
SI (:mod:`margtrack.units`), holes handled by the input policy, and errors that name the
line of the file rather than only the sample.

Holes. An empty or non-finite gyroscope, accelerometer or magnetometer value cannot live in
a :class:`~margtrack.recording.Recording` (whose signals are finite), and refusing the whole
file for one empty cell loses everything else. Such a sample keeps its row: its value is
held from the previous usable sample of that signal (the first usable one at the start),
the rows are listed in ``meta["invalid_samples"]`` (signal -> sample indices) and a warning
names the first line; :func:`flag_invalid` marks them ``Flag.INVALID`` in an estimate, as an
estimator does for a NaN given to it directly. Ground truth may have holes (NaN rows); the
metrics skip them. A non-finite timestamp is an error naming its line.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.recording import Recording
from margtrack.units import (
    UnitError,
    check_unit_magnitudes,
    convert_unit,
    unit_factor,
    unit_fix_keyword,
)

Array = NDArray[np.float64]

__all__ = ["build_recording", "flag_invalid", "invalid_mask"]


def _hold(values: Array, bad: NDArray[np.bool_]) -> Array:
    """``values`` (N, 3) with the rows in ``bad`` replaced by the last good row before them."""
    n = values.shape[0]
    idx = np.where(bad, -1, np.arange(n))
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = int(np.argmin(bad))  # leading holes: the first good row
    return values[idx]


def _line_text(lines: NDArray[np.intp] | None, sample: int) -> str:
    if lines is None or not 0 <= sample < lines.shape[0]:
        return ""
    return f" (sample {sample} is line {int(lines[sample])} of the file)"


def _with_lines(message: str, lines: NDArray[np.intp] | None) -> str:
    """``message`` with the file line of the first ``sample i`` it mentions."""
    found = re.search(r"sample (\d+)", message)
    if lines is None or found is None:
        return message
    return message + _line_text(lines, int(found.group(1)))


def build_recording(
    source: str,
    data: Mapping[str, Array],
    units: Mapping[str, str | None],
    *,
    rate_hz: float | None = None,
    frame: str = "ENU",
    name: str = "",
    meta: Mapping[str, Any] | None = None,
    lines: NDArray[np.intp] | None = None,
    check_units: bool = True,
    fix_where: str = "read",
    columns: Mapping[str, list[str]] | None = None,
) -> Recording:
    """A Recording from column arrays in declared units.

    Parameters
    ----------
    source : the file (or "DataFrame") the columns come from, named in every message.
    data : ``t`` (N,), ``gyr``/``acc`` (N, 3), optional ``mag`` (N, 3), ``quat_true``
        (N, 4, NaN rows are truth holes) and ``movement`` (N,) 0/1.
    units : ``gyr``, ``acc``, ``mag``, ``time`` -> unit of the raw values (None: SI, the
        magnetometer kept as it is).
    rate_hz : the rate when there is no ``t`` (never assumed).
    lines : the 1-based file line of each row, for messages.
    check_units : refuse gyr that looks like deg/s and acc like g (the fix names
        ``fix_where``'s keyword).
    columns : the column map the data came from, to name columns in messages.
    """
    unit = {k: units.get(k) for k in ("gyr", "acc", "mag", "time")}
    for signal, u in unit.items():
        if u is not None:
            unit_factor(signal, u)  # unknown units fail before anything else
    for required in ("gyr", "acc"):
        if required not in data:
            raise ValueError(f"{source}: no {required} columns mapped (3 names, x y z)")
    if ("t" in data) == (rate_hz is not None):
        raise ValueError(
            f"{source}: give a time column (t) or rate_hz, exactly one of them "
            "(no rate is assumed)"
        )
    out_meta: dict[str, Any] = dict(meta or {})
    fields: dict[str, Any] = {}
    t = None
    if "t" in data:
        raw_t = np.asarray(data["t"], dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(raw_t))
        if bad.size:
            i = int(bad[0])
            raise ValueError(
                f"{source}: the time column is empty or not a number at sample {i}; every "
                f"row needs a timestamp: fix or delete it{_line_text(lines, i)}"
            )
        t = convert_unit(raw_t, "time", unit["time"] or "s")
    invalid: dict[str, list[int]] = {}
    signals: dict[str, Array] = {}
    for signal in ("gyr", "acc", "mag"):
        if signal not in data:
            continue
        values = np.asarray(data[signal], dtype=np.float64)
        bad = ~np.isfinite(values).all(axis=1)
        if bad.all():
            raise ValueError(
                f"{source}: {signal} has no usable sample (every value empty or not finite)"
            )
        if bad.any():
            rows = np.flatnonzero(bad)
            invalid[signal] = rows.tolist()
            first = int(rows[0])
            warnings.warn(
                f"{source}: {signal} is empty or not finite on {rows.size} row(s), first at "
                f"sample {first}; held from the previous sample and listed in "
                f"meta['invalid_samples'] (io.flag_invalid flags them INVALID in an estimate)"
                f"{_line_text(lines, first)}",
                UserWarning, stacklevel=3,
            )
            values = _hold(values, bad)
        signals[signal] = values
    if invalid:
        out_meta["invalid_samples"] = invalid
    if "mag" in signals and unit["mag"] is not None:
        signals["mag"] = convert_unit(signals["mag"], "mag", unit["mag"])
    if "quat_true" in data:
        fields["quat_true"] = np.asarray(data["quat_true"], dtype=np.float64)
    if "movement" in data:
        m = np.asarray(data["movement"], dtype=np.float64)
        wrong = np.flatnonzero((m != 0.0) & (m != 1.0))
        if wrong.size:
            i = int(wrong[0])
            column = (columns or {}).get("movement", ["movement"])[0]
            raise ValueError(
                f"{source}: column {column!r} has value {float(m[i])!r} at sample {i}; "
                f"movement must be 0 or 1{_line_text(lines, i)}"
            )
        fields["movement"] = m == 1.0
    converted = {
        s: u for s, u in unit.items()
        if u is not None and unit_factor(s, u) != 1.0 and (s != "mag" or "mag" in signals)
    }
    # keyed by field ("t" for the time column), as the column map is
    out_meta["units"] = {("t" if s == "time" else s): u for s, u in unit.items() if u is not None}
    if converted:
        out_meta["units_converted"] = converted
    if rate_hz is not None:
        out_meta["rate_hz"] = float(rate_hz)
    try:
        rec = Recording.from_arrays(
            signals["gyr"], signals["acc"], signals.get("mag"), t=t, rate_hz=rate_hz,
            gyr_unit=unit["gyr"] or "rad/s", acc_unit=unit["acc"] or "m/s2",
            check_units=False, frame=frame, name=name, meta=out_meta, **fields,
        )
        if check_units:
            check_unit_magnitudes(rec.gyr, rec.acc, fix=unit_fix_keyword(fix_where), t_s=rec.t)
    except ValueError as exc:
        text = f"{source}: {_with_lines(str(exc), lines)}"
        if isinstance(exc, UnitError):
            raise UnitError(text, signal=exc.signal, suspected=exc.suspected,
                            fix=exc.fix) from None
        raise ValueError(text) from None
    return rec


def invalid_mask(rec: Recording, start: int = 0) -> NDArray[np.bool_]:
    """(N,) True where a reader held a value over a hole (``meta["invalid_samples"]``).

    ``start``: the index of ``rec``'s first sample in the recording the meta describes
    (a chunk or slice of it keeps the whole recording's meta).
    """
    mask = np.zeros(rec.n_samples, dtype=bool)
    for rows in (rec.meta.get("invalid_samples") or {}).values():
        idx = np.asarray(rows, dtype=np.intp) - int(start)
        mask[idx[(idx >= 0) & (idx < mask.size)]] = True
    return mask


def flag_invalid(estimate: Any, rec: Recording, start: int = 0) -> Any:
    """``estimate`` with ``Flag.INVALID`` set on the samples a reader held over a hole.

    The estimate of ``rec`` (flags (N,)), which starts at sample ``start`` of the recording
    read (for chunked runs); returned unchanged when no sample was held.
    """
    import dataclasses

    from margtrack.estimator.flags import Flag

    mask = invalid_mask(rec, start)
    flags = getattr(estimate, "flags", None)
    if not mask.any() or flags is None or flags.shape != mask.shape:
        return estimate
    new = flags.copy()
    new[mask] |= np.uint16(Flag.INVALID)
    return dataclasses.replace(estimate, flags=new)
