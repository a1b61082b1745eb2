"""The ``bench`` commands: margtrack against other libraries on real data."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from margtrack.cli.app import app, console, friendly_errors, warn

#: the peer libraries `bench broad` compares with: name -> the package that provides it
PEER_PACKAGES = {"vqf": "vqf", "imufusion": "imufusion", "madgwick": "ahrs"}


def _peer_installed(name: str) -> bool:
    """True if the peer library ``name`` imports (unknown names: True, refused later)."""
    import importlib

    if name not in PEER_PACKAGES:
        return True
    try:
        importlib.import_module(PEER_PACKAGES[name])
    except ImportError:
        return False
    return True


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
    from margtrack.bench.runner import Method

    names = method or [m for m in methods.available() if methods.get(m).uses_gyr]
    runs: list[tuple[str, Method]] = []
    for name in names:
        runs.append((name, methods.get(name)(frame="ENU")))
    for name in [e.strip() for e in external.split(",") if e.strip()]:
        if not _peer_installed(name):  # margtrack's own rows run without the peer libraries
            package = PEER_PACKAGES[name]
            warn(f"{name} is not installed, its row is left out; add it with "
                 f"`pip install {package}` (every peer: `pip install 'margtrack[dev]'`)")
            continue
        if name == "madgwick":
            adapter = ext.madgwick(madgwick_beta)
            runs.append((adapter.name, adapter))
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
            run_one.run(recordings[0][0].slice(0, 50))
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
