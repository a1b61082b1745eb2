"""Reading a multi-sensor recording: one :class:`~margtrack.recording.Recording` per sensor.

:func:`read_body` accepts

- an x-IMU3 body folder: one sensor folder (with ``Inertial.csv``) per sensor, named after
  it (``../shared/data/xio_lower_body``: ``pelvis/``, ``left_upper_leg/``...);
- a folder of per-sensor files or folders, each read by :func:`margtrack.io.read` and named
  by its file name without extension (``pelvis.h5``, ``imu_7.csv``, ``right_thigh/``);
  hidden files and files with other extensions (the ``body.toml``) are skipped, and so
  are files the map does not list (without a map: files not named after a segment), which
  are not even read (a ``notes.txt`` beside the data);
- a file holding several sensors (the live engine's raw recording, or any file
  :func:`margtrack.io.read_any` reads as several recordings), named by ``Recording.name``.

Sensor names are then matched to segments by :mod:`margtrack.body.mapping`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from margtrack.body.mapping import BodyMap, assign_segments, segment_of
from margtrack.recording import Recording

__all__ = ["SENSOR_SUFFIXES", "read_body"]

#: Extensions of per-sensor files in a folder of sensors.
SENSOR_SUFFIXES = (".csv", ".tsv", ".txt", ".h5", ".hdf5")


_UNIT_KEYS = ("gyr_unit", "acc_unit", "mag_unit", "time_unit")


def _declared(units: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in units.items() if v is not None}


def _units_only(kw: dict[str, Any], what: str) -> dict[str, Any]:
    """``kw`` if it holds unit declarations only; reader options do not apply to ``what``."""
    other = sorted(k for k in kw if k not in _UNIT_KEYS)
    if other:
        raise ValueError(f"{', '.join(other)} (--column, --profile) apply to per-sensor CSV "
                         f"files, not to {what}; leave them out")
    return kw


def read_body(
    path: str | Path,
    mapping: BodyMap | None = None,
    skipped: list[str] | None = None,
    **read_kwargs: Any,
) -> dict[str, Recording]:
    """Every sensor of a multi-sensor recording (module docstring), by sensor name.

    Parameters
    ----------
    path : a folder or a file, as in the module docstring.
    mapping : the sensor -> segment map, if any: in a folder of per-sensor files only the
        files it lists are read.
    skipped : a list that receives one note per per-sensor file left unread.
    **read_kwargs : declared units (``gyr_unit``, ``acc_unit``, ``mag_unit``, ``time_unit``)
        and reader options (e.g. ``columns=`` for CSVs), given to every sensor's reader.

    Returns
    -------
    Recordings in SI units keyed by sensor name, in name order. Magnitudes are not checked
    here (as :func:`margtrack.io.read`); the estimators refuse deg/s and g.
    """
    from margtrack import io

    kw = _declared(read_kwargs)
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"no such file or folder: {p}")
    if p.is_file():
        recs = io.read_any(p, **_units_only(kw, f"{p}"))
        if len(recs) < 2:
            raise ValueError(
                f"{p} holds one sensor ({recs[0].name or 'unnamed'}); the body workflow needs "
                "one sensor per segment: give a folder with one file or folder per sensor, an "
                "x-IMU3 body folder, or a multi-sensor recording"
            )
        names = [r.name for r in recs]
        if len(set(names)) != len(names) or not all(names):
            raise ValueError(f"{p}: its sensors need distinct names, got {names}")
        return dict(sorted(zip(names, recs, strict=True)))
    if (p / "Inertial.csv").is_file():
        raise ValueError(
            f"{p} is one x-IMU3 sensor; give the folder that holds all the sensor folders "
            f"({p.parent})"
        )
    entries = sorted(e for e in p.iterdir() if not e.name.startswith("."))
    xio = [e for e in entries if e.is_dir() and (e / "Inertial.csv").is_file()]
    if xio and len(xio) == sum(e.is_dir() for e in entries):
        return io.read_xio_body(p, **{"check_units": False,
                                      **_units_only(kw, "an x-IMU3 body folder")})
    sensors = [e for e in entries
               if e.is_dir() or (e.is_file() and e.suffix.lower() in SENSOR_SUFFIXES)]
    if not sensors:
        raise ValueError(
            f"{p} holds no sensor recordings; expected x-IMU3 sensor folders (with "
            f"Inertial.csv) or one file per sensor ({', '.join(SENSOR_SUFFIXES)}) named by "
            "segment or listed in the map (--map body.toml)"
        )
    stems = [e.stem if e.is_file() else e.name for e in sensors]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if twice:
        raise ValueError(
            f"{p} has several files for sensor(s) {', '.join(twice)} (e.g. a .csv and a .h5); "
            "keep one file per sensor"
        )
    if mapping is not None:
        assign_segments(stems, mapping)  # every mapped sensor must be there
        wanted = [s in mapping.sensors for s in stems]
        why = "not in the map"
    else:
        wanted = [segment_of(s) is not None for s in stems]
        if not any(wanted):
            assign_segments(stems, None)  # raises: names are not segments, give a map
        why = "not a segment name (list it in a map, --map, to use it)"
    if skipped is not None:
        skipped += [f"{e.name}: {why}, not read" for e, w in zip(sensors, wanted, strict=True)
                    if not w]
    return {stem: io.read(e, **kw)
            for stem, e, w in zip(stems, sensors, wanted, strict=True) if w}
