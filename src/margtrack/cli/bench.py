"""The ``bench`` commands: margtrack against other libraries on real data."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from margtrack.cli.app import app, console, friendly_errors, warn
from margtrack.cli.batch import SchedulerOption, WorkersOption
from margtrack.cli.evaluate import CVByOption, CVCommand, cv_split

if TYPE_CHECKING:
    from margtrack.bench.cv import CVResult
    from margtrack.recording import Recording

#: the peer libraries `bench broad` compares with: name -> the package that provides it
PEER_PACKAGES = {
    "vqf": "vqf", "vqf-offline": "vqf", "imufusion": "imufusion", "madgwick": "ahrs"
}


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


@bench_app.command("broad", cls=CVCommand)
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
        str,
        typer.Option(
            help="Other libraries, comma-separated: vqf, vqf-offline, imufusion, madgwick."
        ),
    ] = "vqf,vqf-offline,imufusion",
    madgwick_beta: Annotated[
        float,
        typer.Option(help="Gain of ahrs' Madgwick (best single beta on BROAD; pure Python, slow)."),
    ] = 0.08,
    out: Annotated[Path, typer.Option(help="PNG bar plot.")] = Path("broad_comparison.png"),
    cv: Annotated[
        bool,
        typer.Option(
            "--cv/--no-cv",
            help="Also cross-validate every method with a declared grid (--cv or --cv trial: "
            "leave-one-trial-out; --cv group: leave-one-group-out; one run of each grid "
            "point on every trial: minutes).",
        ),
    ] = True,
    cv_by: CVByOption = None,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Compare margtrack's methods with other libraries on BROAD: table, bar plot, speed.

    With --cv (the default) each method with a declared grid (margtrack.bench.grids) is
    also cross-validated: every trial scored with the grid point best on the other 15,
    printed next to the in-sample figure. With --cv group each kind of trial (trials.json:
    its disturbance, else its speed and motion) is held out in turn instead, and scored
    with the grid point best on the other kinds, printed per kind beside
    leave-one-trial-out. Its grid points run like `margtrack tune`'s (--workers /
    --scheduler).
    """
    import time

    from rich.progress import Progress

    from margtrack import io, methods
    from margtrack.bench import compare as cmp
    from margtrack.bench import external as ext
    from margtrack.bench.runner import Method

    split = cv_split(cv_by)
    if cv_by is not None and not cv:
        raise ValueError("--cv-by is a cross-validation option: leave out --no-cv")
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
            raise ValueError(
                f"unknown external library {name!r}; known: vqf, vqf-offline, imufusion, "
                "madgwick"
            )
    trials = io.broad_trials(folder)
    if cv and split == "group":
        from margtrack.bench import broad
        from margtrack.bench.cv import fold_of_kinds

        kind_of = broad.trial_kinds(folder)  # a folder without groups fails before any run
        fold_of_kinds([kind_of[t.name] for t in trials])
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
        started = time.perf_counter()
        result = cmp.compare(recordings, runs, progress=progress)
        wall_s = time.perf_counter() - started
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
    if cv:
        # wall time of one default run per method: its estimation plus an equal share of
        # the scoring (the cv runs every grid point like that once)
        spare = max(0.0, wall_s - sum(m.seconds for m in result.methods)) / len(result.methods)
        seconds = {m.method: m.seconds + spare for m in result.methods}
        kinds = None
        if split == "group":
            from margtrack.cli.evaluate import kinds_of

            kinds = kinds_of(folder, trials, recordings)
        _cross_validate_all(names, recordings, seconds, folder, workers, scheduler, kinds)


def _cross_validate_all(
    names: list[str],
    recordings: list[tuple[Recording, tuple[str, ...]]],
    seconds: dict[str, float],
    folder: Path,
    workers: int | None,
    scheduler: str | None,
    kinds: dict[str, str] | None = None,
) -> None:
    """Cross-validate each of ``names`` with a declared grid and print the table; by
    ``kinds`` (recording name -> kind) also leave-one-group-out, per kind."""
    import itertools
    import time

    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from margtrack.batch.cluster import mapper_of, open_pool
    from margtrack.bench import broad, grids
    from margtrack.bench import cv as crossval
    from margtrack.cli.evaluate import group_folds_table
    from margtrack.methods import get

    tuned = [n for n in names if grids.has_grid(get(n).name)]
    if not tuned:
        console.print("cross-validation: none of these methods has a declared grid")
        return
    points = {
        n: len(list(itertools.product(*grids.declared_grid(get(n).name).values()))) for n in tuned
    }
    guess_s = sum(points[n] * seconds.get(n, 0.0) for n in tuned)
    console.print(
        f"cross-validating {', '.join(tuned)}: {sum(points.values())} grid points, each run "
        f"once on the {len(recordings)} trials; at the speed of the runs above about "
        + (f"{guess_s:.0f} s" if guess_s < 120 else f"{guess_s / 60:.0f} min")
        + " in one process"
    )
    start = time.perf_counter()
    results: list[CVResult] = []
    columns = (TextColumn("{task.description}"), BarColumn(), TimeRemainingColumn())
    with Progress(*columns, transient=True) as bar, open_pool(workers, scheduler) as pool:
        mapper = None if pool.client is None else mapper_of(pool)
        task = bar.add_task("cross-validation", total=sum(points.values()) + len(tuned))
        for n in tuned:

            def progress(label: str, n: str = n) -> None:
                bar.update(task, description=f"cv {n}: {label}")
                bar.advance(task)

            results.append(crossval.cross_validate(
                n, grids.declared_grid(get(n).name), recordings,
                group_order=broad.group_order(folder), progress=progress, mapper=mapper,
            ))
    console.print(cv_comparison_table(results))
    if kinds is not None:
        by_group = [crossval.cross_validate_grid(r.grid, kinds=kinds) for r in results]
        console.print(cv_comparison_table(by_group))
        for r, g in zip(results, by_group, strict=True):
            console.print(group_folds_table(g, r))
    console.print(
        f"cross-validation took {time.perf_counter() - start:.0f} s ({pool.description}). "
        "cross-validated: each trial scored with the grid point best on the other trials."
    )


def cv_comparison_table(results: list[CVResult]) -> Table:
    """Per method: defaults and best point in-sample, cross-validated means, stability."""
    split = results[0].split_name() if results else "leave-one-trial-out"
    table = Table(title=f"BROAD: in-sample vs {split} cross-validated (deg)")
    table.add_column("method", no_wrap=True)
    for col in ("default", "best", "CV", "CV h/i", "CV u/d", "folds"):
        table.add_column(col, justify="right", no_wrap=True)
    for r in results:
        scores = r.cross_validated
        cvm = scores.mean()
        by_group = "/".join(
            f"{scores.mean(g)['total_rmse_deg']:.2f}" if g in scores.groups() else "-"
            for g in ("undisturbed", "disturbed")
        )
        default = "-" if r.default is None else f"{r.default.mean()['total_rmse_deg']:.2f}"
        table.add_row(
            r.method, default, f"{r.best_in_sample.mean()['total_rmse_deg']:.2f}",
            f"{cvm['total_rmse_deg']:.2f}",
            f"{cvm['heading_rmse_deg']:.2f}/{cvm['inclination_rmse_deg']:.2f}", by_group,
            f"{sum(f.chosen == r.best_index for f in r.folds)}/{len(r.folds)}",
        )
    table.caption = (
        "default, best: mean total on all trials (in-sample); CV: each trial scored with the "
        "grid point best on the "
        + ("trials of other kinds" if results and results[0].by_kind else "others")
        + " (total, heading/inclination, undisturbed/disturbed); "
        "folds: how many chose the in-sample best"
    )
    return table
