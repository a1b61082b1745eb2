"""The ``methods`` and ``info`` commands: what margtrack offers, what a file holds."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from margtrack.cli.app import app, console, err_console, friendly_errors
from margtrack.cli.options import (
    AccUnitOption,
    GyrUnitOption,
    MagUnitOption,
    TimeUnitOption,
    check_units,
    units,
)
from margtrack.units import UnitError


@app.command()
@friendly_errors
def methods(
    name: Annotated[
        str | None, typer.Argument(help="A method: list its parameters (unit, range, help).")
    ] = None,
) -> None:
    """List the estimation methods, or one method's parameters with unit, range and help."""
    from margtrack import methods as registry
    from margtrack.estimator.params import Params, specs

    if name is None:
        table = Table(title="margtrack methods (margtrack methods NAME lists its parameters)")
        table.add_column("name", no_wrap=True)
        table.add_column("what")
        for method in registry.available():
            cls = registry.get(method)
            doc = (cls.__doc__ or "").strip().splitlines()[0].replace("``", "")
            star = " [green](default)[/]" if method == registry.DEFAULT_METHOD else ""
            table.add_row(method + star, doc)
        console.print(table)
        return
    cls = registry.get(name)
    shared = {spec.name for spec in specs(Params)}
    own = [s for s in specs(cls.params_type) if s.name not in shared]
    base = [s for s in specs(cls.params_type) if s.name in shared]
    what = (cls.__doc__ or "").strip().splitlines()[0].replace("``", "")
    for title, rows in ((f"{cls.name}: {what}", own),
                        ("input policy and frame (every method)", base)):
        if not rows:
            console.print(f"{title}\n  (no parameters of its own)")
            continue
        table = Table(title=title, title_justify="left")
        table.add_column("parameter", no_wrap=True)
        table.add_column("default", no_wrap=True)
        table.add_column("unit", no_wrap=True)
        table.add_column("range")
        table.add_column("what")
        for spec in rows:
            table.add_row(spec.name, repr(spec.default), spec.unit, spec.bounds_text(), spec.help)
        console.print(table)


@app.command()
@friendly_errors
def info(
    path: Annotated[Path, typer.Argument(help="Recording file or folder.")],
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    mag_unit: MagUnitOption = None,
    time_unit: TimeUnitOption = None,
) -> None:
    """Say what a recording holds: samples, rate, duration, units, frame, gaps, truth."""
    from margtrack import io

    recordings = io.read_any(path, **units(gyr_unit, acc_unit, mag_unit, time_unit))
    for rec in recordings:
        try:
            check_units(rec, path if len(recordings) == 1 else f"{path} [{rec.name}]")
        except UnitError as exc:  # info describes the file anyway; run and evaluate refuse it
            err_console.print(f"[yellow]warning:[/] {escape(str(exc))}", soft_wrap=True)
        table = Table(title=f"{rec.name or path.name}", show_header=False)
        table.add_column("field")
        table.add_column("value")
        gaps = rec.gaps()
        table.add_row("samples", f"{rec.n_samples}")
        table.add_row("rate", f"{rec.rate_hz:.3f} Hz (median interval)")
        table.add_row("duration", f"{rec.duration_s:.3f} s")
        table.add_row("signals", "gyr rad/s, acc m/s²" + (", mag" if rec.mag is not None else ""))
        if rec.mag is not None:
            norm = np.linalg.norm(rec.mag, axis=1)
            table.add_row(
                "mag norm",
                f"median {np.median(norm):.2f}, range {norm.min():.2f}..{norm.max():.2f}",
            )
        acc_norm = np.median(np.linalg.norm(rec.acc, axis=1))
        table.add_row("acc norm", f"median {acc_norm:.3f} m/s²")
        table.add_row(
            "gaps", f"{gaps.size}" + (f" (first at sample {gaps[0]})" if gaps.size else "")
        )
        clipped = rec.saturation()
        table.add_row(
            "saturation",
            "; ".join(
                f"{k} at ±{v.level:.4g} from sample {v.first_sample} ({v.n_samples} samples)"
                for k, v in clipped.items()
            )
            or "none",
        )
        truth = "none"
        if rec.quat_true is not None:
            truth = f"quat_true in {rec.frame}"
            if rec.movement is not None:
                truth += f", movement {100 * np.mean(rec.movement):.1f} % of samples"
        table.add_row("truth", truth)
        for key, value in rec.meta.items():
            if key != "info":
                table.add_row(key, str(value))
        console.print(table)
