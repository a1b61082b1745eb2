"""Shared pieces of the ``margtrack calibrate`` commands: error handling, reading, tables.

Used by :mod:`margtrack.cli.calibrate` (the command app) and
:mod:`margtrack.cli.calibrate_guided` (the guided procedure, offline and live).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

if TYPE_CHECKING:  # pragma: no cover
    from margtrack.recording import Recording

__all__ = ["OutputOption", "fmt", "friendly", "make_table", "read", "triad_rows", "update"]

F = TypeVar("F", bound=Callable[..., Any])
OutputOption = Annotated[
    Path | None,
    typer.Option("--output", "-o", help="Calibration JSON to write (kept parts are updated)."),
]


def friendly(func: F) -> F:
    """Bad input becomes a one-line message and exit code 2 instead of a traceback."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (ValueError, FileNotFoundError, OSError) as exc:
            from margtrack.cli.app import cli_message  # the command line's fix, not Python's

            Console(stderr=True).print(f"[bold red]error:[/] {escape(cli_message(exc))}",
                                       soft_wrap=True)
            raise typer.Exit(code=2) from None

    return wrapper  # type: ignore[return-value]


def read(path: Path) -> Recording:
    """The recording at ``path`` (any format :func:`margtrack.io.read` knows)."""
    from margtrack import io

    return io.read(path)


def update(output: Path | None, console: Console, **parts: Any) -> None:
    """Write ``parts`` into the calibration JSON ``output``, keeping its other parts."""
    from margtrack.calibration.calibration_file import (
        Calibration,
        load_calibration,
        save_calibration,
    )

    if output is None:
        return
    existed = output.is_file()
    base = load_calibration(output) if existed else Calibration()
    calibration = dataclasses.replace(base, **parts)
    save_calibration(calibration, output)
    console.print(f"{'updated' if existed else 'wrote'} {output}")


def make_table(title: str, columns: list[str]) -> Table:
    """A table with a left-aligned first column and right-aligned figures."""
    table = Table(title=title)
    for k, col in enumerate(columns):
        table.add_column(col, justify="left" if k == 0 else "right")
    return table


def fmt(values: Any, digits: int = 5) -> list[str]:
    """Each value with ``digits`` significant digits."""
    return [f"{v:.{digits}g}" for v in np.asarray(values, dtype=float).ravel()]


def triad_rows(table: Table, label: str, triad: Any, unit: str, factor: float = 1.0) -> None:
    """Rows of a triad's bias (times ``factor``, in ``unit``), scale, misalignment, rotation."""
    scale, mis, rot = triad.decompose()
    table.add_row(f"{label} bias ({unit})", *fmt(triad.b * factor))
    table.add_row(f"{label} scale error (%)", *fmt(100.0 * scale, 4))
    table.add_row(f"{label} misalignment αx αy αz (deg)", *fmt(mis, 4))
    table.add_row(f"{label} triad rotation (deg)", f"{rot:.4f}", "", "")
