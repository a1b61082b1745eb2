"""The ``evaluate`` and ``tune`` commands: error against ground truth, parameter search."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

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

if TYPE_CHECKING:
    from margtrack.bench.cv import CVResult


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
        with _trials_folder(path, "evaluate"):
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
        list[str] | None,
        typer.Option(
            "--grid", "-g",
            help="Candidates as name=v1,v2,...; repeatable (default: the method's declared "
            "grid, margtrack.bench.grids).",
        ),
    ] = None,
    param: ParamOption = None,
    cv: Annotated[
        bool,
        typer.Option(
            "--cv/--no-cv",
            help="Cross-validate by trial: score each trial with the point best on the others.",
        ),
    ] = False,
    folds: Annotated[
        int | None,
        typer.Option(help="With --cv: K folds by trial (trial i in fold i mod K) instead of "
                     "leave-one-trial-out."),
    ] = None,
    top: Annotated[int, typer.Option(help="How many of the best points to show.")] = 5,
    json_out: Annotated[
        Path | None,
        typer.Option("--json", help="Best result (with --cv: the cross-validation) as JSON."),
    ] = None,
    force: Annotated[
        bool, typer.Option("--force", help="Replace an existing --json file.")
    ] = False,
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    mag_unit: MagUnitOption = None,
    time_unit: TimeUnitOption = None,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Find one parameter set for all trials that minimises the mean total RMSE.

    The grid points run on Dask like `margtrack batch`: an embedded local cluster (one
    worker per CPU; --workers 1: in this process) or --scheduler tcp://HOST:PORT. With
    --cv every point runs once on every trial; each trial is then scored with the point
    best on the other trials (leave-one-trial-out, or --folds K), and that cross-validated
    mean is printed next to the in-sample best and the defaults.
    """
    from rich.progress import Progress

    from margtrack import io, methods
    from margtrack.batch.cluster import mapper_of, open_pool
    from margtrack.bench import broad, grids
    from margtrack.bench import cv as crossval
    from margtrack.bench import tune as tuning

    if folds is not None and not cv:
        raise ValueError("--folds is a cross-validation option: add --cv")
    name = methods.get(method).name
    candidates = tuning.parse_grid(grid) if grid else grids.declared_grid(name)
    fixed = dict(methods.parse_params_items(param or ()))
    # a bad grid fails before anything is read; with --cv the defaults may be one more run
    _, points = tuning.grid_points(methods.get(method), candidates, fixed)
    n_points = len(points)
    extra = int(cv and methods.parse_params(methods.get(method).params_type, fixed) not in points)
    if json_out is not None:
        from margtrack.io.safe_output import check_output

        check_output(json_out, [path], force=force)
    unit_kw = units(gyr_unit, acc_unit, mag_unit, time_unit)
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
            with _trials_folder(path, "tune"):
                recordings = [(r, ()) for r in read_checked(path, unit_kw)]
            order = ()
        bar.remove_task(loading)
        if cv:
            crossval.fold_of_trials(len(recordings), folds)  # before any run
        task = bar.add_task(f"tuning {method}", total=n_points + extra)

        def progress(point: str) -> None:
            bar.update(task, description=f"{method}: {point}")
            bar.advance(task)

        # a single point is not worth starting workers for
        with open_pool(1 if n_points == 1 and scheduler is None else workers, scheduler) as pool:
            bar.update(task, description=f"tuning {method} on {pool.description}")
            mapper = None if pool.client is None else mapper_of(pool)
            if cv:
                cv_result = crossval.cross_validate(
                    method, candidates, recordings, folds=folds, fixed=fixed,
                    group_order=order, progress=progress, mapper=mapper,
                )
                ranked = sorted(
                    cv_result.grid.results, key=lambda r: r.mean()["total_rmse_deg"]
                )
                result = tuning.TuneResult(cv_result.method, tuple(ranked))
            else:
                result = tuning.tune(
                    method, candidates, recordings, fixed=fixed, group_order=order,
                    progress=progress, mapper=mapper,
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
    if not cv:
        console.print(broad.format_table(result.best))
        if json_out is not None:
            _write_json(json_out, result.best.to_json())
        return
    console.print(cv_table(cv_result))
    console.print(folds_table(cv_result))
    console.print(
        f"stability: {cv_result.n_distinct_choices} distinct choice(s) over "
        f"{cv_result.n_folds} folds; {cv_result.stability:.0%} chose the in-sample best"
    )
    if json_out is not None:
        _write_json(json_out, cv_result.to_json())


@contextlib.contextmanager
def _trials_folder(path: Path, command: str) -> Iterator[None]:
    """Within the block, a folder that holds no recording is refused with what the
    command's folder must hold."""
    from margtrack.errors import NoRecordingError

    try:
        yield
    except NoRecordingError:
        if not path.is_dir():
            raise
        raise NoRecordingError(
            f"{path} holds no trials: margtrack {command} FOLDER reads the .hdf5 recordings "
            "with truth (quat_true) in a folder, such as the BROAD trials or files margtrack "
            f"simulate wrote; margtrack {command} FILE reads one recording with truth"
        ) from None


def _write_json(path: Path, data: object) -> None:
    """Write ``data`` as JSON to ``path`` atomically (checked with check_output first)."""
    import json

    from margtrack.io.safe_output import atomic_output

    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n")
    console.print(f"wrote {path}")


def cv_table(result: CVResult) -> Table:
    """Defaults, in-sample best and cross-validated means (deg), overall and per group."""
    from margtrack.bench.runner import KEYS

    table = Table(
        title=f"{result.method}: in-sample vs cross-validated ({result.split_name()}), "
        "mean RMSE over movement samples (deg)"
    )
    rows = [("defaults", result.default), ("best point", result.best_in_sample),
            ("cross-validated", result.cross_validated)]
    groups = [g for g in result.cross_validated.groups() if g in ("undisturbed", "disturbed")]
    table.caption = (
        "defaults, best point: in-sample (chosen on these trials); cross-validated: each "
        "trial scored with the point best on the other folds; groups: total"
    )
    table.add_column("figure", no_wrap=True)
    for col in ("total", "heading", "inclination", *groups):
        table.add_column(col, justify="right")
    for label, scores in rows:
        if scores is None:
            continue
        m = scores.mean()
        table.add_row(
            label, *(f"{m[k]:.2f}" for k in KEYS),
            *(f"{scores.mean(g)['total_rmse_deg']:.2f}" for g in groups),
        )
    return table


def folds_table(result: CVResult) -> Table:
    """Per fold: held-out trials, the point chosen without them, train and held-out total."""
    table = Table(title=f"{result.method}: the point each fold chose without its trials")
    for col in ("held out", "chosen", "train total", "held-out total"):
        table.add_column(col, justify="right" if "total" in col else "left")
    for f in result.folds:
        table.add_row(
            ", ".join(f.held_out), f.label, f"{f.train_total_deg:.2f}",
            f"{f.held_out_total_deg:.2f}",
        )
    return table
