"""The ``run`` command: estimate one recording's orientation and save it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from margtrack.cli.app import app, console, friendly_errors, progress_bar, warn
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
    reader_warnings,
)


@app.command()
@friendly_errors
def run(
    paths: Annotated[
        list[Path],
        typer.Argument(
            help="Recording file or folder (x-IMU3 sensor, per-sensor files), or several "
            "files with one sensor type each (Gyroscope.csv Accelerometer.csv ...).",
            show_default=False,
        ),
    ],
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
    column: ColumnOption = None,
    profile: ProfileOption = None,
    force: Annotated[
        bool, typer.Option("--force", help="Replace the output file if it exists.")
    ] = False,
    chunk_samples: Annotated[
        int,
        typer.Option(
            "--chunk-samples", min=1,
            help="Samples processed at a time (bounds the memory; results do not depend on it).",
        ),
    ] = 1_000_000,
) -> None:
    """Estimate the orientation of a recording and save it (datasets `t` and `quat`).

    Several files with one sensor type each (at their own rates) are merged onto the
    gyroscope's timestamps first, as a folder of per-sensor files would be.
    """
    from margtrack import methods
    from margtrack.io.safe_output import check_output
    from margtrack.run.chunked import run_file

    check_output(output, paths, force=force)  # before any reading or computing
    cal = None
    if calibration is not None:
        from margtrack.calibration import load_calibration

        cal = load_calibration(calibration)
        values = cal.parameter_values(methods.get(method).params_type)
        told = ", ".join(f"{k}={v:.4g}" for k, v in values.items())
        console.print(f"applied calibration {calibration}" + (f"; sets {told}" if told else ""))
    # a progress bar on a terminal (long recordings take minutes), nothing in pipes and logs;
    # parameters given with -p win over the calibration's (run_file merges them so)
    with reader_warnings(), progress_bar(", ".join(p.name for p in paths)) as progress:
        result = run_file(
            paths[0] if len(paths) == 1 else paths, output, method, param or (),
            calibration=cal, frame=frame,
            read_kwargs=read_options(gyr_unit, acc_unit, mag_unit, time_unit, column, profile),
            chunk_samples=chunk_samples, force=force, on_warning=warn,
            progress=progress,
        )
    console.print(
        f"{result.method}: {result.samples} samples, frame {result.frame} -> {output}"
    )
    if result.flag_summary:
        console.print(result.flag_summary, soft_wrap=True)
    if result.total_rmse_deg is not None:
        console.print(
            f"against the truth: total {result.total_rmse_deg:.2f} deg, heading "
            f"{result.heading_rmse_deg:.2f} deg, inclination {result.inclination_rmse_deg:.2f} "
            "deg RMSE"
        )
