"""The batch summary: ``summary.csv`` and ``summary.parquet``, one row per input.

Columns (:data:`COLUMNS`): ``file`` (the input), ``status`` (``done``, ``skipped``,
``failed``), ``output``, ``samples``, ``duration_s``, ``rate_hz``, ``method``, ``gaps``
(gap starts), ``fault_samples`` (samples with a fault flag: 0 for clean data),
``rest_samples`` and ``initialising_samples`` (samples in those normal states, not faults),
``mag_ignored_pct`` (% of samples whose magnetometer was not used), ``total_rmse_deg`` /
``heading_rmse_deg`` / ``inclination_rmse_deg`` (against the recording's truth; empty
without one), ``seconds`` (processing time) and ``error`` (why a ``failed`` input failed).
A ``skipped`` row carries the figures of the run that made its output. Both files are
written atomically; Parquet needs pyarrow (``pip install margtrack[parquet]``), without it
only the CSV is written and the caller is told why.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from margtrack.io.safe_output import atomic_output

__all__ = ["COLUMNS", "FIGURES", "read_summary_csv", "write_summary"]

#: the figures of a processed recording (as ``FileSummary.as_row()`` names them)
FIGURES = (
    "samples",
    "duration_s",
    "rate_hz",
    "method",
    "gaps",
    "fault_samples",
    "rest_samples",
    "initialising_samples",
    "mag_ignored_pct",
    "total_rmse_deg",
    "heading_rmse_deg",
    "inclination_rmse_deg",
    "seconds",
)
COLUMNS = ("file", "status", "output", *FIGURES, "error")
_INTS = ("samples", "gaps", "fault_samples", "rest_samples", "initialising_samples")
_STRS = ("file", "status", "output", "method", "error")
PARQUET_HINT = "pip install margtrack[parquet] (or pip install pyarrow)"


def _cell(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, float):
        return repr(value)  # every digit: the CSV reads back to the same float
    return str(value)


def write_summary(rows: Sequence[dict[str, Any]], outdir: Path) -> tuple[Path, Path | None, str]:
    """Write ``summary.csv`` (and ``summary.parquet``) in ``outdir``; replace earlier ones.

    Returns the CSV path, the Parquet path (None when pyarrow is missing) and a note for
    people (empty, or how to get the Parquet file).
    """
    csv_path = outdir / "summary.csv"
    with atomic_output(csv_path) as tmp, tmp.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        for row in rows:
            writer.writerow([_cell(row.get(c)) for c in COLUMNS])
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return csv_path, None, f"summary.parquet not written: pyarrow is missing; {PARQUET_HINT}"
    types = {c: pa.int64() if c in _INTS else pa.string() if c in _STRS else pa.float64()
             for c in COLUMNS}
    table = pa.table(
        {c: pa.array([row.get(c) for row in rows], type=types[c]) for c in COLUMNS}
    )
    parquet_path = outdir / "summary.parquet"
    with atomic_output(parquet_path) as tmp:
        pq.write_table(table, tmp)
    return csv_path, parquet_path, ""


def read_summary_csv(path: str | Path) -> list[dict[str, Any]]:
    """The rows of a ``summary.csv``, typed back (ints, floats, None for empty cells)."""
    out = []
    with Path(path).open(newline="") as f:
        for raw in csv.DictReader(f):
            row: dict[str, Any] = {}
            for c in COLUMNS:
                v = raw.get(c, "")
                if v == "":
                    row[c] = None
                elif c in _INTS:
                    row[c] = int(v)
                elif c in _STRS:
                    row[c] = v
                else:
                    row[c] = float(v)
            out.append(row)
    return out
