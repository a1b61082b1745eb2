"""The ``batch`` command: many recordings, one estimate file each and a summary, on Dask."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from margtrack.cli.app import app, console, err_console, friendly_errors, warn
from margtrack.cli.options import (
    AccUnitOption,
    ColumnOption,
    GyrUnitOption,
    MagUnitOption,
    MethodOption,
    ParamOption,
    ProfileOption,
    TimeUnitOption,
    read_options,
)

WorkersOption = Annotated[
    int | None,
    typer.Option(
        "--workers",
        help="Worker processes of the embedded local Dask cluster (default: one per CPU); "
        "1 runs everything in this process.",
    ),
]
SchedulerOption = Annotated[
    str | None,
    typer.Option(
        "--scheduler",
        help="Run on an existing Dask cluster: the scheduler's address, tcp://HOST:PORT "
        "(start it with `dask scheduler` and `dask worker tcp://HOST:PORT`).",
    ),
]


@app.command()
@friendly_errors
def batch(
    inputs: Annotated[
        list[str],
        typer.Argument(
            help="Recordings: files (.h5/.hdf5/.csv/.tsv), folders of them (a BROAD folder, "
            "an x-IMU3 export, a phone's per-sensor files) and globs (quote them: "
            "'study/**/*.hdf5').",
            show_default=False,
        ),
    ],
    outdir: Annotated[
        Path, typer.Option("--output", "-o", help="Output folder: <name>.h5 per input, "
                           "summary.csv and summary.parquet.")
    ],
    method: MethodOption = "default",
    param: ParamOption = None,
    frame: Annotated[str | None, typer.Option(help="Output frame (default: the method's).")] = None,
    calibration: Annotated[
        Path | None, typer.Option(help="Calibration JSON (margtrack calibrate) for every input.")
    ] = None,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
    force: Annotated[
        bool, typer.Option("--force", help="Redo every input; replace outputs not made here.")
    ] = False,
    full_hash: Annotated[
        bool,
        typer.Option("--full-hash", help="Tell changed inputs by every byte, not by size, "
                     "time and the first and last MiB (slower on large files)."),
    ] = False,
    chunk_samples: Annotated[
        int, typer.Option(help="Samples per chunk: bounds each worker's memory.")
    ] = 1_000_000,
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    mag_unit: MagUnitOption = None,
    time_unit: TimeUnitOption = None,
    column: ColumnOption = None,
    profile: ProfileOption = None,
) -> None:
    """Estimate the orientation of many recordings: one .h5 each, summary.csv and .parquet.

    Resumable: an output whose input and parameters are unchanged is skipped (--force
    redoes it). A failing input is a `failed` row and the exit code is 1; the others run.
    --column and --profile apply to the inputs that are tables (.csv, .tsv, .txt).
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    from margtrack.batch import BatchConfig, execute, open_pool, plan_batch

    options = read_options(gyr_unit, acc_unit, mag_unit, time_unit, column, profile)
    read_kwargs = {k: (str(v) if k == "profile" else v) for k, v in options.items()
                   if v is not None}
    config = BatchConfig(
        method=method,
        params=tuple(param or ()),
        frame=frame,
        calibration=None if calibration is None else str(calibration),
        read_kwargs=read_kwargs,
        chunk_samples=chunk_samples,
    )
    # usage errors and the skip decisions come before any worker starts
    plan = plan_batch(inputs, outdir, config, force=force, full_hash=full_hash)
    # nothing to run (a rerun of a finished batch): no cluster to start
    where = (1 if not plan.todo and scheduler is None else workers), scheduler
    with open_pool(*where) as pool:
        err_console.print(
            f"batch: {plan.method}, {_count(plan.n_inputs)} ({len(plan.todo)} to run), "
            f"{pool.description}"
        )
        with Progress(
            "{task.description}", BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
            console=err_console, transient=True,
        ) as bar:
            task = bar.add_task("recordings", total=plan.n_inputs)

            def progress(row: dict, finished: int, total: int) -> None:
                bar.update(task, completed=finished,
                           description=f"{row['status']}: {Path(row['file']).name}")
                if row["status"] == "failed":
                    warn(f"{row['file']} failed: {row['error']}")

            result = execute(plan, pool, progress)
    counts = result.counts()
    done = [r for r in result.rows if r["status"] == "done"]
    samples = sum(r["samples"] or 0 for r in done)
    speed = f"; {samples / result.seconds:,.0f} samples/s" if done and result.seconds > 0 else ""
    console.print(
        f"{_count(len(result.rows))}: {counts['done']} done, {counts['skipped']} skipped, "
        f"{counts['failed']} failed in {result.seconds:.1f} s{speed} -> {result.summary_csv}"
        + (f", {result.summary_parquet.name}" if result.summary_parquet else ""),
        soft_wrap=True,
    )
    if result.note:
        warn(result.note)
    if counts["failed"]:
        err_console.print(
            f"[bold red]{counts['failed']} of {_count(len(result.rows))} failed[/]; "
            f"their errors are in {result.summary_csv} (column error)",
            soft_wrap=True,
        )
        raise typer.Exit(code=1)


def _count(n: int) -> str:
    return f"{n} recording{'' if n == 1 else 's'}"
