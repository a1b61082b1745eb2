"""The ``methods`` and ``info`` commands: what margtrack offers, what a file holds."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from margtrack.cli.app import app, cli_message, console, err_console, friendly_errors
from margtrack.cli.options import (
    AccUnitOption,
    ColumnOption,
    GyrUnitOption,
    MagUnitOption,
    ProfileOption,
    TimeUnitOption,
    check_units,
    read_options,
    reader_warnings,
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
            doc = description(cls, first_line=True)
            star = " [green](default)[/]" if method == registry.DEFAULT_METHOD else ""
            table.add_row(method + star, doc)
        _print_whole(table)
        console.print(PAPERS_NOTE, soft_wrap=True)
        return
    cls = registry.get(name)
    shared = {spec.name for spec in specs(Params)}
    own = [s for s in specs(cls.params_type) if s.name not in shared]
    base = [s for s in specs(cls.params_type) if s.name in shared]
    console.print(f"{cls.name}: {escape(description(cls))}", soft_wrap=True)
    for title, rows in ((f"{cls.name}'s own parameters", own),
                        ("input policy and frame (every method)", base)):
        if not rows:
            console.print(f"{title}\n  (no parameters of its own)")
            continue
        table = Table(title=title, title_justify="left")
        table.add_column("parameter", no_wrap=True)
        table.add_column("default", overflow="fold")  # whole, folded if it must be
        table.add_column("unit", no_wrap=True)
        table.add_column("range", overflow="fold")
        table.add_column("what", overflow="fold")
        for spec in rows:
            table.add_row(spec.name, repr(spec.default), spec.unit, spec.bounds_text(), spec.help)
        _print_whole(table)
    console.print(f"set one with -p NAME=VALUE (e.g. margtrack run REC -o OUT -m {cls.name} "
                  f"-p {(own or base)[0].name}=...). {PAPERS_NOTE}", soft_wrap=True)


def _paragraph(doc: str | None, first_line: bool) -> str:
    """The first paragraph (or line) of a docstring on one line, without reST markup."""
    first = (doc or "").strip().split("\n\n")[0]
    lines = first.splitlines()[:1] if first_line else first.splitlines()
    text = " ".join(line.strip() for line in lines)
    return re.sub(r":\w+:`~?([^`]+)`", r"\1", text).replace("``", "")


def description(cls: type, first_line: bool = False) -> str:
    """What a method is, in one paragraph (or its first line): its class docstring's, or
    its module's where the class defers to that ("see the module docstring")."""
    import sys

    text = _paragraph(cls.__doc__, first_line)
    if "module docstring" in text:
        text = _paragraph(sys.modules[cls.__module__].__doc__, first_line)
    return text


#: where the paper numbers of the help texts ("000 eq. 5") are resolved
PAPERS_NOTE = "Papers 000-004 cited above: docs/papers.md."


def _print_whole(table: Table) -> None:
    """Print ``table`` with every cell whole: a pipe or a file gets the table's full width.

    On a terminal rich fits the table to the window, folding long cells onto more lines
    (never cutting them); elsewhere rich would assume 80 columns, so the table is printed
    as wide as its longest rows need.
    """
    if console.is_terminal:
        console.print(table)
        return
    from rich.console import Console
    from rich.measure import Measurement

    width = Measurement.get(console, console.options.update(width=10_000), table).maximum
    Console(width=max(width, console.width), file=console.file, color_system=None,
            highlight=False).print(table)


@app.command()
@friendly_errors
def info(
    path: Annotated[Path, typer.Argument(help="Recording file or folder.")],
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    mag_unit: MagUnitOption = None,
    time_unit: TimeUnitOption = None,
    column: ColumnOption = None,
    profile: ProfileOption = None,
) -> None:
    """Say what a recording or an estimate holds: samples, rate, units, frame, gaps, flags."""
    from margtrack import io
    from margtrack.io.estimate_reader import is_estimate_file

    if is_estimate_file(path):
        _estimate_info(path)
        return
    with reader_warnings():
        recordings = io.read_any(
            path, **read_options(gyr_unit, acc_unit, mag_unit, time_unit, column, profile)
        )
    for rec in recordings:
        time_note = ""
        try:
            check_units(rec, path if len(recordings) == 1 else f"{path} [{rec.name}]")
        except UnitError as exc:  # info describes the file anyway; run and evaluate refuse it
            err_console.print(f"[yellow]warning:[/] {escape(cli_message(exc))}", soft_wrap=True)
            if exc.signal == "time":
                time_note = f"; timestamps probably in {exc.suspected}: --time-unit {exc.suspected}"
        table = Table(title=escape(f"{rec.name or path.name}"), show_header=False)
        table.add_column("field")
        table.add_column("value")
        gaps = rec.gaps()
        table.add_row("samples", f"{rec.n_samples}")
        table.add_row("rate", f"{rec.rate_hz:.3f} Hz (median interval{time_note})")
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
            holes = int(rec.quat_true.shape[0] - np.count_nonzero(rec.truth_valid))
            if holes:
                truth += f", {holes} samples without truth (NaN, skipped by the metrics)"
            if rec.movement is not None:
                truth += f", movement {100 * np.mean(rec.movement):.1f} % of samples"
        table.add_row("truth", truth)
        for key, value in rec.meta.items():
            if key != "info":  # values hold file names and units: "[deg/s]" is not markup
                table.add_row(escape(key), escape(str(value)))
        console.print(table)


def _estimate_info(path: Path) -> None:
    """The ``info`` table of an estimate file (what ``margtrack run`` wrote)."""
    from margtrack.estimator.flags import count_flags, summary
    from margtrack.io.estimate_reader import read_estimate

    est = read_estimate(path)
    table = Table(title=f"{path.name}: orientation estimate", show_header=False)
    table.add_column("field")
    table.add_column("value", overflow="fold")
    dt = np.diff(est.t)
    table.add_row("method", est.method or "not stated")
    table.add_row(
        "frame",
        escape(f"quat [w, x, y, z], body to {est.frame} (earth)") if est.frame else
        "not stated in the file (a CSV without a 'frame=' line): give `margtrack plot` "
        "--frame ENU or NED",
    )
    table.add_row("samples", f"{est.n_samples}")
    if dt.size:
        table.add_row("rate", f"{1.0 / np.median(dt):.3f} Hz (median interval)")
    table.add_row("duration", f"{est.t[-1] - est.t[0]:.3f} s (t {est.t[0]:.3f}..{est.t[-1]:.3f})")
    if est.flags is None:
        table.add_row("flags", "none stored")
    else:
        table.add_row("flags", summary(est.flags))
        counts = count_flags(est.flags)
        for name, n in counts.items():
            table.add_row(f"  {name}", f"{n} samples ({100.0 * n / est.n_samples:.2f} %)")
    bias = est.outputs.get("gyr_bias_rad_s")
    if bias is not None:
        deg = np.degrees(np.asarray(bias, dtype=np.float64))
        table.add_row(
            "gyr bias (deg/s)",
            "; ".join(f"{axis} {deg[:, k].min():+.4f}..{deg[:, k].max():+.4f} "
                      f"(last {deg[-1, k]:+.4f})" for k, axis in enumerate("xyz")),
        )
    others = [f"{name} {tuple(np.shape(value))}" for name, value in est.outputs.items()
              if name != "gyr_bias_rad_s"]
    if others:
        table.add_row("other outputs", ", ".join(others))
    if est.params:
        table.add_row("parameters", ", ".join(f"{k}={v!r}" for k, v in sorted(est.params.items())))
    _print_whole(table)
