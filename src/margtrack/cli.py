"""The ``margtrack`` command: inspect, simulate, estimate and evaluate recordings."""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from margtrack.recording import Recording
from margtrack.units import (
    ACC_UNITS,
    GYR_UNITS,
    MAG_UNITS,
    TIME_UNITS,
    UnitError,
    check_unit_magnitudes,
)

app = typer.Typer(
    name="margtrack",
    help="Orientation tracking with MARG sensors (gyroscope, accelerometer, magnetometer).",
    no_args_is_help=True,
    add_completion=False,
)
console = Console()
err_console = Console(stderr=True)


def _mount_calibration() -> None:
    from margtrack.calibration.cli import calibrate_app

    app.add_typer(calibrate_app, name="calibrate", help="Calibrate a MARG sensor (000, 003).")


_mount_calibration()


def _mount_live() -> None:
    from margtrack.live.cli import live_command

    app.command(
        name="live",
        help="Track sensors live in a browser page (simulator, replay, UDP, serial).",
    )(live_command)


_mount_live()

F = TypeVar("F", bound=Callable[..., Any])

MethodOption = Annotated[
    str, typer.Option("--method", "-m", help="Estimation method (see `margtrack methods`).")
]
ParamOption = Annotated[
    list[str] | None,
    typer.Option("--param", "-p", help="Method parameter as name=value; repeatable."),
]


# The units of a recording file's raw columns, declared on every command that reads one.
GyrUnitOption = Annotated[
    str | None,
    typer.Option(
        "--gyr-unit",
        help=f"Unit of the file's gyroscope values: {', '.join(GYR_UNITS)} (default: the "
        "format's own: rad/s in margtrack and BROAD files, deg/s in x-IMU3 exports).",
    ),
]
AccUnitOption = Annotated[
    str | None,
    typer.Option(
        "--acc-unit",
        help=f"Unit of the file's accelerometer values: {', '.join(ACC_UNITS)} "
        "(g = 9.80665 m/s²; default: the format's own: m/s² in margtrack and BROAD files, g "
        "in x-IMU3 exports).",
    ),
]
MagUnitOption = Annotated[
    str | None,
    typer.Option(
        "--mag-unit",
        help=f"Unit of the file's magnetometer values, converted to µT: {', '.join(MAG_UNITS)} "
        "(G = gauss; default: kept as stored).",
    ),
]
TimeUnitOption = Annotated[
    str | None,
    typer.Option(
        "--time-unit",
        help=f"Unit of the file's timestamps: {', '.join(TIME_UNITS)} (default: the "
        "format's own: s in margtrack files, us in x-IMU3 exports).",
    ),
]


def _units(
    gyr_unit: str | None, acc_unit: str | None, mag_unit: str | None, time_unit: str | None
) -> dict[str, str | None]:
    """The unit options as keyword arguments of ``io.read`` / ``io.read_any``."""
    return {"gyr_unit": gyr_unit, "acc_unit": acc_unit, "mag_unit": mag_unit,
            "time_unit": time_unit}


def cli_unit_fix(signal: str, suspected: str) -> str:
    """The fix sentence of a unit mix-up on the command line: the option to declare."""
    return f"declare the file's unit with --{signal}-unit {suspected}"


def _check_units(rec: Recording, source: object) -> Recording:
    """``rec`` if its magnitudes look like rad/s and m/s², else a UnitError naming ``source``."""
    try:
        check_unit_magnitudes(rec.gyr, rec.acc, fix=cli_unit_fix)
    except UnitError as exc:
        raise UnitError(f"{source}: {exc}", signal=exc.signal, suspected=exc.suspected) from None
    return rec


def _read_checked(path: Path, units: dict[str, str | None]) -> list[Recording]:
    """Every recording at ``path`` (``io.read_any``) in the declared units, magnitudes checked."""
    from margtrack import io

    recs = io.read_any(path, **units)
    return [_check_units(r, path if len(recs) == 1 else f"{path} [{r.name}]") for r in recs]


def _friendly_errors(func: F) -> F:
    """Turn input errors into a one-line message and exit code 2 instead of a traceback."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (ValueError, FileNotFoundError, KeyError, OSError) as exc:
            err_console.print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)
            raise typer.Exit(code=2) from None

    return wrapper  # type: ignore[return-value]


@app.command()
@_friendly_errors
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
@_friendly_errors
def info(
    path: Annotated[Path, typer.Argument(help="Recording file or folder.")],
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    mag_unit: MagUnitOption = None,
    time_unit: TimeUnitOption = None,
) -> None:
    """Say what a recording holds: samples, rate, duration, units, frame, gaps, truth."""
    from margtrack import io

    recordings = io.read_any(path, **_units(gyr_unit, acc_unit, mag_unit, time_unit))
    for rec in recordings:
        try:
            _check_units(rec, path if len(recordings) == 1 else f"{path} [{rec.name}]")
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


@app.command()
@_friendly_errors
def simulate(
    output: Annotated[Path, typer.Option("--output", "-o", help="Output .h5/.hdf5 or .csv file.")],
    motion: Annotated[
        str, typer.Option(help="random, limb, static or tilt (constant rotation about x).")
    ] = "random",
    duration_s: Annotated[float, typer.Option("--duration", help="Length in s.")] = 60.0,
    rate_hz: Annotated[float, typer.Option("--rate", help="Sample rate in Hz.")] = 100.0,
    seed: Annotated[int, typer.Option(help="Random seed (same seed, same data).")] = 0,
    frame: Annotated[str, typer.Option(help="Earth frame of the truth: ENU or NED.")] = "ENU",
    noise: Annotated[bool, typer.Option(help="Apply the MEMS sensor error model.")] = True,
    mag: Annotated[bool, typer.Option(help="Include a magnetometer.")] = True,
) -> None:
    """Write a simulated recording with ground truth."""
    from margtrack import io, sim

    rec = sim.simulate_motion(
        motion,
        duration_s=duration_s,
        rate_hz=rate_hz,
        seed=seed,
        frame=frame,
        noise=noise,
        with_mag=mag,
    )
    io.write(rec, output)
    console.print(
        f"wrote {output}: {rec.n_samples} samples at {rate_hz:g} Hz, {motion} motion, "
        f"{'noisy' if noise else 'noise-free'}, truth in {rec.frame}"
    )


@app.command()
@_friendly_errors
def run(
    path: Annotated[Path, typer.Argument(help="Recording file or x-IMU3 sensor folder.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="Output .h5/.hdf5 or .csv.")],
    method: MethodOption = "default",
    param: ParamOption = None,
    frame: Annotated[str | None, typer.Option(help="Output frame (default: the method's).")] = None,
    calibration: Annotated[
        Path | None, typer.Option(help="Calibration JSON (margtrack calibrate) to apply first.")
    ] = None,
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    mag_unit: MagUnitOption = None,
    time_unit: TimeUnitOption = None,
) -> None:
    """Estimate the orientation of a recording and save it (datasets `t` and `quat`)."""
    from margtrack import io, methods
    from margtrack.bench.metrics import error_series, summarize

    rec = _check_units(io.read(path, **_units(gyr_unit, acc_unit, mag_unit, time_unit)), path)
    for name, hit in rec.saturation().items():
        advice = (
            "remove the magnet or metal near the sensor"
            if name == "mag"
            else "choose a wider sensor range"
        )
        err_console.print(
            f"[yellow]warning:[/] {name} sits at its range limit ±{hit.level:.4g} from sample "
            f"{hit.first_sample} ({hit.n_samples} samples); estimates there are unreliable: "
            f"{advice}",
            soft_wrap=True,
        )
    values: dict[str, object] = {}
    if calibration is not None:
        from margtrack.calibration import load_calibration

        cal = load_calibration(calibration)
        rec = cal.apply(rec)
        values = cal.parameter_values(methods.get(method).params_type)
        told = ", ".join(f"{k}={v:.4g}" for k, v in values.items())
        console.print(f"applied calibration {calibration}" + (f"; sets {told}" if told else ""))
    # parameters given with -p win over the calibration's
    values.update(methods.parse_params_items(param or ()))
    estimator = methods.create(method, values)
    estimate = estimator.run(rec)
    if frame is not None:
        estimate = estimate.in_frame(frame)
    io.write_estimate(estimate, output)
    console.print(
        f"{estimator.name}: {estimate.n_samples} samples, frame {estimate.frame} -> {output}"
    )
    if estimate.flags is not None:
        from margtrack.estimator.flags import summary

        console.print(summary(estimate.flags), soft_wrap=True)
    if rec.quat_true is not None:
        s = summarize(
            error_series(estimate.quat, rec.quat_true, estimate.frame, rec.frame), rec.movement
        )
        console.print(
            f"against the truth: total {s.total_rmse_deg:.2f} deg, heading "
            f"{s.heading_rmse_deg:.2f} deg, inclination {s.inclination_rmse_deg:.2f} deg RMSE"
        )


@app.command()
@_friendly_errors
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
) -> None:
    """Error table (RMSE in degrees) of a method against ground truth."""
    from rich.progress import Progress

    from margtrack import io, methods
    from margtrack.bench import broad

    estimator = methods.create(method, param or ())
    cls = type(estimator)
    params = estimator.params

    def make():
        return cls(params)

    units = _units(gyr_unit, acc_unit, mag_unit, time_unit)
    if path.is_dir() and any(path.glob("*.hdf5")):
        trials = io.broad_trials(path)
        order = broad.group_order(path)
        # one trial in memory at a time, read with the declared units and checked
        recs: Iterable[tuple[Recording, tuple[str, ...]]] = (
            (_check_units(io.read(t.path, **units), t.path), tuple(t.groups)) for t in trials
        )
    else:
        trials, order = [], ()
        recs = [(r, ()) for r in _read_checked(path, units)]
    with Progress(transient=True, disable=not trials) as bar:
        task = bar.add_task(f"{cls.name} on {len(trials)} trials", total=len(trials))

        def progress(name: str) -> None:
            bar.update(task, description=f"{cls.name}: {name}")
            bar.advance(task)

        result = broad.evaluate_recordings(
            make, recs, method=cls.name, params=params.as_dict(), group_order=order,
            progress=progress,
        )
    console.print(broad.format_table(result))
    console.print(
        f"speed: {result.samples_per_s():,.0f} samples/s (including compilation on first use)"
    )
    if json_out is not None:
        result.write_json(json_out)
        console.print(f"wrote {json_out}")


@app.command()
@_friendly_errors
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
) -> None:
    """Find one parameter set for all trials that minimises the mean total RMSE."""
    import itertools

    from rich.progress import Progress

    from margtrack import io, methods
    from margtrack.bench import broad
    from margtrack.bench import tune as tuning

    units = _units(gyr_unit, acc_unit, mag_unit, time_unit)
    candidates = tuning.parse_grid(grid)
    fixed = dict(methods.parse_params_items(param or ()))
    n_points = len(list(itertools.product(*candidates.values())))
    with Progress(transient=True) as bar:
        loading = bar.add_task("reading recordings", total=None)
        if path.is_dir() and any(path.glob("*.hdf5")):
            trials = io.broad_trials(path)
            recordings = [
                (_check_units(io.read(t.path, **units), t.path), tuple(t.groups))
                for t in trials
            ]
            order = broad.group_order(path)
        else:
            recordings = [(r, ()) for r in _read_checked(path, units)]
            order = ()
        bar.remove_task(loading)
        task = bar.add_task(f"tuning {method}", total=n_points)

        def progress(point: str) -> None:
            bar.update(task, description=f"{method}: {point}")
            bar.advance(task)

        result = tuning.tune(
            method, candidates, recordings, fixed=fixed, group_order=order, progress=progress
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


@app.command()
@_friendly_errors
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


bench_app = typer.Typer(
    help="Benchmarks on real data, against other libraries.", no_args_is_help=True
)
app.add_typer(bench_app, name="bench")


@bench_app.command("broad")
@_friendly_errors
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


@app.command()
@_friendly_errors
def demo(
    duration_s: Annotated[float, typer.Option("--duration", help="Simulated length in s.")] = 60.0,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
) -> None:
    """Simulate a noisy MARG recording and compare every method against its truth."""
    from margtrack import methods, sim
    from margtrack.bench import broad

    rec = sim.simulate_motion("random", duration_s=duration_s, rate_hz=100.0, seed=seed)
    console.print(
        f"simulated {rec.duration_s:.0f} s of random motion at 100 Hz with MEMS sensor errors "
        f"(seed {seed})"
    )
    table = Table(title="RMSE against the simulated truth (deg)")
    for col in ("method", "total", "heading", "inclination"):
        table.add_column(col, justify="left" if col == "method" else "right")
    for name in methods.available():
        estimator = methods.create(name)
        errors, _ = broad.evaluate_recording(estimator, rec)
        star = " (default)" if name == methods.DEFAULT_METHOD else ""
        table.add_row(
            name + star,
            f"{errors.total_rmse_deg:.2f}",
            f"{errors.heading_rmse_deg:.2f}",
            f"{errors.inclination_rmse_deg:.2f}",
        )
    console.print(table)


if __name__ == "__main__":  # pragma: no cover
    app()
