"""Phone logger exports and folders of per-sensor files, merged onto the gyroscope's timestamps.

Two widely used apps are recognised from their headers:

- **Sensor Logger** (Kelvin Choi, tszheichoi/awesome-sensor-logger, ``UNITS.md`` and
  ``COORDINATES.md``): a zip export unzipped into a folder with one CSV per sensor
  (``Gyroscope.csv``, ``Accelerometer.csv``, ``TotalAcceleration.csv``, ``Gravity.csv``,
  ``Magnetometer.csv``, ``Metadata.csv``...), columns ``time,seconds_elapsed,z,y,x``;
  ``time`` in ns since the epoch, gyroscope rad/s, acceleration m/s², field µT.
  ``Accelerometer.csv`` is acceleration *without* gravity; ``TotalAcceleration.csv``
  (Android) has it. Without it, gravity is added back from ``Gravity.csv``; on iOS both
  have the opposite sign to Android's (the gravity vector points to -z on a table), so the
  sum is negated there (``platform`` in ``Metadata.csv``) to give specific force, which
  points up at rest as margtrack expects.
- **phyphox** (RWTH Aachen; the ``<export>`` sets of its experiment files, e.g.
  ``gyroscope.phyphox``): ``"Time (s)","Gyroscope x (rad/s)",...``, ``"Acceleration x
  (m/s^2)"`` (with gravity), ``"Magnetic field x (µT)"``; one file per sensor (folder of
  ``Accelerometer.csv``, ``Gyroscope.csv``, ``Magnetometer.csv``) or one file with several
  sensors. The unit is read from the column name.

Any other folder of per-sensor files works the same way when its file names say the sensor
(``gyr*``, ``acc*``, ``mag*``...) and its columns are a time column and ``x, y, z`` (in any
order); their units are the declared ones (``gyr_unit``...). The accelerometer and
magnetometer are interpolated linearly onto the gyroscope's timestamps
(:func:`margtrack.recording.resample`, 004's interpolation).
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.io.csv_layout import Table, guess_columns, read_table, sniff
from margtrack.io.mapped import build_recording
from margtrack.recording import Recording, resample
from margtrack.units import UNITS, convert_unit

Array = NDArray[np.float64]

__all__ = ["phone_columns", "read_sensor_files", "sensor_files"]

# file-name stems (lower case, no spaces/underscores) -> the sensor a file holds
_STEMS = {
    "gyr": ("gyroscope", "gyro", "gyr", "rotationrate", "gyroscopeuncalibrated"),
    "acc": ("totalacceleration", "accelerometer", "acceleration", "accel", "acc",
            "accelerometeruncalibrated"),
    "gravity": ("gravity",),
    "mag": ("magnetometer", "magneticfield", "magnetic", "mag", "magnetometeruncalibrated"),
}
_PHYPHOX = {
    "gyr": re.compile(r"^Gyroscope ([xyz]) \((.+)\)$"),
    "acc": re.compile(r"^Acceleration ([xyz]) \((.+)\)$"),
    "mag": re.compile(r"^Magnetic field ([xyz]) \((.+)\)$", re.IGNORECASE),
}
_PHYPHOX_TIME = re.compile(r"^Time \((s|ms)\)$")


def _unit(signal: str, text: str, where: str) -> str:
    """A unit named in a column header, normalised to margtrack's table."""
    unit = text.replace("²", "^2").replace("µ", "u").replace("μ", "u").replace("°/s", "deg/s")
    if unit not in UNITS[signal]:
        raise ValueError(f"{where}: unknown {signal} unit {text!r} in the column name")
    return unit


def phone_columns(header: Sequence[str]) -> tuple[dict[str, list[str]], dict[str, str]] | None:
    """The column map and units of a phyphox table with gyroscope and accelerometer, or None."""
    time = [h for h in header if _PHYPHOX_TIME.match(h)]
    if not time:
        return None
    columns: dict[str, list[str]] = {"t": [time[0]]}
    units = {"time": _PHYPHOX_TIME.match(time[0]).group(1)}  # type: ignore[union-attr]
    for signal, pattern in _PHYPHOX.items():
        axes: dict[str, tuple[str, str]] = {}
        for h in header:
            m = pattern.match(h)
            if m:
                axes.setdefault(m.group(1), (h, m.group(2)))
        if len(axes) == 3:
            columns[signal] = [axes[a][0] for a in "xyz"]
            units[signal] = _unit(signal, axes["x"][1], "phyphox header")
    return (columns, units) if "gyr" in columns and "acc" in columns else None


def _kind(path: Path) -> str | None:
    stem = re.sub(r"[\s_\-]+", "", path.stem.lower())
    for kind, stems in _STEMS.items():
        if stem in stems:
            return kind
    return None


def sensor_files(folder: Path) -> dict[str, Path]:
    """The per-sensor files of ``folder`` by sensor (gyr, acc, gravity, mag), best first.

    A calibrated file wins over an uncalibrated one, ``TotalAcceleration`` over
    ``Accelerometer`` (which Sensor Logger writes without gravity).
    """
    found: dict[str, list[Path]] = {}
    for p in sorted(folder.iterdir()):
        if p.is_file() and p.suffix.lower() in (".csv", ".tsv", ".txt"):
            kind = _kind(p)
            if kind is not None:
                found.setdefault(kind, []).append(p)
    out = {}
    for kind, paths in found.items():
        order = _STEMS[kind]
        out[kind] = min(paths, key=lambda q: order.index(re.sub(r"[\s_\-]+", "",
                                                                  q.stem.lower())))
    return out


def _is_sensor_logger(header: Sequence[str]) -> bool:
    return {"time", "seconds_elapsed", "x", "y", "z"} <= set(header)


def _stream(path: Path, signal: str, declared: dict[str, str | None],
            delimiter: str | None, decimal: str | None) -> tuple[Array, Array, dict[str, Any]]:
    """One per-sensor file: (t s, values (M, 3) in SI, what was read)."""
    table: Table = sniff(path, delimiter, decimal)
    header = table.header
    kind = "generic"
    if _is_sensor_logger(header):
        kind, names, units = "sensor-logger", ["time", "x", "y", "z"], {"time": "ns"}
        units[signal] = {"gyr": "rad/s", "acc": "m/s2", "gravity": "m/s2", "mag": "uT"}[signal]
    else:
        time = [h for h in header if _PHYPHOX_TIME.match(h)]
        pattern = _PHYPHOX.get("acc" if signal == "gravity" else signal)
        axes = {m.group(1): (h, m.group(2)) for h in header
                if pattern is not None and (m := pattern.match(h))}
        if time and len(axes) == 3:
            kind = "phyphox"
            names = [time[0], *(axes[a][0] for a in "xyz")]
            units = {"time": _PHYPHOX_TIME.match(time[0]).group(1),  # type: ignore[union-attr]
                     signal: _unit("acc" if signal == "gravity" else signal, axes["x"][1],
                                   str(path))}
        else:
            lower = {h.lower(): h for h in header}
            t_guess = guess_columns(header).get("t")
            if t_guess is None or not all(a in lower for a in "xyz"):
                raise ValueError(
                    f"{path}: cannot tell its time and x, y, z columns; the file has columns "
                    f"{header}; a per-sensor file needs a time column (time, timestamp, t...) "
                    "and columns x, y, z"
                )
            names = [t_guess[0], lower["x"], lower["y"], lower["z"]]
            units = {"time": declared.get("time") or "s",
                     signal: declared.get("acc" if signal == "gravity" else signal)
                     or {"gyr": "rad/s", "acc": "m/s2", "gravity": "m/s2", "mag": "uT"}[signal]}
    try:
        values, lines, dropped = read_table(table, names)
    except KeyError as exc:
        raise ValueError(f"{path}: no column {exc.args[0]!r}; it has {header}") from None
    t = convert_unit(values[:, 0], "time", units["time"])
    xyz = convert_unit(values[:, 1:], "acc" if signal == "gravity" else signal, units[signal])
    keep = np.isfinite(t) & np.isfinite(xyz).all(axis=1)
    info: dict[str, Any] = {"file": path.name, "layout": kind, "units": units}
    if dropped is not None:
        info["dropped_lines"] = [int(dropped)]
    if not keep.all():
        info["rows_with_holes"] = int((~keep).sum())
        warnings.warn(
            f"{path}: {int((~keep).sum())} row(s) with an empty or non-finite value, first on "
            f"line {int(lines[np.argmin(keep)])}; left out (the neighbours are interpolated)",
            UserWarning, stacklevel=3,
        )
        t, xyz, lines = t[keep], xyz[keep], lines[keep]
    # exact repeats of a row (loggers re-send buffered samples) are dropped; a timestamp
    # that repeats with other values or goes back is an error naming the lines
    steps = np.diff(t)
    same = np.flatnonzero((steps == 0.0) & (np.diff(xyz, axis=0) == 0.0).all(axis=1)) + 1
    if same.size:
        info["repeated_rows_dropped"] = int(same.size)
        mask = np.ones(t.shape[0], bool)
        mask[same] = False
        t, xyz, lines = t[mask], xyz[mask], lines[mask]
        steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0.0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(
            f"{path}: the timestamp on line {int(lines[i])} ({t[i]!r} s) is not after the one "
            f"on line {int(lines[i - 1])} ({t[i - 1]!r} s); timestamps must increase: sort the "
            "file or fix the logger's clock"
        )
    return t, xyz, info


def _platform(folder: Path | None) -> str | None:
    """``platform`` (ios / android) from a Sensor Logger ``Metadata.csv``, if there is one."""
    if folder is None:
        return None
    for name in ("Metadata.csv", "metadata.csv"):
        p = folder / name
        if p.is_file():
            table = sniff(p)
            if "platform" in table.header:
                for line in p.read_text(encoding="utf-8-sig").splitlines()[table.skip:]:
                    fields = table.split(line)
                    if len(fields) == len(table.header):
                        return fields[table.header.index("platform")].lower()
    return None


def read_sensor_files(
    paths: Sequence[str | Path] | str | Path,
    *,
    gyr_unit: str | None = None,
    acc_unit: str | None = None,
    mag_unit: str | None = None,
    time_unit: str | None = None,
    delimiter: str | None = None,
    decimal: str | None = None,
    name: str | None = None,
    frame: str = "ENU",
) -> Recording:
    """One Recording from per-sensor files (or the folder holding them), on the gyro's clock.

    Parameters
    ----------
    paths : a folder (its files are sorted out by name, :func:`sensor_files`) or a list of
        files named after their sensor (``Gyroscope.csv``, ``acc.csv``...). A gyroscope and
        an accelerometer (or Sensor Logger's ``Accelerometer`` + ``Gravity``) are needed.
    gyr_unit, acc_unit, mag_unit, time_unit : the units of files whose layout does not
        state them (Sensor Logger and phyphox files do); default rad/s, m/s², µT, s.
    delimiter, decimal : forced table layout (detected by default).

    Returns
    -------
    Recording on the gyroscope's timestamps (s), the others interpolated linearly onto them;
    ``meta["sensor_files"]`` says what was read from each file.
    """
    folder: Path | None = None
    if isinstance(paths, str | Path) and Path(paths).is_dir():
        folder = Path(paths)
        files = sensor_files(folder)
    else:
        items = [Path(paths)] if isinstance(paths, str | Path) else [Path(p) for p in paths]
        files = {}
        for p in items:
            if not p.is_file():
                raise FileNotFoundError(f"no such file: {p}")
            kind = _kind(p)
            if kind is None:
                raise ValueError(
                    f"{p}: cannot tell which sensor this file holds from its name; name it "
                    "after the sensor (Gyroscope.csv, Accelerometer.csv, Magnetometer.csv)"
                )
            if kind in files:
                raise ValueError(f"{p} and {files[kind]} both hold {kind}; give one of them")
            files[kind] = p
        folder = items[0].parent
    where = folder if len(files) != 1 else next(iter(files.values()))
    if "gyr" not in files:
        raise ValueError(
            f"{where}: no gyroscope file (Gyroscope.csv, gyr.csv...); found "
            f"{sorted(p.name for p in files.values())}"
        )
    if "acc" not in files:
        raise ValueError(
            f"{where}: no accelerometer file (Accelerometer.csv, TotalAcceleration.csv...); "
            f"found {sorted(p.name for p in files.values())}"
        )
    declared = {"gyr": gyr_unit, "acc": acc_unit, "mag": mag_unit, "time": time_unit}
    streams = {k: _stream(p, k, declared, delimiter, decimal) for k, p in files.items()}
    t_gyr, gyr, _ = streams["gyr"]
    t_acc, acc, acc_info = streams["acc"]
    meta: dict[str, Any] = {"source": str(where),
                            "sensor_files": {k: s[2] for k, s in streams.items()}}
    if acc_info["layout"] == "sensor-logger" and files["acc"].stem == "Accelerometer":
        if "gravity" not in streams:
            raise ValueError(
                f"{files['acc']} is Sensor Logger's acceleration without gravity; an "
                "orientation needs gravity: export TotalAcceleration (Android) or Gravity too"
            )
        platform = _platform(folder)
        if platform not in ("ios", "android"):
            raise ValueError(
                f"{where}: Sensor Logger's Accelerometer + Gravity have opposite signs on iOS "
                "and Android, and no Metadata.csv says which phone recorded them: keep "
                "Metadata.csv (column platform) in the folder"
            )
        t_grav, grav, _ = streams["gravity"]
        acc = acc + resample(t_grav, grav, t_acc)
        if platform == "ios":  # iOS reports inertial force: gravity points down (-z flat)
            acc = -acc
        meta["acc_from"] = f"Accelerometer + Gravity ({platform})"
    data: dict[str, Array] = {"t": t_gyr, "gyr": gyr, "acc": resample(t_acc, acc, t_gyr)}
    if "mag" in streams:
        t_mag, mag, _ = streams["mag"]
        data["mag"] = resample(t_mag, mag, t_gyr)
    for k in ("acc", "mag"):
        if k in streams:
            t_k = streams[k][0]
            outside = int(np.sum((t_gyr < t_k[0]) | (t_gyr > t_k[-1])))
            if outside:
                meta.setdefault("held_outside_span", {})[k] = outside
    return build_recording(
        str(where), data, {"time": "s"}, frame=frame,
        name=name or (folder.name if folder is not None else files["gyr"].stem), meta=meta,
        check_units=False,
    )
