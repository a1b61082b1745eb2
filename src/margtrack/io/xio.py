"""x-IMU3 recordings (x-io Technologies) exported as one CSV per message type.

A sensor folder holds:

- ``Inertial.csv``: ``Timestamp (us)``, ``Gyroscope X/Y/Z (deg/s)``, ``Accelerometer X/Y/Z (g)``;
- ``Magnetometer.csv`` (optional): ``Timestamp (us)``, ``X/Y/Z (a.u.)``, at its own slower rate;
- ``Quaternion.csv`` (optional): the device's on-board orientation estimate ``W, X, Y, Z``;
- ``Command.json`` (optional): the device's ``name`` and serial number ``sn``.

:func:`read_xio_sensor` converts to SI (deg/s to rad/s, g to m/s² with standard gravity,
µs to s), keeps absolute timestamps, and resamples the magnetometer linearly onto the
inertial timestamps (inertial samples outside the magnetometer's span hold its first or last
value; their count is ``meta["mag_held_samples"]``).

Timestamp policy: timestamps must be strictly increasing in every file. A duplicate or
backwards step raises ``ValueError`` naming the file, the sample and its line; nothing is
dropped or reordered silently (the shipped lower-body recording has none). Dropped packets
(intervals above 1.5 times the median) are kept as gaps and counted in
``meta["inertial_gaps"]``.

Declared units. The units in the column names are the reader's defaults
(``gyr_unit="deg/s"``, ``acc_unit="g"``, ``time_unit="us"``, magnetometer left in a.u.).
A declared unit replaces the default for the raw column, it does not apply on top of the
conversion: ``read_xio_sensor(folder, gyr_unit="rad/s")`` takes the gyroscope columns as
rad/s whatever their names say, and ``gyr_unit="deg/s"`` is the default, converted once.
``margtrack.io.read`` passes its declarations here for the same reason.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.io.csv import _header, _load
from margtrack.io.hdf5 import _naming_path
from margtrack.recording import Recording, resample
from margtrack.units import (
    check_unit_magnitudes,
    convert_unit,
    unit_factor,
    unit_fix_keyword,
)

__all__ = ["read_xio_body", "read_xio_quaternion", "read_xio_sensor"]

_TIME = "Timestamp (us)"
_INERTIAL = [
    _TIME,
    "Gyroscope X (deg/s)", "Gyroscope Y (deg/s)", "Gyroscope Z (deg/s)",
    "Accelerometer X (g)", "Accelerometer Y (g)", "Accelerometer Z (g)",
]
_MAGNETOMETER = [_TIME, "X (a.u.)", "Y (a.u.)", "Z (a.u.)"]
_QUATERNION = [_TIME, "W", "X", "Y", "Z"]


def _folder(folder: str | Path) -> Path:
    root = Path(folder)
    if not root.is_dir():
        raise FileNotFoundError(f"x-IMU3 folder {root} does not exist")
    return root


def _table(
    path: Path, names: list[str], time_unit: str = "us"
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Timestamps in s and the other columns of an x-IMU3 CSV, timestamps checked.

    ``time_unit`` is the unit of the timestamp column (the export's is us).
    """
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    _, header, skip = _header(path)
    data = _load(path, names, header, skip, "; is this an x-IMU3 export?")
    t_raw = data[:, 0]
    steps = np.diff(t_raw)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        kind = "duplicate" if steps[i - 1] == 0 else "backwards (non-monotonic)"
        raise ValueError(
            f"{path}: {kind} timestamp at sample {i} (line {i + skip + 1}): "
            f"{t_raw[i - 1]:.0f} {time_unit} then {t_raw[i]:.0f} {time_unit}; x-IMU3 timestamps "
            "must be strictly increasing: remove or reorder the repeated rows deliberately "
            "before reading"
        )
    return convert_unit(t_raw, "time", time_unit), data[:, 1:]


def _device(root: Path) -> tuple[str, str | None]:
    """Device name and serial number from Command.json (folder name and None if absent)."""
    path = root / "Command.json"
    if not path.is_file():
        return root.name, None
    try:
        entries = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path} is not valid JSON: {exc}") from None
    for entry in entries if isinstance(entries, list) else [entries]:
        ping = entry.get("ping") if isinstance(entry, dict) else None
        if isinstance(ping, dict) and "name" in ping:
            sn = ping.get("sn")
            return str(ping["name"]), None if sn is None else str(sn)
    return root.name, None


def read_xio_sensor(
    folder: str | Path,
    *,
    gyr_unit: str = "deg/s",
    acc_unit: str = "g",
    mag_unit: str | None = None,
    time_unit: str = "us",
    check_units: bool = True,
) -> Recording:
    """Read one x-IMU3 sensor folder as a Recording in SI units.

    Parameters
    ----------
    folder : a folder with ``Inertial.csv`` (and optionally ``Magnetometer.csv``, ``Command.json``).
    gyr_unit, acc_unit, time_unit : the units of the raw gyroscope, accelerometer and
        timestamp columns (default: those the export's column names give); a declaration
        replaces the default, it is not applied on top of it (module docstring).
    mag_unit : the unit of the raw magnetometer columns (``MAG_UNITS``: "uT", "G"...), converted
        to µT; None (default) keeps the export's arbitrary units (a.u.).
    check_units : refuse gyr that looks like deg/s and acc that looks like g after conversion
        (a :class:`~margtrack.recording.UnitError` naming ``gyr_unit``/``acc_unit``).

    Returns
    -------
    Recording with t (N,) absolute s (device clock), gyr (N, 3) rad/s, acc (N, 3) m/s²,
    mag (N, 3) a.u. resampled onto t (None without ``Magnetometer.csv``), no truth, name the
    device name, and meta with ``source``, ``serial_number``, ``units`` (the original ones),
    ``mag_rate_hz``, ``mag_held_samples``, ``inertial_gaps`` and ``units_converted`` (the
    conversions applied, as :meth:`~margtrack.recording.Recording.with_units` records them).
    """
    declared = {"gyr": gyr_unit, "acc": acc_unit, "time": time_unit}
    if mag_unit is not None:
        declared["mag"] = mag_unit
    for signal, unit in declared.items():
        unit_factor(signal, unit)  # unknown units fail before reading
    root = _folder(folder)
    t_s, inertial = _table(root / "Inertial.csv", _INERTIAL, time_unit)
    name, serial = _device(root)
    meta: dict[str, Any] = {
        "source": str(root),
        "serial_number": serial,
        "units": {
            "t": time_unit, "gyr": gyr_unit, "acc": acc_unit,
            "mag": "a.u." if mag_unit is None else mag_unit,
        },
        "gravity_m_s2": STANDARD_GRAVITY_M_S2,
        "mag_rate_hz": None,
        "mag_held_samples": 0,
    }
    mag = None
    mag_path = root / "Magnetometer.csv"
    if mag_path.is_file():
        t_mag_s, mag_raw = _table(mag_path, _MAGNETOMETER, time_unit)
        if mag_unit is not None:
            mag_raw = convert_unit(mag_raw, "mag", mag_unit)
        if t_mag_s.size >= 2:
            meta["mag_rate_hz"] = float(1.0 / np.median(np.diff(t_mag_s)))
        meta["mag_held_samples"] = int(np.sum((t_s < t_mag_s[0]) | (t_s > t_mag_s[-1])))
        with _naming_path(mag_path):
            mag = resample(t_mag_s, mag_raw, t_s)
    steps = np.diff(t_s)
    meta["inertial_gaps"] = int(np.sum(steps > 1.5 * np.median(steps))) if steps.size >= 2 else 0
    meta["units_converted"] = {
        signal: unit for signal, unit in declared.items()
        if unit_factor(signal, unit) != 1.0 and (signal != "mag" or mag is not None)
    }
    with _naming_path(root / "Inertial.csv"):
        rec = Recording.from_arrays(
            inertial[:, 0:3], inertial[:, 3:6], mag, t=t_s, gyr_unit=gyr_unit,
            acc_unit=acc_unit, check_units=False, name=name, meta=meta,
        )
        if check_units:
            check_unit_magnitudes(
                rec.gyr, rec.acc, fix=unit_fix_keyword("read_xio_sensor"), t_s=rec.t
            )
    return rec


def read_xio_quaternion(folder: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Read the device's own orientation estimate from ``Quaternion.csv``.

    Parameters
    ----------
    folder : an x-IMU3 sensor folder.

    Returns
    -------
    t_s : (M,) absolute timestamps, s (same clock as :func:`read_xio_sensor`).
    quat : (M, 4) ``[w, x, y, z]`` in the device's own earth frame, not converted, scaled to
        unit norm: the device writes norms of about 1.00012 (the shipped recording has
        1.000121 to 1.000125 in every sensor), too far from 1 for the quaternion functions.
    """
    path = _folder(folder) / "Quaternion.csv"
    t_s, quat = _table(path, _QUATERNION)
    norms = np.linalg.norm(quat, axis=1)
    bad = np.flatnonzero(~np.isfinite(norms) | (norms < 0.5) | (norms > 1.5))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{path}: quaternion at sample {i} is not a rotation: {quat[i]}")
    return t_s, quat / norms[:, None]


def read_xio_body(folder: str | Path, **units: Any) -> dict[str, Recording]:
    """Read every sensor subfolder (one with ``Inertial.csv``) of an x-IMU3 body recording.

    Parameters
    ----------
    folder : a folder of sensor folders (e.g. ``pelvis/``, ``left_foot/``...).
    **units : ``gyr_unit``, ``acc_unit``, ``mag_unit``, ``time_unit``, ``check_units`` for
        every sensor (see :func:`read_xio_sensor`).

    Returns
    -------
    Recordings keyed by subfolder name, in sorted order (see :func:`read_xio_sensor`).
    """
    root = _folder(folder)
    sensors = sorted(d for d in root.iterdir() if (d / "Inertial.csv").is_file())
    if not sensors:
        raise FileNotFoundError(
            f"{root} has no sensor subfolder with an Inertial.csv; "
            "for a single sensor folder use read_xio_sensor"
        )
    return {d.name: read_xio_sensor(d, **units) for d in sensors}
