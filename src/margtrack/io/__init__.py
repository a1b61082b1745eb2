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
from margtrack.io.hdf5 import read_hdf5, write_estimate_hdf5, write_hdf5
from margtrack.io.xio import read_xio_body, read_xio_quaternion, read_xio_sensor
from margtrack.recording import Recording

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


def read(path: str | Path, **kw: Any) -> Recording:
    """Read a Recording, choosing the reader from what ``path`` contains.

    Parameters
    ----------
    path : one of
        - a folder with ``Inertial.csv``: an x-IMU3 sensor (:func:`read_xio_sensor`);
        - ``.h5``/``.hdf5`` with a dataset ``imu_gyr``: a BROAD trial (:func:`read_broad`);
        - any other ``.h5``/``.hdf5``: margtrack HDF5 (:func:`read_hdf5`);
        - ``.csv``: margtrack CSV (:func:`read_csv`); another CSV needs ``columns=`` (see
          :func:`read_csv`), which is passed on with the other keywords.
    **kw : keyword arguments for the chosen reader.

    Returns
    -------
    The Recording, in SI units (t s, gyr rad/s, acc m/s²).
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"no such file or folder: {p}")
    if p.is_dir():
        if (p / "Inertial.csv").is_file():
            return read_xio_sensor(p, **kw)
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
        return read_broad(p, **kw) if is_broad else read_hdf5(p, **kw)
    if suffix in CSV_SUFFIXES:
        if "columns" in kw or is_margtrack_csv(p):
            return read_csv(p, **kw)
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


def read_any(path: str | Path) -> list[Recording]:
    """Every recording at ``path``: one file, a folder of BROAD trials, or an x-IMU3 body.

    A folder of ``.hdf5`` trials gives them all in name order, a folder of x-IMU3 sensor
    folders gives each sensor (sorted by folder name); anything else is :func:`read`.
    """
    p = Path(path)
    if p.is_dir() and not (p / "Inertial.csv").is_file():
        trials = sorted(p.glob("*.hdf5"))
        if trials:
            return [read(t) for t in trials]
        if any((d / "Inertial.csv").is_file() for d in p.iterdir() if d.is_dir()):
            return list(read_xio_body(p).values())
    return [read(p)]


def write_estimate(estimate: Any, path: str | Path) -> None:
    """Write an Estimate's ``t`` (s) and ``quat`` (and its outputs) to .h5/.hdf5 or .csv.

    HDF5 also stores ``method``, ``frame`` and the parameters as attributes.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in HDF5_SUFFIXES:
        attrs = {
            "method": estimate.method,
            "frame": estimate.frame,
            "params": dict(estimate.params),
        }
        write_estimate_hdf5(p, estimate.t, estimate.quat, dict(estimate.outputs), attrs)
    elif suffix in CSV_SUFFIXES:
        if estimate.quat.ndim != 2:
            raise ValueError("a CSV holds one sensor; write several sensors to HDF5")
        write_estimate_csv(p, estimate.t, estimate.quat, dict(estimate.outputs))
    else:
        raise ValueError(
            f"cannot write {p}: unsupported extension {p.suffix!r}; use one of {_SUPPORTED}"
        )
