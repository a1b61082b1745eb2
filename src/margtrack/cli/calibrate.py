"""``margtrack calibrate ...``: the calibration commands (a typer app the main CLI mounts).

Every command reads a recording (any format :func:`margtrack.io.read` knows), prints its
figures and, with ``--output``, writes or updates a calibration JSON (the other sensors of
an existing file are kept, so ``accel``, ``mag``, ``gyro`` and ``allan`` can fill one file).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape

from margtrack.calibration.cli_common import (
    OutputOption,
    fmt,
    friendly,
    make_table,
    read,
    triad_rows,
    update,
)
from margtrack.cli.calibrate_guided import guided

calibrate_app = typer.Typer(
    name="calibrate",
    help="Calibrate a MARG sensor: guided 18-step procedure, accelerometer, magnetometer, "
    "gyroscope, Allan variance noise.",
    no_args_is_help=True,
    add_completion=False,
)


@calibrate_app.command()
@friendly
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


calibrate_app.command(name="guided")(friendly(guided))


@calibrate_app.command()
@friendly
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
    rec = read(path)
    segments = static_segments(rec)
    means = segment_means(rec.acc, segments)
    poses = make_table(f"{len(segments)} still poses", ["pose", "t (s)", "acc x", "acc y", "acc z"])
    for k, ((a, b), m) in enumerate(zip(segments, means, strict=True)):
        poses.add_row(str(k), f"{rec.t[a]:.1f}-{rec.t[b - 1]:.1f}", *fmt(m))
    console.print(poses)
    choice = acc_cal.choose_accel_model(means, gravity_m_s2)
    table = make_table("accelerometer", ["figure", "x", "y", "z"])
    for fit_name, result in choice.fits.items():
        triad_rows(table, fit_name, result.triad(), "m/s²")
        table.add_row(f"{fit_name} RMS residual (m/s²)", f"{result.rms_residual_m_s2:.5f}", "", "")
    if choice.six is not None:
        table.add_row("six-position null, eq. 1 (m/s²)", *fmt(choice.six.null_m_s2))
        table.add_row("six-position scale, eq. 2", *fmt(choice.six.scale, 6))
    for fit_name, reason in choice.failures.items():
        console.print(f"{fit_name}: {escape(reason)}")
    console.print(table)
    chosen = choice.chosen
    console.print(f"calibration: {chosen.method}")
    update(output, console, acc=chosen)


@calibrate_app.command()
@friendly
def mag(
    path: Annotated[Path, typer.Argument(help="Recording of free rotations (tumbling).")],
    output: OutputOption = None,
    field_ut: Annotated[float | None, typer.Option(help="Local field strength, µT.")] = None,
) -> None:
    """Magnetometer: ellipsoid fit (hard + soft iron) with quality, and min/max (eqs. 3-4)."""
    from margtrack.calibration.magnetometer import fit_ellipsoid, min_max

    console = Console()
    rec = read(path)
    if rec.mag is None:
        raise ValueError(f"{path} has no magnetometer")
    mm = min_max(rec.mag, field_ut)
    fit = fit_ellipsoid(rec.mag, field_ut)
    table = make_table("magnetometer", ["figure", "x", "y", "z"])
    table.add_row("min/max null, eq. 3 (µT)", *fmt(mm.null_ut))
    table.add_row("min/max scale, eq. 4", *fmt(mm.scale, 6))
    table.add_row("ellipsoid hard iron (µT)", *fmt(fit.offset_ut))
    for i, row in enumerate(fit.soft_iron):
        table.add_row(f"ellipsoid soft iron row {'xyz'[i]}", *fmt(row, 6))
    console.print(table)
    console.print(f"field {fit.field_ut:.3f} µT; residual RMS {fit.residual_rms_ut:.3f} µT "
                  f"({100 * fit.residual_spread:.2f} %); sphere coverage "
                  f"{100 * fit.coverage:.0f} %; thinnest spread {100 * fit.thinnest_spread:.0f} %")
    update(output, console, mag=fit.triad())


@calibrate_app.command()
@friendly
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
    rec = read(path)
    found = gyro_cal.gyro_from_turns(rec.t, rec.gyr, static_segments(rec), angle_deg, tolerance)
    for angles in found.skipped_deg:
        console.print(f"skipped a turn of {np.round(angles, 1).tolist()} deg: not a "
                      f"multiple of {angle_deg:g} deg about one axis")
    null, turns, scale = found.null, found.rotations, found.scale
    table = make_table("known turns (000 eq. 5)",
                       ["turn", "axis", "known (deg)", "integrated (deg)", "scale factor"])
    for k, r in enumerate(turns):
        table.add_row(str(k), "xyz"[r.axis], f"{r.known_deg:+g}", f"{r.integrated_deg:+.3f}",
                      f"{r.scale_factor:.6f}")
    console.print(table)
    summary = make_table("gyroscope", ["figure", "x", "y", "z"])
    summary.add_row("null (deg/s)", *fmt(np.degrees(null.null_rad_s)))
    summary.add_row("null noise floor (deg/s)", *fmt(np.degrees(null.noise_floor_rad_s), 3))
    summary.add_row("scale factor (mean)", *fmt(scale.scale_factor, 6))
    summary.add_row("± half range", *fmt(scale.spread, 3))
    console.print(summary)
    update(output, console, gyr=scale.triad())


@calibrate_app.command()
@friendly
def allan(
    path: Annotated[Path, typer.Argument(help="Long recording of a still sensor.")],
    png: Annotated[Path, typer.Option(help="Plot to write.")] = Path("allan.png"),
    output: OutputOption = None,
) -> None:
    """Allan deviation of gyro and accelerometer: noise terms and Kalman filter densities."""
    from margtrack.calibration import allan as av

    console = Console()
    rec = read(path)
    rate = rec.rate_hz
    if rec.gaps().size:
        raise ValueError(f"{path} has {rec.gaps().size} gaps; Allan variance needs even sampling")
    gyr_dev = av.allan_deviation(rec.gyr, rate)
    acc_dev = av.allan_deviation(rec.acc, rate)
    gyr_terms, acc_terms = av.identify_noise(gyr_dev), av.identify_noise(acc_dev)
    table = make_table(f"Allan variance ({rec.duration_s:.0f} s at {rate:.1f} Hz)",
                   ["term", "x", "y", "z"])
    deg = 180.0 / math.pi
    table.add_row("gyr N, angle random walk (deg/s/√Hz)", *fmt(gyr_terms.white * deg, 4))
    table.add_row("gyr B, bias instability (deg/s)", *fmt(gyr_terms.bias_instability * deg, 4))
    table.add_row("gyr K, rate random walk (deg/s/√s)", *fmt(gyr_terms.random_walk * deg, 4))
    table.add_row("acc N, velocity random walk (m/s²/√Hz)", *fmt(acc_terms.white, 4))
    table.add_row("acc B, bias instability (m/s²)", *fmt(acc_terms.bias_instability, 4))
    table.add_row("acc K, acceleration random walk (m/s³/√Hz)", *fmt(acc_terms.random_walk, 4))
    console.print(table)
    noise = av.noise_densities(gyr_terms, acc_terms)
    for key, value in noise.to_dict().items():
        console.print(f"{key} = {value:.6g}")
    for key, value in noise.per_sample(rate).items():
        console.print(f"per sample at {rate:.1f} Hz: {key} = {value:.6g}")
    av.plot_allan([("gyroscope", gyr_dev, gyr_terms, "rad/s"),
                   ("accelerometer", acc_dev, acc_terms, "m/s²")], png)
    console.print(f"plot: {png}")
    update(output, console, noise=noise)


@calibrate_app.command()
@friendly
def apply(
    path: Annotated[Path, typer.Argument(help="Raw recording.")],
    calibration: Annotated[Path, typer.Option("--calibration", "-c", help="Calibration JSON.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="Calibrated recording file.")],
) -> None:
    """Write a calibrated copy of a recording (gyr, acc, mag corrected)."""
    from margtrack import io
    from margtrack.calibration.calibration_file import load_calibration

    rec = load_calibration(calibration).apply(read(path))
    io.write(rec, output)
    Console().print(f"wrote {output}: {rec.n_samples} samples calibrated with {calibration}")


@calibrate_app.command()
@friendly
def show(path: Annotated[Path, typer.Argument(help="Calibration JSON.")]) -> None:
    """Print a calibration file: per triad bias, scale, misalignment; reference; noise."""
    from margtrack.calibration.calibration_file import load_calibration

    cal = load_calibration(path)
    console = Console()
    table = make_table(f"{path} (version {cal.version}; {cal.source or 'no source'})",
                   ["figure", "x", "y", "z"])
    triad_rows(table, "gyr", cal.gyr, "deg/s", 180.0 / math.pi)
    triad_rows(table, "acc", cal.acc, "m/s²")
    if cal.mag is not None:
        triad_rows(table, "mag", cal.mag, "µT")
    console.print(table)
    if cal.reference is not None:
        ref = cal.reference
        console.print(f"reference: gravity {ref.gravity_m_s2:.4f} m/s², field "
                      f"{ref.field_ut:.2f} µT, dip {ref.dip_deg:.2f} deg")
    if cal.noise is not None:
        for key, value in cal.noise.to_dict().items():
            console.print(f"{key} = {value:.6g}")
