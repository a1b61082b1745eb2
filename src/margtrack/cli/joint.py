"""The ``joint`` command: relative orientation of two sensors across a joint, no magnetometer."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from margtrack.cli.app import app, console, friendly_errors, warn
from margtrack.cli.options import (
    AccUnitOption,
    ColumnOption,
    GyrUnitOption,
    ParamOption,
    ProfileOption,
    TimeUnitOption,
    check_units,
    read_options,
    reader_warnings,
)


@app.command()
@friendly_errors
def joint(
    parent: Annotated[Path, typer.Argument(
        help="Recording of the sensor on the parent segment (any format `margtrack run` "
        "reads; t, gyr, acc; mag is not used).", show_default=False)],
    child: Annotated[Path, typer.Argument(
        help="Recording of the sensor on the child segment.", show_default=False)],
    output: Annotated[Path, typer.Option(
        "--output", "-o", help="Output .h5/.hdf5 or .csv: t, quat (child in the parent's "
        "frame, w x y z), flags; the lever arms in the params.")],
    offline: Annotated[bool, typer.Option(
        "--offline", help="MAP over the whole recording (smoother, uses every sample for "
        "each output) instead of the online filter.")] = False,
    lever_arms: Annotated[Path | None, typer.Option(
        "--lever-arms", help="Known lever arms: JSON {\"parent_m\": \\[x, y, z], \"child_m\": "
        "\\[x, y, z]} (m, joint centre to sensor, each sensor's frame) or an earlier output "
        "of margtrack joint. Default: estimated from the recordings.")] = None,
    param: ParamOption = None,
    rate_hz: Annotated[float | None, typer.Option(
        "--rate-hz", help="Rate of the common time base when the two files' timestamps "
        "differ, Hz (default: the slower sensor's).")] = None,
    align_start: Annotated[bool, typer.Option(
        "--align-start", help="Re-time both sensors from their first sample (started "
        "together on unsynchronised clocks).")] = False,
    force: Annotated[bool, typer.Option(
        "--force", help="Replace the output file if it exists.")] = False,
    gyr_unit: GyrUnitOption = None,
    acc_unit: AccUnitOption = None,
    time_unit: TimeUnitOption = None,
    column: ColumnOption = None,
    profile: ProfileOption = None,
) -> None:
    """Orientation of the child sensor relative to the parent across a joint (docs/joint.md).

    Gyroscopes and accelerometers only: both sensors see the joint centre's acceleration
    through their lever arms, which keeps the relative heading from drifting. Parameters
    (-p name=value): gyr_noise_rad_s_sqrt_hz, link_noise_m_s2, incl_noise_m_s2, ...
    """
    from margtrack import io
    from margtrack.estimator.flags import summary
    from margtrack.io.safe_output import check_output
    from margtrack.joint.lever_arms import read_lever_arms
    from margtrack.joint.params import JointParams
    from margtrack.joint.relative import relative_orientation
    from margtrack.methods import parse_params

    inputs = [parent, child] + [p for p in (lever_arms, profile) if p is not None]
    check_output(output, inputs, force=force)  # before any reading or computing
    params = parse_params(JointParams, param or ())  # type: ignore[arg-type]
    arms = read_lever_arms(lever_arms) if lever_arms is not None else None
    options = read_options(gyr_unit, acc_unit, None, time_unit, column, profile)
    recs = []
    with reader_warnings():
        for path in (parent, child):
            recs.append(check_units(io.read(path, **options), path))  # type: ignore[arg-type]
    est = relative_orientation(recs[0], recs[1], offline=offline, lever_arms=arms,
                               params=params, rate_hz=rate_hz, align_start=align_start)
    for note in est.notes:
        warn(note)
    est.write(output)
    arm = est.lever_arms
    console.print(f"{est.method}: {est.n_samples} samples -> {output}", markup=False,
                  highlight=False)
    for role, r, s in zip(("parent", "child"), arm.r_m, arm.std_m, strict=True):
        spread = "" if arm.source == "given" else " ± " + ", ".join(f"{1e3 * v:.1f}" for v in s)
        console.print(f"lever arm {role} ({arm.source}): "
                      + ", ".join(f"{1e3 * v:.1f}" for v in r) + spread + " mm",
                      markup=False, highlight=False)
    console.print(summary(est.flags), markup=False, highlight=False, soft_wrap=True)
