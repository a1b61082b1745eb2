"""Reading and writing recordings: margtrack CSV and HDF5, BROAD trials, x-IMU3 exports.

:func:`read` picks the reader from the content of the path, :func:`write` the writer from
the extension; the format-specific functions are re-exported here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py

from margtrack.io.broad import BroadTrial, broad_trials, read_broad
from margtrack.io.csv import is_margtrack_csv, read_csv, write_csv, write_estimate_csv
from margtrack.io.hdf5 import _naming_path, read_hdf5, write_estimate_hdf5, write_hdf5
from margtrack.io.xio import read_xio_body, read_xio_quaternion, read_xio_sensor
from margtrack.recording import Recording
from margtrack.units import unit_factor

__all__ = [
    "BroadTrial",
    "broad_trials",
    "read",
    "read_any",
    "read_broad",
    "read_csv",
    "read_hdf5",
    "read_xio_body",
    "read_xio_quaternion",
    "read_xio_sensor",
    "write",
    "write_csv",
    "write_estimate",
    "write_estimate_csv",
    "write_estimate_hdf5",
    "write_hdf5",
]

HDF5_SUFFIXES = (".h5", ".hdf5")
CSV_SUFFIXES = (".csv",)
_SUPPORTED = ", ".join((*HDF5_SUFFIXES, *CSV_SUFFIXES))


def read(
    path: str | Path,
    *,
    gyr_unit: str | None = None,
    acc_unit: str | None = None,
    mag_unit: str | None = None,
    time_unit: str | None = None,
    **kw: Any,
) -> Recording:
    """Read a Recording, choosing the reader from what ``path`` contains.

    Parameters
    ----------
    path : one of
        - a folder with ``Inertial.csv``: an x-IMU3 sensor (:func:`read_xio_sensor`);
        - ``.h5``/``.hdf5`` with a dataset ``imu_gyr``: a BROAD trial (:func:`read_broad`);
        - any other ``.h5``/``.hdf5``: margtrack HDF5 (:func:`read_hdf5`);
        - ``.csv``: margtrack CSV (:func:`read_csv`); another CSV needs ``columns=`` (see
          :func:`read_csv`), which is passed on with the other keywords.
    gyr_unit, acc_unit, mag_unit, time_unit : the units the file's raw gyroscope,
        accelerometer, magnetometer and timestamp values are really in (the tables of
        :mod:`margtrack.recording`: "deg/s", "g", "nT", "ms"...); None (default) means the
        format's own units. A declaration describes the raw columns and replaces the
        format's unit, it is never applied on top of a reader's conversion:
        - margtrack HDF5/CSV and BROAD are SI (µT for mag) by construction; a declaration
          says the file breaks that (a logger wrote deg/s into ``gyr``) and the values are
          converted with :meth:`Recording.with_units`;
        - an x-IMU3 folder's columns are deg/s, g and us by their names, and the reader
          converts them; a declaration replaces those defaults (``gyr_unit="deg/s"`` is
          the default itself, converted once, not twice);
        - a mapped CSV (``columns=``) has no units of its own; the declarations go to
          :func:`read_csv` (rad/s, m/s², s and the magnetometer unchanged when undeclared).
        The conversions are recorded in ``meta["units_converted"]``.
    **kw : keyword arguments for the chosen reader.

    Returns
    -------
    The Recording, in SI units (t s, gyr rad/s, acc m/s²; mag µT when declared).

    Magnitudes are not checked here: gyr still in deg/s or acc in g come back as read, and
    the caller (the CLI, an estimator's ``run``) refuses them with the fix on its own path.
    The x-IMU3 and mapped-CSV readers' own checks are switched off for that reason (pass
    ``check_units=True`` to keep them).
    """
    declared = {"gyr_unit": gyr_unit, "acc_unit": acc_unit, "mag_unit": mag_unit,
                "time_unit": time_unit}
    for arg, unit in declared.items():
        if unit is not None:
            unit_factor(arg.removesuffix("_unit"), unit)  # unknown units fail before reading
    given = {k: v for k, v in declared.items() if v is not None}
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"no such file or folder: {p}")
    if p.is_dir():
        if (p / "Inertial.csv").is_file():
            return read_xio_sensor(p, **{"check_units": False, **kw, **given})
        if any((d / "Inertial.csv").is_file() for d in p.iterdir()):
            raise ValueError(
                f"{p} holds several x-IMU3 sensor folders; read them all with "
                "read_xio_body(path) or one with read(path / <sensor>)"
            )
        raise ValueError(f"{p} is a folder without an x-IMU3 Inertial.csv; give a file path")
    suffix = p.suffix.lower()
    if suffix in HDF5_SUFFIXES:
        try:
            with h5py.File(p, "r") as f:
                is_broad = "imu_gyr" in f
        except OSError as exc:
            raise ValueError(f"{p} is not a readable HDF5 file: {exc}") from None
        rec = read_broad(p, **kw) if is_broad else read_hdf5(p, **kw)
        return _declared(rec, p, declared)
    if suffix in CSV_SUFFIXES:
        if "columns" in kw:
            return read_csv(p, **{"check_units": False, **kw, **given})
        if is_margtrack_csv(p):
            return _declared(read_csv(p, **kw), p, declared)
        hint = ""
        if p.name == "Inertial.csv":
            hint = f"; it looks like an x-IMU3 export: use read(r'{p.parent}') on its folder"
        raise ValueError(
            f"{p} is not a margtrack CSV; read it with read_csv(path, columns={{'t': [...], "
            "'gyr': [...], 'acc': [...]}}, gyr_unit=..., acc_unit=..., time_unit=...) "
            f"mapping your column names{hint}"
        )
    raise ValueError(
        f"cannot read {p}: unsupported extension {p.suffix!r}; supported: {_SUPPORTED}"
        " or an x-IMU3 sensor folder"
    )


def _declared(rec: Recording, path: Path, declared: dict[str, str | None]) -> Recording:
    """``rec`` (read from an SI format) converted from the declared units, path in errors."""
    with _naming_path(path):
        return rec.with_units(**{k.removesuffix("_unit"): v for k, v in declared.items()})


def write(rec: Recording, path: str | Path) -> None:
    """Write ``rec`` in the format given by the extension of ``path`` (.h5, .hdf5 or .csv).

    Parameters
    ----------
    rec : the Recording to write; every field is kept and reads back exactly with :func:`read`.
    path : the file to create or overwrite; its folder must exist.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in HDF5_SUFFIXES:
        write_hdf5(rec, p)
    elif suffix in CSV_SUFFIXES:
        write_csv(rec, p)
    else:
        raise ValueError(
            f"cannot write {p}: unsupported extension {p.suffix!r}; use one of {_SUPPORTED}"
        )


def read_any(
    path: str | Path,
    *,
    gyr_unit: str | None = None,
    acc_unit: str | None = None,
    mag_unit: str | None = None,
    time_unit: str | None = None,
) -> list[Recording]:
    """Every recording at ``path``: one file, a folder of BROAD trials, or an x-IMU3 body.

    A folder of ``.hdf5`` trials gives them all in name order, a folder of x-IMU3 sensor
    folders gives each sensor (sorted by folder name); anything else is :func:`read`.
    The declared units apply to every recording, as in :func:`read`.
    """
    units = {"gyr_unit": gyr_unit, "acc_unit": acc_unit, "mag_unit": mag_unit,
             "time_unit": time_unit}
    p = Path(path)
    if p.is_dir() and not (p / "Inertial.csv").is_file():
        trials = sorted(p.glob("*.hdf5"))
        if trials:
            return [read(t, **units) for t in trials]
        if any((d / "Inertial.csv").is_file() for d in p.iterdir() if d.is_dir()):
            return [read(d, **units) for d in sorted(
                d for d in p.iterdir() if (d / "Inertial.csv").is_file()
            )]
    return [read(p, **units)]


def write_estimate(estimate: Any, path: str | Path) -> None:
    """Write an Estimate's ``t`` (s) and ``quat`` (and its outputs) to .h5/.hdf5 or .csv.

    The health flags go with them (dataset or column ``flags``, bits of
    :class:`margtrack.estimator.Flag`). HDF5 also stores ``method``, ``frame``, the
    parameters and the flag bits (``flag_bits``) as attributes.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    outputs = dict(estimate.outputs)
    flags = getattr(estimate, "flags", None)
    if flags is not None:
        outputs["flags"] = flags
    if suffix in HDF5_SUFFIXES:
        from margtrack.estimator.flags import Flag

        attrs = {
            "method": estimate.method,
            "frame": estimate.frame,
            "params": dict(estimate.params),
            "flag_bits": {str(f.name): int(f) for f in Flag},
        }
        write_estimate_hdf5(p, estimate.t, estimate.quat, outputs, attrs)
    elif suffix in CSV_SUFFIXES:
        if estimate.quat.ndim != 2:
            raise ValueError("a CSV holds one sensor; write several sensors to HDF5")
        write_estimate_csv(p, estimate.t, estimate.quat, outputs)
    else:
        raise ValueError(
            f"cannot write {p}: unsupported extension {p.suffix!r}; use one of {_SUPPORTED}"
        )
