"""The ``evaluate`` and ``tune`` commands: error against ground truth, parameter search."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import click
import typer
from rich.table import Table

from margtrack.cli.app import PlainHelpCommand, app, console, friendly_errors
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
    from rich.console import Group

    from margtrack.bench.cv import CVResult
    from margtrack.io.broad import BroadTrial

#: the splits of --cv: leave-one-trial-out (the default) or leave-one-group-out
CV_SPLITS = ("trial", "group")


class CVCommand(PlainHelpCommand):
    """A command whose ``--cv`` flag may name its split: ``--cv group`` (or ``--cv=group``)
    is read as ``--cv --cv-by group``; ``--cv`` alone stays by trial, as before.

    Typer's options take a value always or never, so the optional value is read here,
    before click parses the line: only the words of :data:`CV_SPLITS` right after ``--cv``.
    """

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        out: list[str] = []
        i = 0
        while i < len(args):
            arg = args[i]
            if arg == "--":
                out += args[i:]
                break
            if arg.startswith("--cv="):
                out += ["--cv", "--cv-by", arg.partition("=")[2]]
            elif arg == "--cv" and i + 1 < len(args) and args[i + 1] in CV_SPLITS:
                out += ["--cv", "--cv-by", args[i + 1]]
                i += 1
            else:
                out.append(arg)
            i += 1
        return super().parse_args(ctx, out)


CVByOption = Annotated[
    str | None,
    typer.Option(
        "--cv-by",
        help="The split of --cv: trial (leave-one-trial-out) or group (hold out every trial "
        "of one kind at a time, from trials.json; also printed: leave-one-trial-out). "
        "`--cv group` is short for `--cv --cv-by group`.",
    ),
]


def cv_split(cv_by: str | None) -> str:
    """``trial`` or ``group`` from ``--cv-by`` (None: trial); anything else is refused."""
    if cv_by is None:
        return "trial"
    if cv_by not in CV_SPLITS:
        raise ValueError(f"--cv takes trial or group, got {cv_by!r}")
    return cv_by


def kinds_of(
    folder: Path, trials: Iterable[BroadTrial], recordings: Iterable[tuple[Recording, object]]
) -> dict[str, str]:
    """Recording name -> its trial's kind (margtrack.bench.broad.trial_kinds) for ``--cv group``;
    ``recordings`` are ``trials`` read, in the same order."""
    from margtrack.bench import broad

    by_trial = broad.trial_kinds(folder)
    return {rec.name: by_trial[t.name] for t, (rec, _) in zip(trials, recordings, strict=True)}


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


@app.command(cls=CVCommand)
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
            help="Cross-validate: score each trial with the point best on the other trials "
            "(--cv or --cv trial: leave-one-trial-out; --cv group: leave-one-group-out).",
        ),
    ] = False,
    cv_by: CVByOption = None,
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
    mean is printed next to the in-sample best and the defaults. With --cv group each kind
    of trial (trials.json: its disturbance, else its speed and motion) is held out in turn
    and scored with the point best on the other kinds, per kind and overall, beside
    leave-one-trial-out.
    """
    from rich.progress import Progress

    from margtrack import io, methods
    from margtrack.batch.cluster import mapper_of, open_pool
    from margtrack.bench import broad, grids
    from margtrack.bench import cv as crossval
    from margtrack.bench import tune as tuning

    split = cv_split(cv_by)
    cv = cv or cv_by is not None
    if folds is not None and not cv:
        raise ValueError("--folds is a cross-validation option: add --cv")
    if folds is not None and split == "group":
        raise ValueError("--folds splits by trial; leave it out with --cv group")
    if split == "group" and not (path / "trials.json").is_file():
        raise ValueError(
            f"--cv group needs a folder of trials with trials.json (their groups); {path} "
            "has none: use --cv trial"
        )
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
            kinds = kinds_of(path, trials, recordings) if split == "group" else None
        else:
            kinds = None
            with _trials_folder(path, "tune"):
                recordings = [(r, ()) for r in read_checked(path, unit_kw)]
            order = ()
        bar.remove_task(loading)
        if cv:
            crossval.fold_of_trials(len(recordings), folds)  # before any run
            if kinds is not None:
                crossval.fold_of_kinds(list(kinds.values()))
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
                    method, candidates, recordings, folds=folds, kinds=kinds, fixed=fixed,
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
    # by group, leave-one-trial-out beside it: the same grid, another split, no run
    loto = crossval.cross_validate_grid(cv_result.grid) if cv_result.by_kind else None
    console.print(cv_table(cv_result, loto))
    console.print(group_folds_table(cv_result, loto) if loto else folds_table(cv_result))
    console.print(
        f"stability: {cv_result.n_distinct_choices} distinct choice(s) over "
        f"{cv_result.n_folds} folds; {cv_result.stability:.0%} chose the in-sample best"
    )
    if json_out is not None:
        data = cv_result.to_json()
        if loto is not None:
            data["leave_one_trial_out"] = loto.to_json()["cross_validated"]
        _write_json(json_out, data)


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


def cv_table(result: CVResult, loto: CVResult | None = None) -> Table:
    """Defaults, in-sample best and cross-validated means (deg), overall and per group;
    ``loto``: the same grid's leave-one-trial-out figure, one more row."""
    from margtrack.bench.runner import KEYS

    table = Table(
        title=f"{result.method}: in-sample vs cross-validated ({result.split_name()}), "
        "mean RMSE over movement samples (deg)"
    )
    rows = [("defaults", result.default), ("best point", result.best_in_sample),
            *([("leave-one-trial-out", loto.cross_validated)] if loto is not None else []),
            ("leave-one-group-out" if result.by_kind else "cross-validated",
             result.cross_validated)]
    groups = [g for g in result.cross_validated.groups() if g in ("undisturbed", "disturbed")]
    table.caption = (
        "defaults, best point: in-sample (chosen on these trials); "
        + ("leave-one-trial-out: each trial scored with the point best on the other trials; "
           "leave-one-group-out: with the point best on the trials of other kinds"
           if result.by_kind else
           "cross-validated: each trial scored with the point best on the other folds")
        + "; groups: total"
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


def group_folds_table(result: CVResult, loto: CVResult) -> Group:
    """Leave-one-group-out, per held-out kind: its figures (deg) with the point chosen
    without it, the same trials' leave-one-trial-out and in-sample best totals; then the
    point each kind's fold chose, one line each."""
    from rich.console import Group

    loto_total = {t.name: t.total_rmse_deg for t in loto.cross_validated.trials}
    best_total = {t.name: t.total_rmse_deg for t in result.best_in_sample.trials}
    table = Table(title=f"{result.method}: each kind of trial scored with the point chosen "
                  "without it (deg)")
    table.add_column("held out (trials)", no_wrap=True)
    for col in ("train", "total", "heading", "incl.", "LOTO", "best"):
        table.add_column(col, justify="right", no_wrap=True)
    for f in result.folds:
        total, heading, inclination = f.held_out_figures
        table.add_row(
            f"{f.kind} ({len(f.held_out)})", f"{f.train_total_deg:.2f}",
            f"{total:.2f}", f"{heading:.2f}", f"{inclination:.2f}",
            f"{sum(loto_total[n] for n in f.held_out) / len(f.held_out):.2f}",
            f"{sum(best_total[n] for n in f.held_out) / len(f.held_out):.2f}",
        )
    table.caption = (
        "train: the chosen point's mean total on the other groups; total, heading, incl.: "
        "its mean on the held-out group's trials; LOTO: their total when each is scored "
        "with the point best on the other trials (its own group's included); best: their "
        "total with the point best on all trials (in-sample)"
    )
    return Group(table, *(f"without {f.kind}: chose {f.label}" for f in result.folds))
