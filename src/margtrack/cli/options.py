"""Options and input helpers shared by the commands that read a recording."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from margtrack.recording import Recording
from margtrack.units import (
    ACC_UNITS,
    GYR_UNITS,
    MAG_UNITS,
    TIME_UNITS,
    UnitError,
    check_unit_magnitudes,
)

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


def units(
    gyr_unit: str | None, acc_unit: str | None, mag_unit: str | None, time_unit: str | None
) -> dict[str, str | None]:
    """The unit options as keyword arguments of ``io.read`` / ``io.read_any``."""
    return {"gyr_unit": gyr_unit, "acc_unit": acc_unit, "mag_unit": mag_unit,
            "time_unit": time_unit}


def cli_unit_fix(signal: str, suspected: str) -> str:
    """The fix sentence of a unit mix-up on the command line: the option to declare."""
    return f"declare the file's unit with --{signal}-unit {suspected}"


def check_units(rec: Recording, source: object) -> Recording:
    """``rec`` if its magnitudes look like rad/s and m/s², else a UnitError naming ``source``."""
    try:
        check_unit_magnitudes(rec.gyr, rec.acc, fix=cli_unit_fix)
    except UnitError as exc:
        raise UnitError(f"{source}: {exc}", signal=exc.signal, suspected=exc.suspected) from None
    return rec


def read_checked(path: Path, units: dict[str, str | None]) -> list[Recording]:
    """Every recording at ``path`` (``io.read_any``) in the declared units, magnitudes checked."""
    from margtrack import io

    recs = io.read_any(path, **units)
    return [check_units(r, path if len(recs) == 1 else f"{path} [{r.name}]") for r in recs]
