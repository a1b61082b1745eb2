"""Import profiles: a lab's logger layout written once in a small TOML file.

A profile holds what the command-line flags say about a file (``--column``, the units, the
delimiter), so ``margtrack run data.csv --profile mylogger.toml`` replaces a line of flags::

    # mylogger.toml: our lab's logger (semicolon, decimal comma, ms, deg/s, g)
    delimiter = ";"          # ",", ";", "tab" or "whitespace"; detected when left out
    decimal = ","            # "." or ","; detected when left out
    time_unit = "ms"         # s, ms, us, ns
    gyr_unit = "deg/s"       # rad/s, deg/s
    acc_unit = "g"           # m/s2, g
    mag_unit = "uT"          # uT, nT, mT, T, G, mG
    frame = "ENU"            # the earth frame of a quat_true column
    # rate_hz = 100.0        # only for a file without a time column

    [columns]
    t = "time_ms"
    gyr = ["gx", "gy", "gz"]  # or "gx,gy,gz"
    acc = ["ax", "ay", "az"]
    mag = ["mx", "my", "mz"]
    # quat_true = ["qw", "qx", "qy", "qz"]

Every key is optional; an unknown key is an error (a typo would otherwise be ignored).
Flags given on the command line (or keywords in Python) win over the profile's values.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from margtrack.io.csv_layout import DELIMITERS, normalise_columns
from margtrack.units import unit_factor

__all__ = ["PROFILE_KEYS", "load_profile", "merge_profile"]

#: the keys a profile may hold, and what each is
PROFILE_KEYS = {
    "columns": "table: field (t, gyr, acc, mag, quat_true, movement) -> column name(s)",
    "delimiter": '",", ";", "tab" or "whitespace"',
    "decimal": '"." or ","',
    "time_unit": "unit of the time column: s, ms, us, ns",
    "gyr_unit": "unit of the gyroscope columns: rad/s, deg/s",
    "acc_unit": "unit of the accelerometer columns: m/s2, g",
    "mag_unit": "unit of the magnetometer columns: uT, nT, mT, T, G, mG",
    "frame": "earth frame of the truth columns: ENU or NED",
    "rate_hz": "sampling rate, Hz, for a file without a time column",
}


def load_profile(path: str | Path) -> dict[str, Any]:
    """The keyword arguments of ``margtrack.io.read`` that the profile at ``path`` sets.

    Raises ``ValueError`` naming the file for invalid TOML, an unknown key (listing the
    valid ones), a value of the wrong type, an unknown unit or a malformed column map.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such import profile: {p}")
    try:
        with p.open("rb") as f:
            raw = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{p}: not valid TOML: {exc}") from None
    unknown = sorted(set(raw) - set(PROFILE_KEYS))
    if unknown:
        valid = "; ".join(f"{k} ({v})" for k, v in PROFILE_KEYS.items())
        raise ValueError(f"{p}: unknown key(s) {unknown} in the import profile; valid: {valid}")
    out: dict[str, Any] = {}
    for key, value in raw.items():
        where = f"{p}: {key}"
        if key == "columns":
            if not isinstance(value, dict):
                raise ValueError(f"{where} must be a table ([columns] with t = ..., gyr = ...)")
            try:
                out["columns"] = normalise_columns(value)
            except ValueError as exc:
                raise ValueError(f"{where}: {exc}") from None
        elif key == "rate_hz":
            if isinstance(value, bool) or not isinstance(value, int | float) or value <= 0:
                raise ValueError(f"{where} must be a number > 0, got {value!r}")
            out[key] = float(value)
        else:
            if not isinstance(value, str):
                raise ValueError(f"{where} must be a string, got {value!r}")
            if key.endswith("_unit"):
                try:
                    unit_factor("time" if key == "time_unit" else key.removesuffix("_unit"),
                                value)
                except ValueError as exc:
                    raise ValueError(f"{where}: {exc}") from None
            elif key == "delimiter" and value not in DELIMITERS:
                raise ValueError(f"{where} must be one of {sorted(DELIMITERS)}, got {value!r}")
            elif key == "decimal" and value not in (".", ","):
                raise ValueError(f"{where} must be '.' or ',', got {value!r}")
            elif key == "frame" and value not in ("ENU", "NED"):
                raise ValueError(f"{where} must be 'ENU' or 'NED', got {value!r}")
            out[key] = value
    return out


def merge_profile(profile: str | Path | None, given: dict[str, Any]) -> dict[str, Any]:
    """The profile's settings overridden by ``given`` (values that are not None).

    ``columns`` merge per field: ``--column gyr=...`` replaces the profile's gyr and keeps
    its other fields.
    """
    out = load_profile(profile) if profile is not None else {}
    for key, value in given.items():
        if value is None:
            continue
        if key == "columns":
            out["columns"] = {**out.get("columns", {}), **normalise_columns(value)}
        else:
            out[key] = value
    return out
