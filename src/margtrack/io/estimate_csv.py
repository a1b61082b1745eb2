"""Estimate CSV: an orientation series as a self-describing table (frame, method, units).

Layout (written by :func:`write_estimate_csv` and, chunk by chunk, by
:class:`~margtrack.io.estimate_writer.EstimateWriter`; read by
:func:`margtrack.io.estimate_reader.read_estimate`)::

    # margtrack-estimate v1 method=robust frame=ENU quat=[w,x,y,z] body-to-earth
    # params={"gain": 0.1, ...}
    # units t_s=s quat_w=1 quat_x=1 quat_y=1 quat_z=1 gyr_bias_rad_s_x=rad/s ... flags=bits
    t_s,quat_w,quat_x,quat_y,quat_z,gyr_bias_rad_s_x,...,flags

``frame`` is the earth frame of ``quat`` (the body-to-earth orientation, ``v_earth = q ⊗
v_body ⊗ q*``); ``method=``, ``frame=`` and the ``params`` line are left out when the
writer is not told them (a reader then asks for the frame). The units come from the names
(:mod:`margtrack.io.output_units`). Floats are written with ``repr`` (exact round trip),
booleans and whole numbers (flags) as whole numbers. Any CSV reader that skips ``#``
lines (``np.loadtxt``, ``pandas.read_csv(comment="#")``) reads the table.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.frames import check_frame
from margtrack.io.hdf5 import _json_default, _writable
from margtrack.io.output_units import output_unit
from margtrack.io.safe_output import atomic_output

__all__ = [
    "CSV_BLOCK_ROWS",
    "ESTIMATE_MAGIC",
    "EstimateCsvTable",
    "estimate_csv_table",
    "write_estimate_csv",
]

#: rows formatted at a time when writing CSV (bounds the memory the text takes)
CSV_BLOCK_ROWS = 10_000
#: the start of an estimate CSV's first line
ESTIMATE_MAGIC = "# margtrack-estimate v1"
#: the comment line that lists each column's unit
UNITS_PREFIX = "# units "
#: the comment line that holds the parameters (JSON)
PARAMS_PREFIX = "# params="


def write_estimate_csv(
    path: str | Path,
    t: ArrayLike,
    quat: ArrayLike,
    outputs: Mapping[str, ArrayLike] | None = None,
    *,
    method: str | None = None,
    frame: str | None = None,
    params: Mapping[str, Any] | None = None,
) -> None:
    """Write an orientation estimate as CSV: ``t_s,quat_w,quat_x,quat_y,quat_z,<outputs>``.

    Parameters
    ----------
    path : file to create or overwrite (atomically: a temporary file renamed into place).
    t : (N,) timestamps, s.
    quat : (N, 4) orientation ``[w, x, y, z]`` of the body in the earth frame ``frame``.
    outputs : other per-sample series, name (with its unit, e.g. ``"bias_rad_s"``) to array
        with first axis N. (N,) gives one column ``name``; (N, 3) gives ``name_x/_y/_z``;
        any other shape is flattened row-major per sample to ``name_0 .. name_{k-1}``.
        Booleans and integers (flags) are written as whole numbers (1, 0, 34).
    method, frame, params : the run's method name, earth frame ("NED"/"ENU") and
        parameters, stated in the comment lines (module docstring); None leaves them out.
    """
    table = estimate_csv_table(t, quat, outputs, method=method, frame=frame, params=params)
    with atomic_output(_writable(path)) as tmp, tmp.open("w", encoding="utf-8") as f:
        f.write(table.header())
        for text in table.row_blocks():
            f.write(text)


class EstimateCsvTable:
    """The columns of an estimate as CSV: names, units, which are whole numbers, the values.

    Built by :func:`estimate_csv_table`; :meth:`header` is the comment lines and the column
    names, :meth:`row_blocks` the data lines, formatted ``CSV_BLOCK_ROWS`` at a time
    (floats with ``repr``: exact).
    """

    def __init__(
        self,
        names: list[str],
        integer: list[bool],
        blocks: list[NDArray[Any]],
        units: list[str] | None = None,
        stated: Mapping[str, str] | None = None,
    ):
        self.names = names
        self.integer = integer
        self.blocks = blocks
        self.units = units if units is not None else ["unstated"] * len(names)
        self.stated = dict(stated or {})

    def header(self) -> str:
        """The comment lines (signature, method, frame, params, units) and the column names."""
        words = [ESTIMATE_MAGIC]
        for key in ("method", "frame"):
            if key in self.stated:
                words.append(f"{key}={self.stated[key]}")
        words.append("quat=[w,x,y,z] body-to-earth")
        lines = [" ".join(words)]
        if "params" in self.stated:
            lines.append(PARAMS_PREFIX + self.stated["params"])
        lines.append(UNITS_PREFIX + " ".join(
            f"{n}={u}" for n, u in zip(self.names, self.units, strict=True)
        ))
        lines.append(",".join(self.names))
        return "\n".join(lines) + "\n"

    def row_blocks(self) -> Iterator[str]:
        """Successive strings of up to ``CSV_BLOCK_ROWS`` data lines, each ending in a break."""
        n = self.blocks[0].shape[0]
        for start in range(0, n, CSV_BLOCK_ROWS):
            part = np.s_[start : start + CSV_BLOCK_ROWS]
            columns: list[list[str]] = []
            for block, first in zip(self.blocks, self._offsets(), strict=True):
                for j in range(block.shape[1]):
                    values = block[part, j]
                    if self.integer[first + j]:
                        columns.append(list(map(str, values.astype(np.int64).tolist())))
                    else:
                        columns.append(list(map(repr, values.tolist())))
            yield "\n".join(map(",".join, zip(*columns, strict=True))) + "\n"

    def _offsets(self) -> list[int]:
        out, k = [], 0
        for block in self.blocks:
            out.append(k)
            k += block.shape[1]
        return out


def _output_columns(name: str, value: NDArray[Any], n: int) -> tuple[list[str], NDArray[Any]]:
    if value.shape[:1] != (n,):
        raise ValueError(f"output {name!r} has shape {value.shape}; its first axis must be N={n}")
    if "," in name or "\n" in name or "=" in name or " " in name or not name:
        raise ValueError(
            f"output name {name!r} must be non-empty without commas, spaces, '=' or line breaks"
        )
    if value.ndim == 1:
        return [name], value[:, None]
    flat = value.reshape(n, -1)
    k = flat.shape[1]
    suffixes = ["x", "y", "z"] if value.ndim == 2 and k == 3 else [str(j) for j in range(k)]
    return [f"{name}_{s}" for s in suffixes], flat


def _stated(
    method: str | None, frame: str | None, params: Mapping[str, Any] | None
) -> dict[str, str]:
    stated: dict[str, str] = {}
    if method:
        if any(c.isspace() for c in method) or "=" in method:
            raise ValueError(
                f"method name {method!r} has a space or '=': an estimate CSV states the "
                "method as one word (method=NAME); rename it"
            )
        stated["method"] = method
    if frame is not None:
        stated["frame"] = check_frame(frame)
    if params is not None:
        try:
            text = json.dumps(dict(params), default=_json_default, sort_keys=True)
        except TypeError as exc:
            raise ValueError(f"params cannot be written as JSON: {exc}") from None
        stated["params"] = text
    return stated


def estimate_csv_table(
    t: ArrayLike,
    quat: ArrayLike,
    outputs: Mapping[str, ArrayLike] | None = None,
    *,
    method: str | None = None,
    frame: str | None = None,
    params: Mapping[str, Any] | None = None,
) -> EstimateCsvTable:
    """The CSV columns of an estimate (see :func:`write_estimate_csv`), shapes and names checked."""
    t_arr = np.asarray(t, dtype=np.float64)
    q_arr = np.asarray(quat, dtype=np.float64)
    if t_arr.ndim != 1:
        raise ValueError(f"t must have shape (N,), got {t_arr.shape}")
    n = t_arr.shape[0]
    if q_arr.shape != (n, 4):
        raise ValueError(f"quat must have shape ({n}, 4) to match t, got {q_arr.shape}")
    names = ["t_s", "quat_w", "quat_x", "quat_y", "quat_z"]
    units = [output_unit("t_s")] + [output_unit("quat")] * 4
    blocks: list[NDArray[Any]] = [t_arr[:, None], q_arr]
    integer: list[bool] = [False] * 5
    for name, value in (outputs or {}).items():
        raw = np.asarray(value)
        arr = raw.astype(np.int64) if raw.dtype == bool else raw
        cols, flat = _output_columns(name, arr.astype(np.float64), n)
        names += cols
        units += [output_unit(name, raw.dtype)] * len(cols)
        integer += [np.issubdtype(arr.dtype, np.integer)] * len(cols)
        blocks.append(flat)
    duplicated = sorted({c for c in names if names.count(c) > 1})
    if duplicated:
        raise ValueError(f"output columns {duplicated} clash; rename the outputs")
    return EstimateCsvTable(names, integer, blocks, units, _stated(method, frame, params))
