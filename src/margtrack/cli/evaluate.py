"""The ``evaluate`` and ``tune`` commands: error against ground truth, parameter search."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from margtrack.cli.app import app, console, friendly_errors
from margtrack.cli.batch import SchedulerOption, WorkersOption
from margtrack.cli.options import (
    AccUnitOption,
    ColumnOption,
    GyrUnitOption,
    MagUnitOption,
    MethodOption,
    ParamOption,
    ProfileOption,
    TimeUnitOption,
    check_units,
    read_checked,
    read_options,
    units,
)
from margtrack.recording import Recording


@app.command()
@friendly_errors
def evaluate(
    path: Annotated[Path, typer.Argument(help="A folder of BROAD trials, or one recording.")],
    method: MethodOption = "default",
    param: ParamOption = None,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write the results as JSON.")
    ] = None,
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    mag_unit: MagUnitOption = None,
    time_unit: TimeUnitOption = None,
    column: ColumnOption = None,
    profile: ProfileOption = None,
) -> None:
    """Error table (RMSE in degrees) of a method against ground truth."""
    from rich.progress import Progress

    from margtrack import io, methods
    from margtrack.bench import broad
    from margtrack.bench.runner import evaluate_all

    estimator = methods.create(method, param or ())
    cls = type(estimator)

    unit_kw = units(gyr_unit, acc_unit, mag_unit, time_unit)
    if path.is_dir() and any(path.glob("*.hdf5")):
        trials = io.broad_trials(path)
        order = broad.group_order(path)
        # one trial in memory at a time, read with the declared units and checked
        recs: Iterable[tuple[Recording, tuple[str, ...]]] = (
            (check_units(io.read(t.path, **unit_kw), t.path), tuple(t.groups)) for t in trials
        )
    else:
        trials, order = [], ()
        recs = [(r, ()) for r in read_checked(
            path, read_options(gyr_unit, acc_unit, mag_unit, time_unit, column, profile)
        )]
    with Progress(transient=True, disable=not trials) as bar:
        task = bar.add_task(f"{cls.name} on {len(trials)} trials", total=len(trials))

        def progress(name: str) -> None:
            bar.update(task, description=f"{cls.name}: {name}")
            bar.advance(task)

        result = evaluate_all(estimator, recs, group_order=order, progress=progress)
    console.print(broad.format_table(result))
    console.print(
        f"speed: {result.samples_per_s:,.0f} samples/s (including compilation on first use)"
    )
    if json_out is not None:
        result.write_json(json_out)
        console.print(f"wrote {json_out}")


@app.command()
@friendly_errors
def tune(
    path: Annotated[Path, typer.Argument(help="A folder of BROAD trials (or one recording).")],
    method: MethodOption,
    grid: Annotated[
        list[str],
        typer.Option("--grid", "-g", help="Candidates as name=v1,v2,...; repeatable."),
    ],
    param: ParamOption = None,
    top: Annotated[int, typer.Option(help="How many of the best points to show.")] = 5,
    json_out: Annotated[Path | None, typer.Option("--json", help="Best result as JSON.")] = None,
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    mag_unit: MagUnitOption = None,
    time_unit: TimeUnitOption = None,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Find one parameter set for all trials that minimises the mean total RMSE.

    The grid points run on Dask like `margtrack batch`: an embedded local cluster (one
    worker per CPU; --workers 1: in this process) or --scheduler tcp://HOST:PORT.
    """
    import itertools

    from rich.progress import Progress

    from margtrack import io, methods
    from margtrack.batch.cluster import mapper_of, open_pool
    from margtrack.bench import broad
    from margtrack.bench import tune as tuning

    unit_kw = units(gyr_unit, acc_unit, mag_unit, time_unit)
    candidates = tuning.parse_grid(grid)
    fixed = dict(methods.parse_params_items(param or ()))
    n_points = len(list(itertools.product(*candidates.values())))
    with Progress(transient=True) as bar:
        loading = bar.add_task("reading recordings", total=None)
        if path.is_dir() and any(path.glob("*.hdf5")):
            trials = io.broad_trials(path)
            recordings = [
                (check_units(io.read(t.path, **unit_kw), t.path), tuple(t.groups))
                for t in trials
            ]
            order = broad.group_order(path)
        else:
            recordings = [(r, ()) for r in read_checked(path, unit_kw)]
            order = ()
        bar.remove_task(loading)
        task = bar.add_task(f"tuning {method}", total=n_points)

        def progress(point: str) -> None:
            bar.update(task, description=f"{method}: {point}")
            bar.advance(task)

        # a single point is not worth starting workers for
        with open_pool(1 if n_points == 1 and scheduler is None else workers, scheduler) as pool:
            bar.update(task, description=f"tuning {method} on {pool.description}")
            result = tuning.tune(
                method, candidates, recordings, fixed=fixed, group_order=order,
                progress=progress, mapper=None if pool.client is None else mapper_of(pool),
            )
    table = Table(title=f"{result.method}: best {min(top, len(result.results))} of {n_points}")
    table.add_column("parameters")
    for col in ("total", "heading", "inclination"):
        table.add_column(col, justify="right")
    for r in result.results[:top]:
        m = r.mean()
        shown = ", ".join(f"{k}={r.params[k]}" for k in candidates)
        table.add_row(
            shown,
            f"{m['total_rmse_deg']:.2f}",
            f"{m['heading_rmse_deg']:.2f}",
            f"{m['inclination_rmse_deg']:.2f}",
        )
    console.print(table)
    console.print(broad.format_table(result.best))
    if json_out is not None:
        result.best.write_json(json_out)
        console.print(f"wrote {json_out}")
