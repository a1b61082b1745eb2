"""Reading the estimate files ``margtrack run`` writes (HDF5 and CSV) back.

HDF5 (``format="margtrack-estimate"``, version 1): datasets ``t`` (N,) s, ``quat`` (N, 4)
``[w, x, y, z]`` body to earth, one per output (``gyr_bias_rad_s`` (N, 3) ...) and
``flags`` (N,) (bits of :class:`margtrack.estimator.Flag`); attributes ``method``,
``frame`` (earth frame of ``quat``), ``params`` (JSON); a ``unit`` attribute per dataset.

CSV (:mod:`margtrack.io.estimate_csv`): leading ``#`` lines (``key=value`` words such as
``frame=ENU method=robust`` are read; ``# params=`` holds the parameters as JSON and
``# units`` each column's unit), then the header ``t_s,quat_w,quat_x,quat_y,quat_z,
<outputs>``: a column ``name`` is an (N,) output, ``name_x,name_y,name_z`` an (N, 3) one,
``flags`` the flags. A CSV without a ``frame=`` word (written before margtrack stated it)
does not say its earth frame: pass ``frame=`` to :meth:`EstimateFile.estimate`.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from margtrack.estimator.estimate import Estimate
from margtrack.frames import check_frame
from margtrack.io.estimate_csv import PARAMS_PREFIX, UNITS_PREFIX

Array = NDArray[np.float64]

__all__ = ["EstimateFile", "is_estimate_file", "read_estimate"]

ESTIMATE_FORMAT = "margtrack-estimate"
VERSION = 1
CSV_COLUMNS = ("t_s", "quat_w", "quat_x", "quat_y", "quat_z")
#: largest tolerated deviation of |quat| from 1 (files hold float64 unit quaternions)
NORM_TOLERANCE = 1e-6
_KEY_VALUE = re.compile(r"(\w+)=(\S+)")


@dataclass(frozen=True)
class EstimateFile:
    """What an estimate file holds.

    t : (N,) s. quat : (N, 4) ``[w, x, y, z]``, body to ``frame``. frame : "ENU", "NED"
    or None when the file does not say (a CSV without a ``frame=`` line). method : the
    method name or None. params : the parameters stored (HDF5), else empty. outputs :
    per-sample series by name (units in the names). flags : (N,) uint16 or None.
    units : the unit of each dataset (HDF5) or column (CSV) the file states, else empty.
    """

    path: Path
    t: Array
    quat: Array
    frame: str | None
    method: str | None
    params: dict[str, Any] = field(default_factory=dict)
    outputs: dict[str, NDArray[Any]] = field(default_factory=dict)
    flags: NDArray[np.uint16] | None = None
    units: dict[str, str] = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.shape[0])

    def estimate(self, frame: str | None = None) -> Estimate:
        """As an :class:`~margtrack.estimator.Estimate`; ``frame`` declares an unstated frame.

        Raises ``ValueError`` when the file states no frame and none is given, or when the
        given frame contradicts the one the file states.
        """
        stated = self.frame
        if frame is not None:
            declared = check_frame(frame)
            if stated is not None and declared != stated:
                raise ValueError(
                    f"{self.path} says its frame is {stated}, not {declared}: leave the frame "
                    "out (use frames.convert / Estimate.in_frame to change it)"
                )
            stated = declared
        if stated is None:
            from margtrack.errors import with_cli_fix

            raise with_cli_fix(ValueError(
                f"{self.path} does not say its earth frame (a CSV without a 'frame=' line); "
                "declare it: --frame ENU or --frame NED (frame= in Python)"
            ), " (frame= in Python)", "")
        return Estimate(
            quat=self.quat, t=self.t, frame=check_frame(stated), method=self.method or "",
            params=dict(self.params), outputs=dict(self.outputs), flags=self.flags,
        )


def is_estimate_file(path: str | Path) -> bool:
    """True if ``path`` is an HDF5 or CSV estimate file (by its content, not its name)."""
    p = Path(path)
    if not p.is_file():
        return False
    if p.suffix.lower() in (".h5", ".hdf5"):
        try:
            with h5py.File(p, "r") as f:
                return f.attrs.get("format") == ESTIMATE_FORMAT
        except OSError:
            return False
    if p.suffix.lower() == ".csv":
        try:
            _, header, _ = _csv_header(p)
        except (ValueError, UnicodeDecodeError):
            return False
        return tuple(header[:5]) == CSV_COLUMNS
    return False


def read_estimate(path: str | Path) -> EstimateFile:
    """Read an estimate file written by ``margtrack run`` (``.h5``/``.hdf5`` or ``.csv``).

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` naming the file and
    the fix for anything else: not an estimate (a recording), another version, missing
    datasets or columns, shapes that disagree, a malformed or truncated CSV line (its line
    number), non-finite or non-unit quaternions and timestamps that do not increase (the
    first bad sample).
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such file: {p}")
    suffix = p.suffix.lower()
    if suffix in (".h5", ".hdf5"):
        est = _read_hdf5(p)
    elif suffix == ".csv":
        est = _read_csv(p)
    else:
        raise ValueError(f"cannot read {p} as an estimate: use a .h5, .hdf5 or .csv file")
    _check(est)
    return est


def _read_hdf5(p: Path) -> EstimateFile:
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise ValueError(f"{p} is not a readable HDF5 file (truncated?): {exc}") from None
    with f:
        fmt = f.attrs.get("format")
        if fmt != ESTIMATE_FORMAT:
            what = "a margtrack recording" if fmt == "margtrack-recording" else f"format {fmt!r}"
            raise ValueError(
                f"{p} is not an estimate ({what}); estimates are what `margtrack run` writes"
            )
        version = int(f.attrs.get("version", -1))
        if version != VERSION:
            raise ValueError(f"{p} is estimate version {version}; this margtrack reads {VERSION}")
        for key in ("t", "quat"):
            if key not in f:
                raise ValueError(f"{p} has no dataset {key!r}; it has {sorted(f.keys())}")
        json_attrs = set(json.loads(str(f.attrs.get("json_attrs", "[]"))))
        attrs = {
            k: json.loads(str(v)) if k in json_attrs else _plain(v)
            for k, v in f.attrs.items() if k not in ("format", "version", "json_attrs")
        }
        t = np.asarray(f["t"][()], dtype=np.float64)
        quat = np.asarray(f["quat"][()], dtype=np.float64)
        outputs = {k: f[k][()] for k in f if k not in ("t", "quat", "flags")}
        flags = f["flags"][()].astype(np.uint16) if "flags" in f else None
        units = {k: str(_plain(f[k].attrs["unit"])) for k in f if "unit" in f[k].attrs}
    frame = attrs.get("frame")
    return EstimateFile(
        path=p, t=t, quat=quat, frame=None if frame is None else check_frame(str(frame)),
        method=None if attrs.get("method") is None else str(attrs["method"]),
        params=dict(attrs.get("params") or {}), outputs=outputs, flags=flags, units=units,
    )


def _plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytes):
        return value.decode()
    return value


def _csv_header(p: Path) -> tuple[dict[str, str], list[str], int]:
    """``key=value`` pairs of the ``#`` lines, the column names, lines before the data.

    The ``# params=`` line comes back whole under ``"params"`` (JSON), the ``# units`` line
    as ``"unit:<column>"`` keys.
    """
    stated: dict[str, str] = {}
    with p.open(encoding="utf-8-sig") as f:
        for i, line in enumerate(f):
            line = line.rstrip("\r\n")
            if line.startswith(PARAMS_PREFIX):
                stated["params"] = line[len(PARAMS_PREFIX):]
            elif line.startswith(UNITS_PREFIX):
                stated.update(
                    (f"unit:{k}", v) for k, v in _KEY_VALUE.findall(line[len(UNITS_PREFIX):])
                )
            elif line.startswith("#"):
                stated.update(_KEY_VALUE.findall(line))
            elif line.strip():
                return stated, [c.strip() for c in line.split(",")], i + 1
    raise ValueError(f"{p}: no header line with column names")


def _read_csv(p: Path) -> EstimateFile:
    stated, header, skip = _csv_header(p)
    if tuple(header[:5]) != CSV_COLUMNS:
        hint = ""
        if "t_s" in header and "gyr_x_rad_s" in header:
            hint = " (it is a margtrack recording: run `margtrack run` on it first)"
        raise ValueError(
            f"{p} is not an estimate CSV: its columns start {header[:5]}, expected "
            f"{list(CSV_COLUMNS)}{hint}"
        )
    table = _csv_rows(p, len(header), skip)
    outputs: dict[str, NDArray[Any]] = {}
    flags = None
    k = 5
    while k < len(header):
        name = header[k]
        base = name[:-2]
        if name.endswith("_x") and header[k + 1 : k + 3] == [f"{base}_y", f"{base}_z"]:
            outputs[base] = table[:, k : k + 3]
            k += 3
            continue
        if name == "flags":
            flags = _flags(p, table[:, k])
        else:
            outputs[name] = table[:, k]
        k += 1
    frame = stated.get("frame")
    params: dict[str, Any] = {}
    if "params" in stated:
        try:
            params = dict(json.loads(stated["params"]))
        except (ValueError, TypeError) as exc:
            raise ValueError(
                f"{p}: the '# params=' line is not a JSON object ({exc}); remove the line "
                "or write the file again"
            ) from None
    try:
        frame = None if frame is None else check_frame(frame)
    except ValueError:
        raise ValueError(
            f"{p}: its header says frame={frame}, which is neither NED nor ENU; correct the "
            "'# margtrack-estimate' line or write the file again"
        ) from None
    units = {k.removeprefix("unit:"): v for k, v in stated.items() if k.startswith("unit:")}
    return EstimateFile(
        path=p, t=table[:, 0], quat=table[:, 1:5], frame=frame, method=stated.get("method"),
        params=params, outputs=outputs, flags=flags, units=units,
    )


def _csv_rows(p: Path, width: int, skip: int) -> Array:
    """The data rows as an (N, width) float64 array; a bad line is named by its number."""
    rows: list[list[float]] = []
    with p.open(encoding="utf-8-sig") as f:
        for number, line in enumerate(f, start=1):
            if number <= skip or not line.strip() or line.startswith("#"):
                continue
            cells = line.rstrip("\r\n").split(",")
            if len(cells) != width:
                raise ValueError(
                    f"{p}, line {number}: {len(cells)} values, the header has {width} columns "
                    "(a truncated or malformed line: remove it or write the file again)"
                )
            try:
                rows.append([float(c) for c in cells])
            except ValueError:
                raise ValueError(
                    f"{p}, line {number}: a value is not a number: {line.strip()[:80]!r}"
                ) from None
    if not rows:
        raise ValueError(f"{p} has a header but no data rows")
    return np.asarray(rows, dtype=np.float64)


def _flags(p: Path, column: Array) -> NDArray[np.uint16]:
    bad = ~np.isfinite(column) | (column < 0) | (column > 0xFFFF) | (column != np.round(column))
    if np.any(bad):
        i = int(np.argmax(bad))
        raise ValueError(
            f"{p}: flags at sample {i} is {float(column[i])!r}, not a 16-bit whole number"
        )
    return column.astype(np.uint16)


def _check(est: EstimateFile) -> None:
    p, t, q = est.path, est.t, est.quat
    n = t.shape[0] if t.ndim == 1 else -1
    if t.ndim != 1 or n == 0:
        raise ValueError(f"{p}: t must have shape (N,) with N >= 1, got {t.shape}")
    if q.shape != (n, 4):
        raise ValueError(f"{p}: quat has shape {q.shape}; expected ({n}, 4) to match t")
    for name, arr in est.outputs.items():
        if np.shape(arr)[:1] != (n,):
            raise ValueError(f"{p}: output {name!r} has {np.shape(arr)[:1]} samples, t has {n}")
    if est.flags is not None and est.flags.shape != (n,):
        raise ValueError(f"{p}: flags has shape {est.flags.shape}; expected ({n},)")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{p}: t is not finite at sample {int(np.argmin(np.isfinite(t)))}")
    if n > 1 and np.any(np.diff(t) <= 0.0):
        i = int(np.argmax(np.diff(t) <= 0.0)) + 1
        raise ValueError(
            f"{p}: t does not increase at sample {i} ({float(t[i - 1])!r} s then "
            f"{float(t[i])!r} s)"
        )
    finite = np.all(np.isfinite(q), axis=1)
    if not np.all(finite):
        raise ValueError(f"{p}: quat is not finite at sample {int(np.argmin(finite))}")
    off = np.abs(np.linalg.norm(q, axis=1) - 1.0) > NORM_TOLERANCE
    if np.any(off):
        i = int(np.argmax(off))
        raise ValueError(
            f"{p}: quat at sample {i} has norm {np.linalg.norm(q[i]):.6g}, not 1: not an "
            "orientation in [w, x, y, z] order"
        )
