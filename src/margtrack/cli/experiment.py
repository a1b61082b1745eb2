"""The ``experiment`` command: the source papers' experiments."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from margtrack.cli.app import app, console, friendly_errors


@app.command()
@friendly_errors
def experiment(
    name: Annotated[str, typer.Argument(help="Experiment name; `list` shows them.")],
    out_dir: Annotated[Path, typer.Option("--out", help="Folder for the PNG plots.")] = Path(
        "experiments"
    ),
    quick: Annotated[bool, typer.Option(help="A shorter run (fewer samples or cases).")] = False,
) -> None:
    """Reproduce an experiment of the source papers: print its figures, write its plot."""
    from margtrack.bench import experiments

    if name == "list":
        for item in experiments.available():
            console.print(item)
        return
    result = experiments.run(name, out_dir, quick=quick)
    table = Table(title=f"experiment {result.name}")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for key, value in result.figures.items():
        table.add_row(key, f"{value:.6g}" if isinstance(value, float) else str(value))
    console.print(table)
    for note in result.notes:
        console.print(note)
    for plot in result.plots:
        console.print(f"plot: {plot}")
