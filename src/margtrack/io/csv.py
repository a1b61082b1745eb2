"""CSV recordings: margtrack's own self-describing layout, and any CSV through a column mapping.

margtrack CSV (written by :func:`write_csv`, read back exactly by :func:`read_csv`)::

    # margtrack-recording v1 frame=ENU name=<name, rest of the line>
    # meta=<JSON object>
    t_s,gyr_x_rad_s,gyr_y_rad_s,gyr_z_rad_s,acc_x_m_s2,acc_y_m_s2,acc_z_m_s2,mag_x,mag_y,mag_z,quat_true_w,quat_true_x,quat_true_y,quat_true_z,movement

The ``mag``, ``quat_true`` and ``movement`` columns are present only when the Recording has
them. Floats are written with ``repr`` (the shortest string that parses back to the same
float64), so a write/read round trip is exact; ``movement`` is written as 0/1.

Estimate CSV (:func:`write_estimate_csv`) is in :mod:`margtrack.io.estimate_csv`, re-exported
here.
"""

from __future__ import annotations

import json
import re
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.errors import InputError
from margtrack.frames import check_frame
from margtrack.io.estimate_csv import (
    CSV_BLOCK_ROWS,
    EstimateCsvTable,
    estimate_csv_table,
    write_estimate_csv,
)
from margtrack.io.hdf5 import _existing_file, _naming_path, _writable, meta_to_json
from margtrack.io.safe_output import atomic_output
from margtrack.recording import Recording
from margtrack.units import unit_factor

# the estimate table lives in margtrack.io.estimate_csv; its names stay importable from here
__all__ = [
    "EstimateCsvTable", "estimate_csv_table", "read_csv", "write_csv", "write_estimate_csv",
]

MAGIC = "# margtrack-recording"
_FIRST_LINE = re.compile(r"^# margtrack-recording v(\d+) frame=(\S+) name=(.*)$")
_FIELD_COLUMNS = {
    "t": ["t_s"],
    "gyr": ["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"],
    "acc": ["acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"],
    "mag": ["mag_x", "mag_y", "mag_z"],
    "quat_true": ["quat_true_w", "quat_true_x", "quat_true_y", "quat_true_z"],
    "movement": ["movement"],
}
_FIELD_WIDTHS = {"t": 1, "gyr": 3, "acc": 3, "mag": 3, "quat_true": 4, "movement": 1}


def _header(path: Path) -> tuple[list[str], list[str], int]:
    """Leading ``#`` comment lines, the column names, and the number of lines before the data."""
    comments: list[str] = []
    with path.open(encoding="utf-8-sig") as f:  # -sig: tolerate a byte-order mark
        for i, line in enumerate(f):
            line = line.rstrip("\r\n")
            if line.startswith("#"):
                comments.append(line)
            elif line.strip():
                names = [c.strip().strip('"').strip() for c in line.split(",")]
                return comments, names, i + 1
    raise ValueError(f"{path}: no header line with column names")


def _load(
    path: Path, names: list[str], header: list[str], skip: int, hint: str = ""
) -> NDArray[np.float64]:
    """Columns ``names`` (in that order) of the data rows as an (N, len(names)) float64 array."""
    missing = [n for n in names if n not in header]
    if missing:
        raise ValueError(f"{path}: no column {missing[0]!r}; the file has columns {header}{hint}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # an empty file is reported below
        try:
            data = np.loadtxt(
                path, delimiter=",", skiprows=skip, ndmin=2, dtype=np.float64,
                usecols=[header.index(n) for n in names], comments="#",
            )
        except ValueError as exc:
            raise ValueError(f"{path}: non-numeric data in columns {names}: {exc}") from None
    if data.shape[0] == 0:
        raise ValueError(f"{path}: the file has a header but no data rows")
    return data


def _load_fields(
    path: Path, fields: Mapping[str, list[str]], header: list[str], skip: int, hint: str = ""
) -> dict[str, NDArray[np.float64]]:
    """Read the columns of several fields in one pass; 1-column fields come back as (N,)."""
    names = [c for cols in fields.values() for c in cols]
    data = _load(path, names, header, skip, hint)
    out: dict[str, NDArray[np.float64]] = {}
    start = 0
    for field, cols in fields.items():
        block = data[:, start:start + len(cols)]
        out[field] = block[:, 0].copy() if len(cols) == 1 else block.copy()
        start += len(cols)
    return out


def _movement(values: NDArray[np.float64], column: str) -> NDArray[np.bool_]:
    bad = np.flatnonzero((values != 0.0) & (values != 1.0))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"column {column!r} has value {float(values[i])!r} at sample {i}; "
            "movement must be 0 or 1"
        )
    return values == 1.0


def is_margtrack_csv(path: str | Path) -> bool:
    """True if the first line of the file at ``path`` is margtrack's CSV signature."""
    with Path(path).open(encoding="utf-8", errors="replace") as f:
        return f.readline().startswith(MAGIC)


def write_csv(rec: Recording, path: str | Path) -> None:
    """Write ``rec`` as margtrack CSV (SI units in the column names, exact floats).

    Parameters
    ----------
    rec : the Recording; all its fields, including ``frame``, ``name`` and ``meta``, are kept.
    path : file to create or overwrite; its folder must exist.
    """
    p = _writable(path)
    if "\n" in rec.name or "\r" in rec.name:
        raise ValueError(f"name {rec.name!r} contains a line break, which CSV cannot keep")
    blocks: list[NDArray[np.float64]] = [rec.t[:, None], rec.gyr, rec.acc]
    names = [*_FIELD_COLUMNS["t"], *_FIELD_COLUMNS["gyr"], *_FIELD_COLUMNS["acc"]]
    for field in ("mag", "quat_true"):
        value = getattr(rec, field)
        if value is not None:
            blocks.append(value)
            names += _FIELD_COLUMNS[field]
    lines = [
        f"{MAGIC} v1 frame={rec.frame} name={rec.name}",
        f"# meta={meta_to_json(rec.meta)}",
        ",".join(names + (["movement"] if rec.movement is not None else [])),
    ]
    table = np.hstack(blocks)
    with atomic_output(p) as tmp, tmp.open("w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
        for start in range(0, table.shape[0], CSV_BLOCK_ROWS):
            part = np.s_[start : start + CSV_BLOCK_ROWS]  # bounded memory: one block of text
            rows = [",".join(map(repr, row)) for row in table[part].tolist()]
            if rec.movement is not None:
                moving = rec.movement[part].tolist()
                rows = [f"{row},{int(m)}" for row, m in zip(rows, moving, strict=True)]
            f.write("\n".join(rows) + "\n")


def _read_margtrack(path: Path, comments: list[str], header: list[str], skip: int) -> Recording:
    match = _FIRST_LINE.match(comments[0])
    if match is None:
        raise ValueError(f"{path}: malformed first line {comments[0]!r}")
    if match.group(1) != "1":
        raise ValueError(f"{path}: margtrack CSV version {match.group(1)} is not supported (1 is)")
    meta: dict[str, Any] = {}
    for line in comments[1:]:
        if line.startswith("# meta="):
            meta = json.loads(line[len("# meta="):])
    known = [c for cols in _FIELD_COLUMNS.values() for c in cols]
    extra = [c for c in header if c not in known]
    if extra:
        fix = "read it with read_csv(path, columns={...}) to choose columns"
        raise InputError(
            f"{path}: unexpected columns {extra} in a margtrack CSV; {fix}", fix=fix,
            cli_fix="choose its columns with --column KEY=NAME[,NAME,NAME]",
        )
    wanted = {
        field: cols for field, cols in _FIELD_COLUMNS.items()
        if field in ("t", "gyr", "acc") or any(c in header for c in cols)
    }
    fields: dict[str, Any] = _load_fields(path, wanted, header, skip)
    if "movement" in fields:
        with _naming_path(path):
            fields["movement"] = _movement(fields["movement"], "movement")
    with _naming_path(path):
        return Recording(frame=match.group(2), name=match.group(3), meta=meta, **fields)


def read_csv(
    path: str | Path,
    columns: Mapping[str, Sequence[str] | str] | None = None,
    gyr_unit: str = "rad/s",
    acc_unit: str = "m/s2",
    time_unit: str = "s",
    rate_hz: float | None = None,
    frame: str | None = None,
    check_units: bool = True,
    mag_unit: str | None = None,
    delimiter: str | None = None,
    decimal: str | None = None,
) -> Recording:
    """Read a Recording from margtrack CSV, or from any delimited text file via ``columns``.

    Parameters
    ----------
    path : the CSV file. Lines starting with ``#`` before the header are comments.
    columns : None for margtrack CSV (its header fixes columns, SI units, frame, name and meta).
        Otherwise a mapping from field to column names in the file: ``"gyr"`` and ``"acc"``
        (3 each, x y z) are required; ``"t"`` (1), ``"mag"`` (3), ``"quat_true"`` (4,
        ``w x y z``; NaN or empty rows are truth holes, skipped by the metrics) and
        ``"movement"`` (1, values 0/1) are optional. A value may be one string,
        ``"gx,gy,gz"``. Empty or non-finite gyr/acc/mag cells are held and flagged (see
        :mod:`margtrack.io.mapped`); a truncated last line is left out with a warning.
    delimiter, decimal : for mapped files: ``","``, ``";"``, ``"tab"``, ``"whitespace"`` and
        ``"."``, ``","``; None (default) detects them (:func:`margtrack.io.csv_layout.sniff`).
    gyr_unit : "rad/s" or "deg/s", the unit of the gyr columns (converted to rad/s).
    acc_unit : "m/s2" or "g", the unit of the acc columns (converted to m/s²).
    time_unit : "s", "ms", "us" or "ns", the unit of the time column (converted to s).
    mag_unit : the unit of the mag columns, one of ``margtrack.recording.MAG_UNITS`` ("uT",
        "nT", "G"...), converted to µT; None (default) keeps the values as they are.
    rate_hz : the sampling rate, Hz, required when no time column is mapped (never assumed);
        giving both a time column and ``rate_hz`` is an error.
    frame : earth frame of ``quat_true``; None means the file's frame for margtrack CSV and
        "ENU" otherwise.
    check_units : refuse gyr that looks like deg/s and acc that looks like g (mapped files;
        margtrack CSV is SI by construction) with a :class:`~margtrack.recording.UnitError`.

    Returns
    -------
    Recording named after the file stem (mapped files), with ``meta["source"]`` the path,
    ``meta["units"]`` the declared units and ``meta["units_converted"]`` those that changed
    the values (see :meth:`~margtrack.recording.Recording.with_units`).
    """
    p = _existing_file(path)
    comments, header, skip = _header(p)
    if columns is None:
        if not (comments and comments[0].startswith(MAGIC)):
            from margtrack.io.csv_layout import mapping_hint, sniff

            header = sniff(p, delimiter, decimal).header
            hint = mapping_hint(header)
            raise InputError(
                f"{p} is not a margtrack CSV (its first line is not '{MAGIC} ...'); "
                f"the file has columns {header}; {hint.python}",
                fix=hint.python, cli_fix=hint.cli,
            )
        given = {"gyr_unit": (gyr_unit, "rad/s"), "acc_unit": (acc_unit, "m/s2"),
                 "time_unit": (time_unit, "s"), "mag_unit": (mag_unit, None),
                 "rate_hz": (rate_hz, None)}
        for arg, (value, default) in given.items():
            if value != default:
                raise ValueError(
                    f"{p} is a margtrack CSV, which is SI with timestamps; {arg}={value!r} "
                    "does not apply: leave it out, or pass columns= to map the file yourself"
                )
        rec = _read_margtrack(p, comments, header, skip)
        if frame is not None and check_frame(frame) != rec.frame:
            raise ValueError(f"{p} has frame {rec.frame}, not {frame!r}; leave frame=None")
        return rec
    units = {"gyr": gyr_unit, "acc": acc_unit, "time": time_unit, "mag": mag_unit}
    return _read_mapped(p, columns, units, rate_hz, "ENU" if frame is None else frame,
                        check_units, delimiter, decimal)


def _read_mapped(
    path: Path, columns: Mapping[str, Sequence[str] | str], units: dict[str, str | None],
    rate_hz: float | None, frame: str, check_units: bool,
    delimiter: str | None = None, decimal: str | None = None,
) -> Recording:
    """Any delimited table through a column map (:mod:`margtrack.io.csv_layout`)."""
    from margtrack.io.csv_layout import mapping_hint, normalise_columns, read_table, sniff
    from margtrack.io.mapped import build_recording

    mapping = normalise_columns(columns)
    for required in ("gyr", "acc"):
        if required not in mapping:
            raise ValueError(f"columns must map {required!r} to 3 column names (x, y, z)")
    for signal, unit in units.items():
        if unit is not None:
            unit_factor(signal, unit)  # unknown units fail early
    if "t" in mapping and rate_hz is not None:
        raise ValueError("give either a time column (columns['t']) or rate_hz, not both")
    if "t" not in mapping and rate_hz is None:
        fix = ("map one (columns={'t': NAME, ...}) or give the sampling rate in Hz "
               "(rate_hz=...; no rate is assumed)")
        raise InputError(
            f"{path}: no time column mapped; {fix}", fix=fix,
            cli_fix="map one with --column t=NAME, or give the sampling rate in an import "
            "profile (rate_hz = ... with --profile; no rate is assumed)",
        )
    table = sniff(path, delimiter, decimal)
    names = [c for cols in mapping.values() for c in cols]
    try:
        values, lines, dropped = read_table(table, names)
    except KeyError as exc:
        good = {k: v for k, v in mapping.items() if all(c in table.header for c in v)}
        hint = mapping_hint(table.header, good)
        raise InputError(
            f"{path}: no column {exc.args[0]!r}; the file has columns {table.header}; "
            + hint.python, fix=hint.python, cli_fix=hint.cli,
        ) from None
    data: dict[str, NDArray[np.float64]] = {}
    start = 0
    for field, cols in mapping.items():
        block = values[:, start:start + len(cols)]
        data[field] = block[:, 0].copy() if len(cols) == 1 else block.copy()
        start += len(cols)
    meta: dict[str, Any] = {"source": str(path), "columns": mapping}
    if table.delimiter != "," or table.decimal != ".":
        meta["layout"] = {"delimiter": table.delimiter or "whitespace", "decimal": table.decimal}
    if dropped is not None:
        meta["dropped_lines"] = [int(dropped)]
    return build_recording(
        str(path), data, units, rate_hz=rate_hz, frame=frame, name=path.stem, meta=meta,
        lines=lines, check_units=check_units, fix_where="read_csv", columns=mapping,
    )
