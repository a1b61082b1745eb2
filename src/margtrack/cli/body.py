"""The ``body`` command: a multi-sensor recording to joint angles, OpenSim .sto, BVH and a plot."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from margtrack.cli.app import app, console, friendly_errors
from margtrack.cli.options import (
    FORWARD_AXIS_HELP,
    HEADING_HELP,
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
)


def _window(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    parts = text.replace(" ", "").split(",")
    try:
        start, end = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"--pose-window takes START,END in s (e.g. 0.5,1.5), got {text!r}"
                         ) from None
    return start, end


@app.command()
@friendly_errors
def body(
    path: Annotated[Path, typer.Argument(
        help="x-IMU3 body folder (one folder per sensor), a folder of per-sensor files "
        "(pelvis.h5, right_thigh.csv...), or a multi-sensor recording (margtrack live "
        "--record).")],
    output: Annotated[Path, typer.Option(
        "--output", "-o", help="Output folder (created if missing): joint_angles.csv, "
        "orientations.sto, pelvis_position.csv, motion.bvh, joint_angles.png, "
        "gait_cycles.csv, gait_cycles.png, sensor_flags.csv, summary.txt.")],
    map_file: Annotated[Path | None, typer.Option(
        "--map", help="TOML map of sensor names to segments (\\[sensors] imu_3 = \"pelvis\"), "
        "for sensors not named after segments.")] = None,
    method: MethodOption = "default",
    param: ParamOption = None,
    pose_window: Annotated[str | None, typer.Option(
        "--pose-window", help="START,END s from the start: the reference pose (standing, "
        "facing the heading reference). Default: the first still second.")] = None,
    heading: Annotated[str, typer.Option(help=HEADING_HELP)] = "pelvis",
    forward_axis: Annotated[str | None, typer.Option(
        "--forward-axis", help=FORWARD_AXIS_HELP.replace("(default -z", "(default: the "
                                                         "map's, else -z"))] = None,
    rate_hz: Annotated[float | None, typer.Option(
        "--rate-hz", help="Rate of the common time base, Hz (default: the slowest sensor's, "
        "rounded to a whole Hz within 1 %).")] = None,
    height_m: Annotated[float | None, typer.Option(
        "--height-m", help="Body height, m: segment lengths for positions and BVH (default "
        "the map's, else 1.75); angles do not depend on it.")] = None,
    align_start: Annotated[bool, typer.Option(
        "--align-start", help="Re-time every sensor from its first sample (sensors started "
        "together on unsynchronised clocks).")] = False,
    bvh_unit: Annotated[str, typer.Option(
        "--bvh-unit", help="Length unit of motion.bvh: cm (the default; Blender's BVH import "
        "scale 0.01) or m (import scale 1).")] = "cm",
    force: Annotated[bool, typer.Option(
        "--force", help="Replace output files that already exist.")] = False,
    no_mag: Annotated[bool, typer.Option(
        "--no-mag", help="Use no magnetometer: the pelvis sensor 6-D (its heading fixed on "
        "the reference pose), every other segment tied to its parent across the joint from "
        "both gyroscopes and accelerometers (lever arms estimated; listed in the summary).")
    ] = False,
    offline: Annotated[bool, typer.Option(
        "--offline", help="With --no-mag: the joints' offline estimate (the whole recording "
        "for every sample; finds the relative headings in a still reference pose at the "
        "start) instead of the online filter.")] = False,
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    mag_unit: MagUnitOption = None,
    time_unit: TimeUnitOption = None,
    column: ColumnOption = None,
    profile: ProfileOption = None,
) -> None:
    """Joint angles, gait cycles, OpenSim .sto and a walking BVH from body-worn sensors."""
    from margtrack import body as mt_body
    from margtrack.body.export_bvh import BVH_UNITS
    from margtrack.body.outputs import check_outputs

    if heading not in ("pelvis", "north"):
        raise ValueError(f"--heading must be 'pelvis' or 'north', got {heading!r}")
    if no_mag and heading == "north":
        raise ValueError("--heading north needs the magnetometers, which --no-mag leaves out; "
                         "use --heading pelvis (the default)")
    if offline and not no_mag:
        raise ValueError("--offline chooses the joints' estimate of --no-mag; give it with "
                         "--no-mag")
    if bvh_unit not in BVH_UNITS:
        raise ValueError(f"--bvh-unit must be cm or m, got {bvh_unit!r}")
    window = _window(pose_window)
    body_map = mt_body.read_body_map(map_file) if map_file is not None else None
    inputs = [path] + [p for p in (map_file, profile) if p is not None]
    check_outputs(output, inputs, force=force)  # before any work
    skipped: list[str] = []
    recs = mt_body.read_body(
        path, body_map, skipped,
        **read_options(gyr_unit, acc_unit, mag_unit, time_unit, column, profile))
    recs = {name: check_units(rec, f"{path} [{name}]") for name, rec in recs.items()}
    result = mt_body.process_body(
        recs, body_map, method, param or (), window, heading,  # type: ignore[arg-type]
        forward_axis=forward_axis, rate_hz=rate_hz, height_m=height_m,
        align_start=align_start, notes=skipped, no_mag=no_mag, offline=offline,
    )
    for line in result.summary():
        console.print(line, markup=False, highlight=False, soft_wrap=True)
    written = result.write(output, force=force, inputs=inputs, bvh_unit=bvh_unit)
    console.print(f"wrote {', '.join(p.name for p in written.values())} to {output}",
                  markup=False, highlight=False, soft_wrap=True)
    default = ", the default" if bvh_unit == "cm" else ""
    console.print(f"motion.bvh lengths in {bvh_unit} (--bvh-unit {bvh_unit}{default}): "
                  f"import it into Blender with scale {BVH_UNITS[bvh_unit]:g}",
                  markup=False, highlight=False, soft_wrap=True)
