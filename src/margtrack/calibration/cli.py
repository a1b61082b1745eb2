"""``margtrack calibrate ...``: the calibration commands (a typer app the main CLI mounts).

Every command reads a recording (any format :func:`margtrack.io.read` knows), prints its
figures and, with ``--output``, writes or updates a calibration JSON (the other sensors of
an existing file are kept, so ``accel``, ``mag``, ``gyro`` and ``allan`` can fill one file).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

calibrate_app = typer.Typer(
    name="calibrate",
    help="Calibrate a MARG sensor: guided 18-step procedure, accelerometer, magnetometer, "
    "gyroscope, Allan variance noise.",
    no_args_is_help=True,
    add_completion=False,
)

F = TypeVar("F", bound=Callable[..., Any])
OutputOption = Annotated[
    Path | None,
    typer.Option("--output", "-o", help="Calibration JSON to write (kept parts are updated)."),
]


def _friendly(func: F) -> F:
    """Bad input becomes a one-line message and exit code 2 instead of a traceback."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (ValueError, FileNotFoundError, OSError) as exc:
            Console(stderr=True).print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)
            raise typer.Exit(code=2) from None

    return wrapper  # type: ignore[return-value]


def _read(path: Path):
    from margtrack import io

    return io.read(path)


def _update(output: Path | None, console: Console, **parts: Any) -> None:
    from margtrack.calibration.calibration_file import (
        Calibration,
        load_calibration,
        save_calibration,
    )

    if output is None:
        return
    existed = output.is_file()
    base = load_calibration(output) if existed else Calibration()
    calibration = dataclasses.replace(base, **parts)
    save_calibration(calibration, output)
    console.print(f"{'updated' if existed else 'wrote'} {output}")


def _table(title: str, columns: list[str]) -> Table:
    table = Table(title=title)
    for k, col in enumerate(columns):
        table.add_column(col, justify="left" if k == 0 else "right")
    return table


def _fmt(values: Any, digits: int = 5) -> list[str]:
    return [f"{v:.{digits}g}" for v in np.asarray(values, dtype=float).ravel()]


def _triad_rows(table: Table, label: str, triad: Any, unit: str, factor: float = 1.0) -> None:
    scale, mis, rot = triad.decompose()
    table.add_row(f"{label} bias ({unit})", *_fmt(triad.b * factor))
    table.add_row(f"{label} scale error (%)", *_fmt(100.0 * scale, 4))
    table.add_row(f"{label} misalignment αx αy αz (deg)", *_fmt(mis, 4))
    table.add_row(f"{label} triad rotation (deg)", f"{rot:.4f}", "", "")


@calibrate_app.command()
@_friendly
def simulate(
    output: Annotated[Path, typer.Option("--output", "-o", help="Recording file (.h5 or .csv).")],
    kind: Annotated[str, typer.Option(help="procedure (000's 18 steps), still or tumble.")] = (
        "procedure"
    ),
    profile: Annotated[str, typer.Option(help="Sensor errors: none, mems or raw.")] = "mems",
    rate_hz: Annotated[float, typer.Option("--rate", help="Sample rate, Hz.")] = 100.0,
    duration_s: Annotated[float, typer.Option("--duration", help="still/tumble length, s.")] = (
        60.0
    ),
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
) -> None:
    """Write a simulated recording to try the other commands on (truth in NED)."""
    from margtrack import io, sim
    from margtrack.calibration.simulate_procedure import error_profile, simulate_procedure

    gyr, acc, mag = error_profile(profile)
    if kind == "procedure":
        rec = simulate_procedure(gyr, acc, mag, rate_hz=rate_hz, seed=seed)
    elif kind in ("still", "tumble"):
        trajectory = (sim.static(duration_s, rate_hz) if kind == "still"
                      else sim.random_motion(duration_s, rate_hz, seed, max_rate_deg_s=150.0))
        rec = sim.simulate(trajectory, frame="NED", gyr_errors=gyr, acc_errors=acc,
                           mag_errors=mag, seed=seed, name=f"sim-{kind}")
    else:
        raise ValueError(f"kind must be procedure, still or tumble, got {kind!r}")
    io.write(rec, output)
    Console().print(f"wrote {output}: {rec.n_samples} samples, {rec.duration_s:.1f} s, {kind}, "
                    f"{profile} sensor errors")


@calibrate_app.command()
@_friendly
def guided(
    source: Annotated[Path | None, typer.Option(
        "--source", "-s", help="Recording of the procedure (offline).")] = None,
    output: Annotated[Path, typer.Option("--output", "-o", help="Calibration JSON.")] = Path(
        "calibration.json"
    ),
    quiet: Annotated[bool, typer.Option(help="Print only the result.")] = False,
    udp: Annotated[int | None, typer.Option(
        "--udp", help="Live: lines t,sensor,gx,...,mz on this UDP port (127.0.0.1).")] = None,
    serial: Annotated[str | None, typer.Option(
        "--serial", help="Live: lines from this serial port.")] = None,
    sensors: Annotated[str, typer.Option(
        help="Live: the stream's sensors, a count or comma-separated names.")] = "1",
    sensor: Annotated[str | None, typer.Option(
        help="Live: the sensor to calibrate (name or index; default the first).")] = None,
    timeout: Annotated[float, typer.Option(
        help="Live: give up after this many seconds (wall clock).")] = 600.0,
    force: Annotated[bool, typer.Option(
        "--force", help="Live: replace an existing --output file.")] = False,
) -> None:
    """Walk through 000's 18 steps on a recording, or live on a sensor (--udp/--serial),
    printing each instruction, a progress bar for each hold and what is wrong."""
    from margtrack.calibration.calibration_file import save_calibration
    from margtrack.calibration.guided import GuidedCalibration

    console = Console()
    if (udp is not None or serial is not None) == (source is not None) or (
            udp is not None and serial is not None):
        raise ValueError("give exactly one of --source FILE, --udp PORT or --serial DEVICE")
    if source is None:
        _guided_live(udp, serial, sensors, sensor, timeout, output, force, quiet, console)
        return
    rec = _read(source)
    if rec.mag is None:
        raise ValueError(f"{source} has no magnetometer; the procedure needs one (steps 15-18)")
    machine = GuidedCalibration()
    style = {"instruction": "bold cyan", "done": "green", "warning": "yellow", "finished": "bold"}
    if not quiet:
        console.print(f"[{style['instruction']}]{machine.instruction}[/]")
    block = max(1, round(rec.rate_hz))
    for start in range(0, rec.n_samples, block):
        s = slice(start, start + block)
        for e in machine.add_samples(rec.t[s], rec.gyr[s], rec.acc[s], rec.mag[s]):
            if not quiet:
                console.print(f"{e.t_s:8.2f} s  [{style[e.kind]}]{escape(e.message)}[/]")
        if machine.finished:
            break
    result = machine.result()
    cal = result.calibration
    _guided_table(result, console)
    save_calibration(dataclasses.replace(cal, source=f"guided procedure on {source.name}"),
                     output)
    console.print(f"wrote {output}")


def _guided_table(result: Any, console: Console) -> None:
    cal = result.calibration
    table = _table("guided calibration (000 Appendix B)", ["figure", "x", "y", "z"])
    table.add_row("gyro scale factor, eq. 5", *_fmt(result.gyro_scale.scale_factor, 6))
    _triad_rows(table, "gyr", cal.gyr, "deg/s", 180.0 / math.pi)
    table.add_row("acc null, eq. 1 (m/s²)", *_fmt(result.six_position.null_m_s2))
    table.add_row("acc scale, eq. 2", *_fmt(result.six_position.scale, 6))
    _triad_rows(table, "acc", cal.acc, "m/s²")
    table.add_row("mag null, eq. 3 (µT)", *_fmt(result.min_max.null_ut))
    table.add_row("mag scale, eq. 4", *_fmt(result.min_max.scale, 6))
    if cal.mag is None or cal.reference is None:
        raise ValueError("the procedure produced no magnetometer calibration")
    _triad_rows(table, "mag", cal.mag, "µT")
    ref = cal.reference
    table.add_row("reference acc (m/s²)", *_fmt(ref.acc_m_s2))
    table.add_row("reference mag (µT)", *_fmt(ref.mag_ut))
    console.print(table)
    console.print(f"gravity {ref.gravity_m_s2:.4f} m/s², field {ref.field_ut:.2f} µT, "
                  f"dip {ref.dip_deg:.2f} deg, x from north {ref.heading_offset_deg:+.2f} deg")
    for note in cal.notes:
        console.print(f"- {note}")


def _guided_live(udp: int | None, serial: str | None, sensors: str, sensor: str | None,
                 timeout: float, output: Path, force: bool, quiet: bool,
                 console: Console) -> None:
    """The procedure live on one sensor of a UDP or serial line stream (terminal display:
    events as they come and, every 0.5 s of data, the step, a hold progress bar and what is
    wrong; a terminal shows the status line in place)."""
    import time

    from margtrack.calibration.live_procedure import LiveProcedure, save_result
    from margtrack.io.safe_output import check_output
    from margtrack.live.calibration_panel import feed_chunks

    check_output(output, force=force)  # before the person spends minutes on the procedure
    names = ([f"sensor{i}" for i in range(int(sensors))] if sensors.strip().isdigit()
             else [n.strip() for n in sensors.split(",") if n.strip()])
    if not names:
        raise ValueError("--sensors must be a count or comma-separated names")
    key = names[0] if sensor is None else sensor
    index = int(key) if key.isdigit() else (names.index(key) if key in names else -1)
    if not 0 <= index < len(names):
        raise ValueError(f"--sensor {key!r} is not one of {', '.join(names)}")
    if udp is not None:
        from margtrack.live.udp import UdpSource

        src: Any = UdpSource(names, port=udp)
    else:
        from margtrack.live.serial_port import SerialSource

        src = SerialSource(str(serial), names)
    procedure = LiveProcedure()
    style = {"instruction": "bold cyan", "done": "green", "warning": "yellow", "finished": "bold"}
    console.print(f"guided calibration of {names[index]} on {src.info.description}")
    console.print(f"[{style['instruction']}]{procedure.status.instruction}[/]")
    end = time.perf_counter() + timeout
    next_line = 0.0
    src.open()
    try:
        while not procedure.finished and time.perf_counter() < end:
            for e in feed_chunks(procedure, src.poll(0.1), index):
                if not quiet:
                    console.print(f"{e.t_s:8.2f} s  [{style[e.kind]}]{escape(e.message)}[/]",
                                  soft_wrap=True)
            st = procedure.status
            if not quiet and st.samples and st.t_s >= next_line and not st.finished:
                next_line = st.t_s + 0.5
                console.print(escape(st.line()), end="\r" if console.is_terminal else "\n",
                              soft_wrap=True)
    finally:
        src.close()
    if procedure.rejected or src.stats.malformed:
        console.print(f"rejected: {src.stats.malformed} malformed lines, {procedure.rejected} "
                      f"samples ({procedure.last_rejection or src.stats.last_error})")
    if not procedure.finished:
        raise ValueError(f"no finished procedure after {timeout:g} s; still waiting for "
                         f"{procedure.status.instruction}")
    result = procedure.result()
    _guided_table(result, console)
    path = save_result(result, output, source=f"live guided procedure on {names[index]}",
                       force=force)
    console.print(f"wrote {path} (apply it: margtrack live ... --sensor-calibration "
                  f"{names[index]}={path})", soft_wrap=True)


@calibrate_app.command()
@_friendly
def accel(
    path: Annotated[Path, typer.Argument(help="Recording with still poses.")],
    output: OutputOption = None,
    gravity_m_s2: Annotated[float, typer.Option("--gravity", help="Local gravity, m/s².")] = (
        9.80665
    ),
) -> None:
    """Accelerometer from the still poses of a recording: six-position and least squares."""
    from margtrack.calibration import accelerometer as acc_cal
    from margtrack.calibration.static import segment_means, static_segments

    console = Console()
    rec = _read(path)
    segments = static_segments(rec)
    means = segment_means(rec.acc, segments)
    poses = _table(f"{len(segments)} still poses", ["pose", "t (s)", "acc x", "acc y", "acc z"])
    for k, ((a, b), m) in enumerate(zip(segments, means, strict=True)):
        poses.add_row(str(k), f"{rec.t[a]:.1f}-{rec.t[b - 1]:.1f}", *_fmt(m))
    console.print(poses)
    choice = acc_cal.choose_accel_model(means, gravity_m_s2)
    table = _table("accelerometer", ["figure", "x", "y", "z"])
    for fit_name, result in choice.fits.items():
        _triad_rows(table, fit_name, result.triad(), "m/s²")
        table.add_row(f"{fit_name} RMS residual (m/s²)", f"{result.rms_residual_m_s2:.5f}", "", "")
    if choice.six is not None:
        table.add_row("six-position null, eq. 1 (m/s²)", *_fmt(choice.six.null_m_s2))
        table.add_row("six-position scale, eq. 2", *_fmt(choice.six.scale, 6))
    for fit_name, reason in choice.failures.items():
        console.print(f"{fit_name}: {escape(reason)}")
    console.print(table)
    chosen = choice.chosen
    console.print(f"calibration: {chosen.method}")
    _update(output, console, acc=chosen)


@calibrate_app.command()
@_friendly
def mag(
    path: Annotated[Path, typer.Argument(help="Recording of free rotations (tumbling).")],
    output: OutputOption = None,
    field_ut: Annotated[float | None, typer.Option(help="Local field strength, µT.")] = None,
) -> None:
    """Magnetometer: ellipsoid fit (hard + soft iron) with quality, and min/max (eqs. 3-4)."""
    from margtrack.calibration.magnetometer import fit_ellipsoid, min_max

    console = Console()
    rec = _read(path)
    if rec.mag is None:
        raise ValueError(f"{path} has no magnetometer")
    mm = min_max(rec.mag, field_ut)
    fit = fit_ellipsoid(rec.mag, field_ut)
    table = _table("magnetometer", ["figure", "x", "y", "z"])
    table.add_row("min/max null, eq. 3 (µT)", *_fmt(mm.null_ut))
    table.add_row("min/max scale, eq. 4", *_fmt(mm.scale, 6))
    table.add_row("ellipsoid hard iron (µT)", *_fmt(fit.offset_ut))
    for i, row in enumerate(fit.soft_iron):
        table.add_row(f"ellipsoid soft iron row {'xyz'[i]}", *_fmt(row, 6))
    console.print(table)
    console.print(f"field {fit.field_ut:.3f} µT; residual RMS {fit.residual_rms_ut:.3f} µT "
                  f"({100 * fit.residual_spread:.2f} %); sphere coverage "
                  f"{100 * fit.coverage:.0f} %; thinnest spread {100 * fit.thinnest_spread:.0f} %")
    _update(output, console, mag=fit.triad())


@calibrate_app.command()
@_friendly
def gyro(
    path: Annotated[Path, typer.Argument(help="Recording: still, then turns between holds.")],
    angle_deg: Annotated[float, typer.Option(help="Turns are multiples of this, deg.")] = 90.0,
    tolerance: Annotated[
        float, typer.Option(help="Skip turns further than this fraction from a multiple.")
    ] = 0.05,
    output: OutputOption = None,
) -> None:
    """Gyroscope null (first still period) and scale factors from known turns (000 eq. 5).

    Every turn between two holds must be a whole multiple of --angle-deg about one axis
    (turn the sensor from face to face of a box); others are skipped and listed.
    """
    from margtrack.calibration import gyroscope as gyro_cal
    from margtrack.calibration.static import static_segments

    console = Console()
    rec = _read(path)
    found = gyro_cal.gyro_from_turns(rec.t, rec.gyr, static_segments(rec), angle_deg, tolerance)
    for angles in found.skipped_deg:
        console.print(f"skipped a turn of {np.round(angles, 1).tolist()} deg: not a "
                      f"multiple of {angle_deg:g} deg about one axis")
    null, turns, scale = found.null, found.rotations, found.scale
    table = _table("known turns (000 eq. 5)", ["turn", "axis", "known (deg)", "integrated (deg)",
                                               "scale factor"])
    for k, r in enumerate(turns):
        table.add_row(str(k), "xyz"[r.axis], f"{r.known_deg:+g}", f"{r.integrated_deg:+.3f}",
                      f"{r.scale_factor:.6f}")
    console.print(table)
    summary = _table("gyroscope", ["figure", "x", "y", "z"])
    summary.add_row("null (deg/s)", *_fmt(np.degrees(null.null_rad_s)))
    summary.add_row("null noise floor (deg/s)", *_fmt(np.degrees(null.noise_floor_rad_s), 3))
    summary.add_row("scale factor (mean)", *_fmt(scale.scale_factor, 6))
    summary.add_row("± half range", *_fmt(scale.spread, 3))
    console.print(summary)
    _update(output, console, gyr=scale.triad())


@calibrate_app.command()
@_friendly
def allan(
    path: Annotated[Path, typer.Argument(help="Long recording of a still sensor.")],
    png: Annotated[Path, typer.Option(help="Plot to write.")] = Path("allan.png"),
    output: OutputOption = None,
) -> None:
    """Allan deviation of gyro and accelerometer: noise terms and Kalman filter densities."""
    from margtrack.calibration import allan as av

    console = Console()
    rec = _read(path)
    rate = rec.rate_hz
    if rec.gaps().size:
        raise ValueError(f"{path} has {rec.gaps().size} gaps; Allan variance needs even sampling")
    gyr_dev = av.allan_deviation(rec.gyr, rate)
    acc_dev = av.allan_deviation(rec.acc, rate)
    gyr_terms, acc_terms = av.identify_noise(gyr_dev), av.identify_noise(acc_dev)
    table = _table(f"Allan variance ({rec.duration_s:.0f} s at {rate:.1f} Hz)",
                   ["term", "x", "y", "z"])
    deg = 180.0 / math.pi
    table.add_row("gyr N, angle random walk (deg/s/√Hz)", *_fmt(gyr_terms.white * deg, 4))
    table.add_row("gyr B, bias instability (deg/s)", *_fmt(gyr_terms.bias_instability * deg, 4))
    table.add_row("gyr K, rate random walk (deg/s/√s)", *_fmt(gyr_terms.random_walk * deg, 4))
    table.add_row("acc N, velocity random walk (m/s²/√Hz)", *_fmt(acc_terms.white, 4))
    table.add_row("acc B, bias instability (m/s²)", *_fmt(acc_terms.bias_instability, 4))
    table.add_row("acc K, acceleration random walk (m/s³/√Hz)", *_fmt(acc_terms.random_walk, 4))
    console.print(table)
    noise = av.noise_densities(gyr_terms, acc_terms)
    for key, value in noise.to_dict().items():
        console.print(f"{key} = {value:.6g}")
    for key, value in noise.per_sample(rate).items():
        console.print(f"per sample at {rate:.1f} Hz: {key} = {value:.6g}")
    av.plot_allan([("gyroscope", gyr_dev, gyr_terms, "rad/s"),
                   ("accelerometer", acc_dev, acc_terms, "m/s²")], png)
    console.print(f"plot: {png}")
    _update(output, console, noise=noise)


@calibrate_app.command()
@_friendly
def apply(
    path: Annotated[Path, typer.Argument(help="Raw recording.")],
    calibration: Annotated[Path, typer.Option("--calibration", "-c", help="Calibration JSON.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="Calibrated recording file.")],
) -> None:
    """Write a calibrated copy of a recording (gyr, acc, mag corrected)."""
    from margtrack import io
    from margtrack.calibration.calibration_file import load_calibration

    rec = load_calibration(calibration).apply(_read(path))
    io.write(rec, output)
    Console().print(f"wrote {output}: {rec.n_samples} samples calibrated with {calibration}")


@calibrate_app.command()
@_friendly
def show(path: Annotated[Path, typer.Argument(help="Calibration JSON.")]) -> None:
    """Print a calibration file: per triad bias, scale, misalignment; reference; noise."""
    from margtrack.calibration.calibration_file import load_calibration

    cal = load_calibration(path)
    console = Console()
    table = _table(f"{path} (version {cal.version}; {cal.source or 'no source'})",
                   ["figure", "x", "y", "z"])
    _triad_rows(table, "gyr", cal.gyr, "deg/s", 180.0 / math.pi)
    _triad_rows(table, "acc", cal.acc, "m/s²")
    if cal.mag is not None:
        _triad_rows(table, "mag", cal.mag, "µT")
    console.print(table)
    if cal.reference is not None:
        ref = cal.reference
        console.print(f"reference: gravity {ref.gravity_m_s2:.4f} m/s², field "
                      f"{ref.field_ut:.2f} µT, dip {ref.dip_deg:.2f} deg")
    if cal.noise is not None:
        for key, value in cal.noise.to_dict().items():
            console.print(f"{key} = {value:.6g}")
