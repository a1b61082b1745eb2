"""The ``bench`` commands: margtrack against other libraries on real data."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from margtrack.cli.app import app, console, friendly_errors

bench_app = typer.Typer(
    help="Benchmarks on real data, against other libraries.", no_args_is_help=True
)
app.add_typer(bench_app, name="bench")


@bench_app.command("broad")
@friendly_errors
def bench_broad(
    folder: Annotated[Path, typer.Argument(help="Folder of BROAD trials.")] = Path(
        "../shared/data/broad"
    ),
    method: Annotated[
        list[str] | None,
        typer.Option("--method", "-m", help="margtrack methods (default: every filter)."),
    ] = None,
    external: Annotated[
        str, typer.Option(help="Other libraries, comma-separated: vqf, imufusion, madgwick.")
    ] = "vqf,imufusion",
    madgwick_beta: Annotated[
        float,
        typer.Option(help="Gain of ahrs' Madgwick (best single beta on BROAD; pure Python, slow)."),
    ] = 0.08,
    out: Annotated[Path, typer.Option(help="PNG bar plot.")] = Path("broad_comparison.png"),
) -> None:
    """Compare margtrack's methods with other libraries on BROAD: table, bar plot, speed."""
    from rich.progress import Progress

    from margtrack import io, methods
    from margtrack.bench import compare as cmp
    from margtrack.bench import external as ext

    names = method or [m for m in methods.available() if methods.get(m).uses_gyr]
    runs: list[tuple[str, Callable]] = []
    for name in names:
        cls = methods.get(name)
        runs.append((name, lambda rec, cls=cls: cls(frame="ENU").run(rec).quat))
    for name in [e.strip() for e in external.split(",") if e.strip()]:
        if name == "madgwick":
            runs.append((f"ahrs madgwick (beta {madgwick_beta:g})", ext.madgwick(madgwick_beta)))
        elif name in ext.EXTERNAL:
            runs.append((name, ext.EXTERNAL[name]))
        else:
            raise ValueError(f"unknown external library {name!r}; known: vqf, imufusion, madgwick")
    trials = io.broad_trials(folder)
    with Progress(transient=True) as bar:
        task = bar.add_task("reading", total=len(trials) * (1 + len(runs)))
        recordings = []
        for t in trials:
            recordings.append((io.read_broad(t.path), tuple(t.groups)))
            bar.advance(task)

        def progress(text: str) -> None:
            bar.update(task, description=text)
            bar.advance(task)

        # compile every numba kernel before timing: run each method once on a short slice
        for _, run_one in runs:
            run_one(recordings[0][0].slice(0, 50))
        result = cmp.compare(recordings, runs, progress=progress)
    for group in (None, "undisturbed", "disturbed"):
        title = f"BROAD {group or 'all trials'}: mean RMSE over movement samples (deg)"
        table = Table(title=title)
        for col in ("method", "total", "heading", "inclination", "samples/s"):
            table.add_column(col, justify="left" if col == "method" else "right")
        for row in result.table_rows([group]):
            table.add_row(*row)
        console.print(table)
    plot = cmp.plot_comparison(result, out, ["all", "undisturbed", "disturbed"])
    console.print(f"plot: {plot}")
