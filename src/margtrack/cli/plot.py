"""The ``plot`` command: a PNG of an estimate (or of a recording run through a method)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from margtrack.cli.app import app, console, friendly_errors, warn
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
    read_options,
    reader_warnings,
)


@app.command()
@friendly_errors
def plot(
    path: Annotated[
        Path, typer.Argument(help="Estimate (.h5/.csv from `margtrack run`) or a recording.")
    ],
    output: Annotated[Path, typer.Option("--output", "-o", help="PNG to write.")],
    truth: Annotated[
        Path | None,
        typer.Option(help="Recording with the truth (quat_true) the estimate is compared to."),
    ] = None,
    frame: Annotated[
        str | None,
        typer.Option(help="Earth frame of an estimate CSV that does not state it: ENU or NED."),
    ] = None,
    method: MethodOption = "default",
    param: ParamOption = None,
    show: Annotated[bool, typer.Option(help="Open the PNG in the default viewer.")] = False,
    force: Annotated[bool, typer.Option(help="Replace an existing PNG.")] = False,
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    mag_unit: MagUnitOption = None,
    time_unit: TimeUnitOption = None,
    column: ColumnOption = None,
    profile: ProfileOption = None,
) -> None:
    """Plot orientation (Euler angles), gyro bias, health flags and error against truth.

    An estimate file is drawn as it is (its truth comes from --truth); a recording is
    first run through --method (default: the recommended one) and compared with its own
    truth when it has one.
    """
    from margtrack import io
    from margtrack.bench.plot_estimate import plot_estimate
    from margtrack.estimator.flags import summary
    from margtrack.io.estimate_reader import is_estimate_file, read_estimate
    from margtrack.io.safe_output import check_output

    if output.suffix.lower() != ".png":
        raise ValueError(f"the plot is a PNG: give an output ending in .png, not {output.name}")
    read_kwargs = read_options(gyr_unit, acc_unit, mag_unit, time_unit, column, profile)
    check_output(output, [path] + ([truth] if truth is not None else []), force=force)
    if is_estimate_file(path):
        if method != "default" or param:
            raise ValueError(f"{path} is an estimate already; --method/--param apply to "
                             "recordings (run them with `margtrack run`)")
        estimate = read_estimate(path).estimate(frame)
        reference = None
        if truth is not None:
            with reader_warnings():
                reference = check_units(io.read(truth, **read_kwargs), truth)
    else:
        if truth is not None:
            raise ValueError(f"{path} is a recording: its own quat_true is the truth; "
                             "--truth is for estimate files")
        if frame is not None:
            raise ValueError("--frame declares the frame of an estimate CSV; a recording "
                             "is estimated in the method's frame")
        from margtrack import methods

        with reader_warnings():
            reference = check_units(io.read(path, **read_kwargs), path)
        estimator = methods.create(method, methods.parse_params_items(param or ()))
        estimate = estimator.run(reference)
        if reference.quat_true is None:
            reference = None
    if reference is not None and reference.quat_true is None:
        raise ValueError(f"{truth} has no truth (quat_true) to compare with")
    drawn = plot_estimate(output, estimate, reference)
    console.print(f"plot: {output} ({'; '.join(drawn.panels)})", soft_wrap=True)
    if estimate.flags is not None:
        console.print(summary(estimate.flags), soft_wrap=True)
    if drawn.rmse_deg is not None:
        r = drawn.rmse_deg
        console.print(f"against the truth: total {r['total']:.2f} deg, heading "
                      f"{r['heading']:.2f} deg, inclination {r['inclination']:.2f} deg RMSE")
    if show and typer.launch(str(output)) != 0:
        warn(f"could not open a viewer for {output}; open the file yourself")
