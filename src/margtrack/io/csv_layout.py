"""Delimited text tables from any logger: delimiter and decimal sniffing, column maps, parsing.

A table is a header line of column names after optional ``#`` comment lines, then one row
per line. The delimiter is one of ``,`` ``;`` tab or whitespace, found from the header (the
one that splits it into the most names); the decimal separator is ``.`` or, when the
delimiter is not a comma, ``,`` if the data rows use it ("0,01;9,81"). Both can be forced.

Column maps name, per field of a Recording, the file's columns: ``{"t": ["time"], "gyr":
["gx", "gy", "gz"], ...}`` (keys :data:`FIELD_WIDTHS`). :func:`guess_columns` proposes one
from header names (``gx``, ``gyr_x``, ``Gyroscope x (rad/s)``...), :func:`column_flags` writes
it as the ``--column`` flags of the command line, for error messages that give the fix.
"""

from __future__ import annotations

import io as _io
import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = [
    "FIELD_WIDTHS",
    "MappingHint",
    "Table",
    "column_flags",
    "guess_columns",
    "guess_units",
    "normalise_columns",
    "read_table",
    "sniff",
]

FIELD_WIDTHS = {"t": 1, "gyr": 3, "acc": 3, "mag": 3, "quat_true": 4, "movement": 1}
DELIMITERS = {",": ",", ";": ";", "\t": "\t", "tab": "\t", "whitespace": None, " ": None}
_NAN_TEXT = {"", "nan", "NaN", "NAN", "-nan", "null", "NULL", "None", "NA", "N/A"}


@dataclass(frozen=True)
class Table:
    """A sniffed table: how to split it and where its data starts.

    delimiter : ``","``, ``";"``, ``"\\t"`` or None (runs of whitespace).
    decimal : ``"."`` or ``","``.
    header : the column names, quotes and surrounding spaces removed.
    comments : the ``#`` lines before the header.
    skip : number of lines before the first data line.
    """

    path: Path
    delimiter: str | None
    decimal: str
    header: list[str]
    comments: list[str]
    skip: int

    def split(self, line: str) -> list[str]:
        """The fields of one line (quotes and spaces around each field removed)."""
        parts = line.split() if self.delimiter is None else line.split(self.delimiter)
        return [p.strip().strip('"').strip() for p in parts]


def _delimiter_name(delimiter: str | None) -> str:
    return {"\t": "tab", None: "whitespace"}.get(delimiter, repr(delimiter))  # type: ignore[arg-type]


def sniff(path: Path, delimiter: str | None = None, decimal: str | None = None) -> Table:
    """Find the header, delimiter and decimal separator of the table at ``path``.

    ``delimiter`` (``","``, ``";"``, ``"tab"``, ``"whitespace"``) and ``decimal`` (``"."``,
    ``","``) force the choice; None detects them.
    """
    if delimiter is not None and delimiter not in DELIMITERS:
        raise ValueError(
            f"delimiter must be one of {sorted(DELIMITERS)}, got {delimiter!r}"
        )
    if decimal not in (None, ".", ","):
        raise ValueError(f"decimal must be '.' or ',', got {decimal!r}")
    comments: list[str] = []
    header_line, skip = None, 0
    sample: list[str] = []
    with path.open(encoding="utf-8-sig", errors="replace") as f:  # -sig: a byte-order mark
        for i, raw in enumerate(f):
            line = raw.rstrip("\r\n")
            if header_line is None:
                if line.startswith("#"):
                    comments.append(line)
                elif line.strip():
                    header_line, skip = line, i + 1
            elif line.strip() and not line.startswith("#"):
                sample.append(line)
                if len(sample) >= 20:
                    break
    if header_line is None:
        raise ValueError(f"{path}: no header line with column names (the file is empty)")
    if delimiter is not None:
        delim = DELIMITERS[delimiter]
    else:
        counts = {d: len(header_line.split(d)) for d in ("\t", ";", ",")}
        best = max(counts, key=lambda d: counts[d])
        delim = best if counts[best] > 1 else None
    if decimal is None:
        decimal = "."
        if delim != "," and any(re.search(r"\d,\d", s) for s in sample):
            decimal = ","
    elif decimal == "," and delim == ",":
        raise ValueError(
            f"{path}: a comma cannot be both the delimiter and the decimal separator"
        )
    table = Table(path, delim, decimal, [], comments, skip)
    header = table.split(header_line)
    return Table(path, delim, decimal, header, comments, skip)


def _data_lines(table: Table) -> list[tuple[int, str]]:
    """(1-based line number, text) of every data line (blank and ``#`` lines left out)."""
    text = table.path.read_text(encoding="utf-8-sig", errors="replace")
    lines = text.splitlines()
    return [
        (i + 1, line) for i, line in enumerate(lines[table.skip:], start=table.skip)
        if line and not line.startswith("#") and not line.isspace()
    ]


def _field_count(table: Table, line: str) -> int:
    """Fields on a data line (counting delimiters: numbers never hold one)."""
    if table.delimiter is None:
        return len(line.split())
    return line.count(table.delimiter) + 1


def _number(text: str, decimal: str) -> float:
    if text in _NAN_TEXT:
        return float("nan")
    return float(text.replace(",", ".") if decimal == "," else text)


def read_table(table: Table, names: Sequence[str]) -> tuple[Array, NDArray[np.intp], int | None]:
    """Columns ``names`` of every data row as an (N, len(names)) float64 array.

    Empty cells and ``nan``/``NA``/``null`` read as NaN. Returns the array, the 1-based file
    line number of each row, and the line number of a truncated last line that was left out
    (fewer fields than the header: a logger stopped mid-write), or None.

    Raises ``ValueError`` naming the line for a row with the wrong number of fields (other
    than the last) or a cell that is not a number.
    """
    missing = [n for n in names if n not in table.header]
    if missing:
        raise KeyError(missing[0])
    index = [table.header.index(n) for n in names]
    width = len(table.header)
    rows = _data_lines(table)
    if not rows:
        raise ValueError(f"{table.path}: the file has a header but no data rows")
    dropped = None
    last_no, last = rows[-1]
    if _field_count(table, last) < width and len(rows) > 1:
        dropped = last_no
        rows = rows[:-1]
        warnings.warn(
            f"{table.path}: line {last_no} is truncated ({_field_count(table, last)} of {width} "
            "fields; the logger stopped while writing it): left out",
            UserWarning, stacklevel=3,
        )
    counts = np.fromiter((_field_count(table, line) for _, line in rows), np.intp, len(rows))
    for i in np.flatnonzero(counts != width)[:1]:
        no, n_fields = rows[i][0], int(counts[i])
        raise ValueError(
            f"{table.path}: line {no} has {n_fields} fields but the header has {width} "
            f"(delimiter {_delimiter_name(table.delimiter)}): fix or delete that line"
        )
    lines = np.array([no for no, _ in rows], dtype=np.intp)
    text = "\n".join(line for _, line in rows)
    if table.decimal == ",":
        text = text.replace(",", ".")
    try:  # fast path: a clean numeric table
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data = np.loadtxt(
                _io.StringIO(text), delimiter=table.delimiter, usecols=index, ndmin=2,
                dtype=np.float64, comments=None,
            )
        if data.shape[0] == len(rows):
            return data, lines, dropped
    except ValueError:
        pass
    data = np.empty((len(rows), len(names)), dtype=np.float64)
    for r, (no, line) in enumerate(rows):
        fields = table.split(line)
        for c, k in enumerate(index):
            try:
                data[r, c] = _number(fields[k], table.decimal)
            except ValueError:
                raise ValueError(
                    f"{table.path}: non-numeric data in columns [{names[c]!r}] on line {no}: "
                    f"{fields[k]!r} is not a number (decimal separator {table.decimal!r})"
                ) from None
    return data, lines, dropped


def normalise_columns(columns: Mapping[str, Sequence[str] | str]) -> dict[str, list[str]]:
    """A column map with every value a list of names (``"gx,gy,gz"`` is split at commas).

    Raises ``ValueError`` for an unknown field or a wrong number of names.
    """
    out: dict[str, list[str]] = {}
    for field, value in columns.items():
        if field not in FIELD_WIDTHS:
            raise ValueError(
                f"columns has unknown fields [{field!r}]; the fields are {sorted(FIELD_WIDTHS)}"
            )
        names = [n.strip() for n in value.split(",")] if isinstance(value, str) else [
            str(n) for n in value
        ]
        if len(names) != FIELD_WIDTHS[field]:
            what = "x, y, z" if FIELD_WIDTHS[field] == 3 else "w, x, y, z"
            raise ValueError(
                f"columns[{field!r}] must name {FIELD_WIDTHS[field]} column(s)"
                + (f" ({what})" if FIELD_WIDTHS[field] > 1 else "") + f", got {names}"
            )
        out[field] = names
    return out


# --- guessing a column map from header names ------------------------------------------

#: time words of the usual languages, once a unit is left out (``Zeit [ms]``, ``time_ms``)
_TIME_WORDS = frozenset({
    "t", "ts", "time", "times", "timestamp", "timestamps", "time stamp", "time_stamp",
    "sec", "secs", "seconds", "seconds_elapsed", "elapsed", "elapsed time",
    "zeit", "zeitstempel", "temps", "horodatage", "tiempo", "marca de tiempo", "tempo",
    "tijd", "tid", "czas", "aika", "время",
})
#: a unit written after a name: in brackets or parentheses, or as a suffix (``_ms``)
_UNIT_PART = re.compile(
    r"\s*[\(\[][^\)\]]*[\)\]]\s*$"
    r"|[_\-\. ](s|ms|us|µs|ns|sec|rad_?s|deg_?s|dps|m_?s2|m_?s\^?2|g|ut|nt|mt|gauss)$",
    re.IGNORECASE,
)


def _without_unit(name: str) -> str:
    """``name`` without a trailing unit, lower case: ``"Zeit [ms]"`` -> ``"zeit"``."""
    base = name.strip()
    for _ in range(2):  # "time_ms [ms]"
        base = _UNIT_PART.sub("", base).strip()
    return base.lower()


def _is_time(name: str) -> bool:
    """Whether a column name is a time word of some language, with or without a unit."""
    return name.strip().lower() in _TIME_WORDS or _without_unit(name) in _TIME_WORDS


_PREFIXES = {
    "gyr": ("gyroscope", "gyro", "gyr", "g", "w", "omega", "rotation rate", "rotationrate",
            "angular velocity", "angvel", "rate"),
    "acc": ("acceleration", "accelerometer", "accel", "acc", "a", "totalacceleration",
            "total acceleration"),
    "mag": ("magnetic field", "magnetometer", "magnetic", "mag", "m", "b", "compass"),
    "quat_true": ("quat_true", "quat", "q", "truth", "opt_quat", "quaternion"),
}


def _split_name(name: str) -> tuple[str, str]:
    """(prefix, axis) of a column name like ``gyr_x``, ``gx``, ``Gyroscope x (rad/s)``."""
    base = re.sub(r"\s*[\(\[].*?[\)\]]\s*", " ", name).strip().lower()
    base = re.sub(r"[_\-\.]+(rad_?s|deg_?s|dps|m_?s2|m_?s\^?2|g|ut|nt|mt|gauss)$", "", base)
    m = re.match(r"^(.*?)[\s_\-\.]*([wxyz])$", base)
    if not m:
        return base, ""
    return m.group(1).strip(" _-."), m.group(2)


def guess_columns(header: Sequence[str]) -> dict[str, list[str]]:
    """A column map proposed from header names; fields it cannot place are left out."""
    out: dict[str, list[str]] = {}
    for name in header:
        if _is_time(name) and "t" not in out:
            out["t"] = [name]
    groups: dict[tuple[str, str], str] = {}
    for name in header:
        prefix, axis = _split_name(name)
        if axis:
            groups.setdefault((prefix, axis), name)
    for field, prefixes in _PREFIXES.items():
        axes = "wxyz" if field == "quat_true" else "xyz"
        for prefix in prefixes:
            if all((prefix, a) in groups for a in axes):
                out[field] = [groups[(prefix, a)] for a in axes]
                break
    return out


def _stated(unit: str, flags: int = re.IGNORECASE) -> re.Pattern[str]:
    """A pattern finding ``unit`` (a regular expression) stated in a column name: in
    brackets or parentheses (``[ms]``, ``(deg/s)``) or as a suffix (``_ms``, `` g``)."""
    return re.compile(rf"([\(\[]\s*({unit})\s*[\)\]]|[_ \-\.]({unit})$)", flags)


_UNIT_HINTS = (
    ("time", _stated("ns"), "ns"),
    ("time", _stated("us|µs"), "us"),
    ("time", _stated("ms"), "ms"),
    ("gyr", re.compile(r"(deg/s|°/s|deg_?s$|dps)", re.I), "deg/s"),
    ("acc", _stated("g"), "g"),
    ("mag", _stated("nT", 0), "nT"),
    ("mag", _stated("mG", 0), "mG"),
    ("mag", re.compile(r"([\(\[]\s*G\s*[\)\]]|gauss)", re.I), "G"),
)


def guess_units(columns: Mapping[str, Sequence[str]]) -> dict[str, str]:
    """Units the mapped names state (``Zeit [ms]``, ``time_ms`` -> ms; ``(deg/s)``, ``_dps``
    -> deg/s; ``[g]``, ``_g`` -> g), for the signals not in margtrack's own units."""
    out: dict[str, str] = {}
    for signal, pattern, unit in _UNIT_HINTS:
        field = "t" if signal == "time" else signal
        names = columns.get(field) or []
        if signal not in out and names and pattern.search(names[0]):
            out[signal] = unit
    return out


def _quote(text: str) -> str:
    """``text`` as one word of a shell command line, quoted when it has to be."""
    if not re.search(r"[\s\"'();&|<>$\[\]*?!#`\\{}~]", text):
        return text
    if re.search(r"[\"$`\\!]", text):
        return "'" + text.replace("'", "'\\''") + "'"
    return f'"{text}"'


def column_flags(columns: Mapping[str, Sequence[str]], units: Mapping[str, str] = {}) -> str:
    """The command-line flags for a column map (and units): ``--column t=time ...``."""
    parts = [f"--column {_quote(f'{field}=' + ','.join(names))}"
             for field, names in columns.items()]
    parts += [f"--{signal}-unit {unit}" for signal, unit in units.items()]
    return " ".join(parts)


@dataclass(frozen=True)
class MappingHint:
    """How to map a table's columns, guessed from its header, in both spellings.

    python : ``"map them with read(path, columns={...}, time_unit='ms') (on the command
        line: --column ...)"``.
    cli : the command line's, flags that run as pasted when the guess is whole: ``"map
        them with --column "t=Zeit [ms]" ... --time-unit ms"``.
    """

    python: str
    cli: str


def mapping_hint(
    header: Sequence[str], have: Mapping[str, Sequence[str]] | None = None
) -> MappingHint:
    """How to map ``header``: the column map guessed from the names with the units they
    state (``[ms]``, ``(deg/s)``, ``_g``), as ``--column`` flags and as ``read``'s keywords;
    ``have`` are the fields already mapped correctly."""
    guess = dict(have or {})
    for field, names in guess_columns(header).items():
        guess.setdefault(field, names)
    if not ("gyr" in guess and "acc" in guess):
        flags = ("--column t=TIME --column gyr=GX,GY,GZ --column acc=AX,AY,AZ [--column "
                 "mag=MX,MY,MZ]")
        return MappingHint(
            "map them with read(path, columns={'t': TIME, 'gyr': [GX, GY, GZ], 'acc': [AX, "
            f"AY, AZ]}}) using the file's names (on the command line: {flags})",
            f"map them with {flags} using the file's names",
        )
    units = guess_units(guess)
    flags = column_flags(guess, units)
    py = {k: v[0] if len(v) == 1 else v for k, v in guess.items()}
    keywords = "".join(f", {signal}_unit={unit!r}" for signal, unit in units.items())
    check = " (guessed from the names: check them)"
    if "t" not in guess:
        return MappingHint(
            f"map them with read(path, columns={ {'t': 'TIME', **py} }{keywords}), TIME the "
            f"time column's name (none was recognised; on the command line: {flags} "
            "--column t=TIME)",
            f"map them with {flags} and the time column, --column t=NAME (none was "
            f"recognised){check}",
        )
    return MappingHint(
        f"map them with read(path, columns={py}{keywords}) (on the command line: {flags})"
        f"{check}",
        f"map them with {flags}{check}",
    )
