"""Options and input helpers shared by the commands that read a recording."""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
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
    str,
    typer.Option(
        "--method", "-m", show_default=False,
        help="Estimation method (default: the recommended one; `margtrack methods` lists "
        "them and marks it).",
    ),
]
#: what the subject faces in the reference pose (margtrack body, margtrack live)
HEADING_HELP = (
    "What the subject faces in the reference pose: 'pelvis' (the pelvis sensor's "
    "--forward-axis) or 'north' (magnetic north; every magnetometer must work)."
)
#: the pelvis sensor's forward axis, one spelling for margtrack body and margtrack live
FORWARD_AXIS_HELP = (
    "The pelvis sensor's axis that points forward: +x, -x, +y, -y, +z, -z or x,y,z "
    "(default -z, an x-IMU3 on the sacrum)."
)

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


ColumnOption = Annotated[
    list[str] | None,
    typer.Option(
        "--column",
        help="Map a CSV/TSV column to a signal, KEY=NAME[,NAME,NAME]; keys t, gyr, acc, mag "
        "(3 names, x y z), quat_true (4, w x y z); repeatable, e.g. --column t=time_ms "
        "--column gyr=gx,gy,gz --column acc=ax,ay,az. Delimiter (, ; tab space) and decimal "
        "comma are detected.",
    ),
]
ProfileOption = Annotated[
    Path | None,
    typer.Option(
        "--profile",
        help="Import profile (TOML): columns, units, delimiter, decimal of a logger, so its "
        "flags are written once; flags given here win over it.",
    ),
]


def units(
    gyr_unit: str | None, acc_unit: str | None, mag_unit: str | None, time_unit: str | None
) -> dict[str, str | None]:
    """The unit options as keyword arguments of ``io.read`` / ``io.read_any``."""
    return {"gyr_unit": gyr_unit, "acc_unit": acc_unit, "mag_unit": mag_unit,
            "time_unit": time_unit}


def parse_columns(items: list[str] | tuple[str, ...]) -> dict[str, list[str]]:
    """``--column KEY=NAME[,NAME...]`` items as a column map; errors say which item and why."""
    from margtrack.io.csv_layout import FIELD_WIDTHS, normalise_columns

    out: dict[str, list[str]] = {}
    for item in items:
        key, sep, names = item.partition("=")
        key = key.strip()
        if not sep or not key or not names.strip():
            raise ValueError(
                f"--column {item!r} is not KEY=NAME[,NAME,NAME]; e.g. --column gyr=gx,gy,gz"
            )
        if key not in FIELD_WIDTHS:
            raise ValueError(
                f"--column {item!r}: unknown key {key!r}; the keys are t, gyr, acc, mag, "
                "quat_true (and movement)"
            )
        if key in out:
            raise ValueError(
                f"--column {key}= is given twice ({','.join(out[key])} and {names}); give "
                "each key once"
            )
        try:
            out.update(normalise_columns({key: names}))
        except ValueError as exc:
            raise ValueError(f"--column {item!r}: {exc}") from None
    return out


def read_options(
    gyr_unit: str | None = None,
    acc_unit: str | None = None,
    mag_unit: str | None = None,
    time_unit: str | None = None,
    column: list[str] | None = None,
    profile: Path | None = None,
) -> dict[str, object]:
    """The input options of a command as keyword arguments of ``io.read`` / ``io.read_any``.

    The units always; ``columns`` and ``profile`` only when given (readers of formats
    that take no column map see no such keyword).
    """
    out: dict[str, object] = dict(units(gyr_unit, acc_unit, mag_unit, time_unit))
    if column:
        out["columns"] = parse_columns(column)
    if profile is not None:
        out["profile"] = profile
    return out


@contextmanager
def reader_warnings() -> Iterator[None]:
    """Within the block, Python warnings (a reader leaving out a truncated line, holding an
    empty cell) print as one-line CLI warnings instead of a file:line Python warning."""
    from margtrack.cli.app import warn

    def show(message: object, *args: object, **kwargs: object) -> None:
        warn(str(message))

    with warnings.catch_warnings():
        warnings.simplefilter("always", UserWarning)
        warnings.showwarning = show  # type: ignore[assignment]
        yield


def cli_unit_fix(signal: str, suspected: str) -> str:
    """The fix sentence of a unit mix-up on the command line: the option to declare."""
    return f"declare the file's unit with --{signal}-unit {suspected}"


def check_units(rec: Recording, source: object) -> Recording:
    """``rec`` if its magnitudes look like rad/s, m/s² and s, else a UnitError naming
    ``source``."""
    try:
        check_unit_magnitudes(rec.gyr, rec.acc, fix=cli_unit_fix, t_s=rec.t)
    except UnitError as exc:
        raise exc.prefixed(f"{source}: ") from None
    return rec


def read_checked(path: Path, units: dict[str, object]) -> list[Recording]:
    """Every recording at ``path`` (``io.read_any``) read with the input options
    (:func:`read_options`: units, columns, profile), magnitudes checked."""
    from margtrack import io

    with reader_warnings():
        recs = io.read_any(path, **units)  # type: ignore[arg-type]
    return [check_units(r, path if len(recs) == 1 else f"{path} [{r.name}]") for r in recs]
