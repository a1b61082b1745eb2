"""The ``run`` command: estimate one recording's orientation and save it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from margtrack.cli.app import app, console, err_console, friendly_errors
from margtrack.cli.options import (
    AccUnitOption,
    GyrUnitOption,
    MagUnitOption,
    MethodOption,
    ParamOption,
    TimeUnitOption,
    check_units,
    units,
)


@app.command()
@friendly_errors
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

    rec = check_units(io.read(path, **units(gyr_unit, acc_unit, mag_unit, time_unit)), path)
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
