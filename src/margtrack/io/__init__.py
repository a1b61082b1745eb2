"""Reading and writing recordings: margtrack CSV and HDF5, BROAD trials, x-IMU3 exports,
any delimited table through a column map, phone loggers, per-sensor files, DataFrames.

:func:`read` picks the reader from the content of the path, :func:`write` the writer from
the extension; the format-specific functions are re-exported here, and so are
:func:`read_estimate` / :func:`is_estimate_file` for the estimate files ``margtrack run``
writes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from margtrack.errors import InputError, NoRecordingError
from margtrack.lazy import lazy_names
from margtrack.recording import Recording
from margtrack.units import unit_factor

#: re-exported name -> its module: loaded on first use, so reading one format loads no other
_WHERE = {
    "BroadTrial": "broad",
    "broad_trials": "broad",
    "read_broad": "broad",
    "is_margtrack_csv": "csv",
    "read_csv": "csv",
    "write_csv": "csv",
    "write_estimate_csv": "csv",
    "from_dataframe": "dataframe",
    "EstimateFile": "estimate_reader",
    "is_estimate_file": "estimate_reader",
    "read_estimate": "estimate_reader",
    "read_hdf5": "hdf5",
    "write_estimate_hdf5": "hdf5",
    "write_hdf5": "hdf5",
    "LIVE_FORMAT": "live_hdf5",
    "is_live_recording": "live_hdf5",
    "read_live_recording": "live_hdf5",
    "write_live_recording": "live_hdf5",
    "flag_invalid": "mapped",
    "read_sensor_files": "phone",
    "load_profile": "profile",
    "merge_profile": "profile",
    "read_xio_body": "xio",
    "read_xio_quaternion": "xio",
    "read_xio_sensor": "xio",
}


__all__ = [
    "BroadTrial",
    "EstimateFile",
    "broad_trials",
    "flag_invalid",
    "from_dataframe",
    "is_estimate_file",
    "load_profile",
    "read",
    "read_any",
    "read_broad",
    "read_csv",
    "read_estimate",
    "read_hdf5",
    "read_live_recording",
    "read_sensor_files",
    "read_xio_body",
    "read_xio_quaternion",
    "read_xio_sensor",
    "write",
    "write_csv",
    "write_estimate",
    "write_estimate_csv",
    "write_estimate_hdf5",
    "write_hdf5",
    "write_live_recording",
]

__getattr__, __dir__ = lazy_names(__name__, _WHERE, eager=__all__)

HDF5_SUFFIXES = (".h5", ".hdf5")
CSV_SUFFIXES = (".csv",)
TABLE_SUFFIXES = (".csv", ".tsv", ".txt")  # read as delimited tables (written: .csv only)
_SUPPORTED = ", ".join((*HDF5_SUFFIXES, *CSV_SUFFIXES))


def read(
    path: str | Path | Sequence[str | Path],
    *,
    gyr_unit: str | None = None,
    acc_unit: str | None = None,
    mag_unit: str | None = None,
    time_unit: str | None = None,
    columns: Mapping[str, Sequence[str] | str] | None = None,
    profile: str | Path | None = None,
    delimiter: str | None = None,
    decimal: str | None = None,
    **kw: Any,
) -> Recording:
    """Read a Recording, choosing the reader from what ``path`` contains.

    Parameters
    ----------
    path : one of
        - a folder with ``Inertial.csv``: an x-IMU3 sensor (:func:`read_xio_sensor`);
        - a folder of per-sensor files (``Gyroscope.csv``, ``Accelerometer.csv``...: Sensor
          Logger, phyphox or any logger writing one file per sensor), or a list of such
          files: merged onto the gyroscope's timestamps (:func:`read_sensor_files`);
        - ``.h5``/``.hdf5`` with a dataset ``imu_gyr``: a BROAD trial (:func:`read_broad`);
        - any other ``.h5``/``.hdf5``: margtrack HDF5 (:func:`read_hdf5`);
        - ``.csv``/``.tsv``/``.txt``: margtrack CSV (:func:`read_csv`), a phyphox table
          with gyroscope and accelerometer (recognised from its header), or any table
          through ``columns``; otherwise the error lists the file's columns and the
          ``--column`` flags (guessed from the names) that map them.
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
    columns : field -> column name(s) of a table (:func:`read_csv`): ``{"t": "time_ms",
        "gyr": ["gx", "gy", "gz"], "acc": "ax,ay,az"}``.
    profile : an import profile (TOML, :mod:`margtrack.io.profile`) with the columns,
        units and layout of a lab's logger; the other arguments win over it.
    delimiter, decimal : the table layout (``";"``, ``"tab"``...; ``","``), detected when
        None.
    **kw : keyword arguments for the chosen reader.

    Returns
    -------
    The Recording, in SI units (t s, gyr rad/s, acc m/s²; mag µT when declared).

    Magnitudes are not checked here: gyr still in deg/s or acc in g come back as read, and
    the caller (the CLI, an estimator's ``run``) refuses them with the fix on its own path.
    The x-IMU3 and mapped-CSV readers' own checks are switched off for that reason (pass
    ``check_units=True`` to keep them).
    """
    if profile is not None:
        from margtrack.io.profile import merge_profile

        settings = merge_profile(profile, {
            "gyr_unit": gyr_unit, "acc_unit": acc_unit, "mag_unit": mag_unit,
            "time_unit": time_unit, "columns": columns, "delimiter": delimiter,
            "decimal": decimal, **{k: kw.pop(k) for k in ("frame", "rate_hz") if k in kw},
        })
        return read(path, **settings, **kw)
    declared = {"gyr_unit": gyr_unit, "acc_unit": acc_unit, "mag_unit": mag_unit,
                "time_unit": time_unit}
    for arg, unit in declared.items():
        if unit is not None:
            unit_factor(arg.removesuffix("_unit"), unit)  # unknown units fail before reading
    given = {k: v for k, v in declared.items() if v is not None}
    layout = {"delimiter": delimiter, "decimal": decimal}
    if not isinstance(path, str | Path):
        if columns is not None:
            raise InputError("columns= maps one table; per-sensor files are mapped by name",
                             fix="columns=", cli_fix="--column")
        from margtrack.io.phone import read_sensor_files

        return read_sensor_files(path, **given, **layout, **kw)
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"no such file or folder: {p}")
    if columns is not None and not (p.is_file() and p.suffix.lower() in TABLE_SUFFIXES):
        raise ValueError(
            f"{p}: a column map (--column / columns=) applies to a CSV/TSV table, not to "
            "this " + ("folder" if p.is_dir() else f"{p.suffix} file") + "; leave it out"
        )
    if p.is_dir():
        if (p / "Inertial.csv").is_file():
            from margtrack.io.xio import read_xio_sensor

            return read_xio_sensor(p, **{"check_units": False, **kw, **given})
        if any((d / "Inertial.csv").is_file() for d in p.iterdir()):
            fix = "read them all with read_xio_body(path) or one with read(path / <sensor>)"
            raise InputError(
                f"{p} holds several x-IMU3 sensor folders; {fix}", fix=fix,
                cli_fix=f"margtrack body {p} -o OUT/ tracks them all as a body, margtrack "
                f"run {p}/<sensor> -o OUT.h5 one sensor",
            )
        from margtrack.io.phone import read_sensor_files, sensor_files

        if "gyr" in sensor_files(p):
            return read_sensor_files(p, **given, **layout, **kw)
        _no_recording(p)
    suffix = p.suffix.lower()
    if suffix in HDF5_SUFFIXES:
        import h5py

        from margtrack.io.broad import read_broad
        from margtrack.io.estimate_reader import ESTIMATE_FORMAT
        from margtrack.io.hdf5 import read_hdf5
        from margtrack.io.live_hdf5 import LIVE_FORMAT

        try:
            with h5py.File(p, "r") as f:
                is_broad = "imu_gyr" in f
                is_live = f.attrs.get("format") == LIVE_FORMAT
                is_estimate = f.attrs.get("format") == ESTIMATE_FORMAT
        except OSError as exc:
            raise ValueError(f"{p} is not a readable HDF5 file: {exc}") from None
        if is_estimate:
            _an_estimate(p)
        if is_live:
            fix = "read them with read_any(path) or read_live_recording(path)"
            raise InputError(
                f"{p} is a live recording of several sensors: {fix}", fix=fix,
                cli_fix=f"margtrack body {p} -o OUT/ tracks them as a body, margtrack live "
                f"--replay {p} replays the session",
            )
        rec = read_broad(p, **kw) if is_broad else read_hdf5(p, **kw)
        return _declared(rec, p, declared)
    if suffix in TABLE_SUFFIXES:
        from margtrack.io.csv import is_margtrack_csv, read_csv
        from margtrack.io.estimate_reader import is_estimate_file

        if is_estimate_file(p):
            _an_estimate(p)
        if columns is not None:
            return read_csv(p, columns, **{"check_units": False, **kw, **given, **layout})
        if is_margtrack_csv(p):
            return _declared(read_csv(p, **kw), p, declared)
        return _read_other_table(p, given, layout, kw)
    raise ValueError(
        f"cannot read {p}: unsupported extension {p.suffix!r}; supported: {_SUPPORTED}, "
        ".tsv, .txt, an x-IMU3 sensor folder or a folder of per-sensor files"
    )


def _read_other_table(
    p: Path, given: dict[str, str], layout: dict[str, str | None], kw: dict[str, Any]
) -> Recording:
    """A table that is not margtrack's: a phone logger's, or an error giving the mapping."""
    from margtrack.io.csv import read_csv
    from margtrack.io.csv_layout import mapping_hint, sniff
    from margtrack.io.phone import phone_columns

    header = sniff(p, **layout).header
    found = phone_columns(header)
    if found is not None:
        cols, units = found
        phone_units = {f"{k}_unit": v for k, v in units.items()}
        rec = read_csv(p, cols, **{"check_units": False, **kw, **phone_units, **given,
                                   **layout})
        return replace(rec, meta={**rec.meta, "layout_name": "phyphox"})
    if p.name == "Inertial.csv":
        fix = f"use read(r'{p.parent}') on its folder"
        raise InputError(f"{p} looks like an x-IMU3 export: {fix}", fix=fix,
                         cli_fix=f"give its folder, {p.parent}")
    if {"time", "seconds_elapsed", "x", "y", "z"} <= set(header) or any(
        h.startswith(("Gyroscope x", "Acceleration x", "Magnetic field x")) for h in header
    ):
        raise ValueError(
            f"{p} is one sensor of a phone logger export (one file per sensor); give the "
            f"folder that holds Gyroscope.csv and the accelerometer file: {p.parent}"
        )
    hint = mapping_hint(header)
    raise InputError(f"{p} is not a margtrack CSV; the file has columns {header}; "
                     + hint.python, fix=hint.python, cli_fix=hint.cli)


def _no_recording(p: Path) -> None:
    """Raise :class:`~margtrack.errors.NoRecordingError`: folder ``p`` is no recording."""
    inside = sorted(q.name for q in p.iterdir()
                    if q.suffix.lower() in (*HDF5_SUFFIXES, *TABLE_SUFFIXES))
    if inside:
        listed = ", ".join(inside[:3]) + (", ..." if len(inside) > 3 else "")
        fix = "read them all with read_any(path), or one with read(path / name)"
        raise NoRecordingError(
            f"{p} is a folder of {len(inside)} recording file(s) ({listed}), not one "
            f"recording; {fix}", fix=fix,
            cli_fix=f"margtrack batch {p} -o OUT/ runs them all, margtrack evaluate {p} "
            f"scores them against their truth, margtrack run {p}/{inside[0]} -o OUT.h5 runs "
            "one",
        )
    raise NoRecordingError(
        f"{p} holds no recording: a folder is read as one recording when it holds an x-IMU3 "
        "export (Inertial.csv) or per-sensor files (Gyroscope.csv, Accelerometer.csv, "
        "Magnetometer.csv); give such a folder or a recording file (.h5, .hdf5, .csv)"
    )


def _an_estimate(p: Path) -> None:
    """Raise :class:`~margtrack.errors.InputError`: ``p`` is an estimate, not a recording."""
    fix = "read it with margtrack.io.read_estimate(path)"
    raise InputError(
        f"{p} is an orientation estimate file, not a recording; {fix}", fix=fix,
        cli_fix=f"margtrack info {p} describes it, margtrack plot {p} --truth RECORDING -o "
        "OUT.png compares it with a recording's truth; run and evaluate take the recording",
    )


def _declared(rec: Recording, path: Path, declared: dict[str, str | None]) -> Recording:
    """``rec`` (read from an SI format) converted from the declared units, path in errors."""
    from margtrack.io.hdf5 import _naming_path

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
        from margtrack.io.hdf5 import write_hdf5

        write_hdf5(rec, p)
    elif suffix in CSV_SUFFIXES:
        from margtrack.io.csv import write_csv

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
    **options: Any,
) -> list[Recording]:
    """Every recording at ``path``: one file, a folder of BROAD trials, or an x-IMU3 body.

    ``options`` (``columns``, ``profile``, ``delimiter``, ``decimal``) go to :func:`read`
    for a single table or a folder of per-sensor files.

    A folder of ``.hdf5`` trials gives them all in name order, a folder of x-IMU3 sensor
    folders gives each sensor (sorted by folder name), a raw live recording
    (:mod:`margtrack.io.live_hdf5`) one Recording per sensor in the source's order;
    anything else is :func:`read`.
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
    from margtrack.io.live_hdf5 import is_live_recording, read_live_recording

    if p.is_file() and p.suffix.lower() in HDF5_SUFFIXES and is_live_recording(p):
        recs = read_live_recording(p).recordings.values()  # one per sensor, source order
        return [_declared(r, p, units) for r in recs]
    return [read(p, **units, **{k: v for k, v in options.items() if v is not None})]


def write_estimate(estimate: Any, path: str | Path) -> None:
    """Write an Estimate's ``t`` (s) and ``quat`` (and its outputs) to .h5/.hdf5 or .csv.

    The health flags go with them (dataset or column ``flags``, bits of
    :class:`margtrack.estimator.Flag`). HDF5 also stores ``method``, ``frame``, the
    parameters and the flag bits (``flag_bits``) as attributes. The file is written to a
    temporary file and renamed into place (an existing file is replaced: check first with
    :func:`margtrack.io.safe_output.check_output`); a long run can be written chunk by
    chunk with :class:`margtrack.io.estimate_writer.EstimateWriter`, which this uses.
    """
    from margtrack.io.estimate_writer import EstimateWriter

    p = Path(path)
    if p.suffix.lower() in CSV_SUFFIXES and estimate.quat.ndim != 2:
        raise ValueError("a CSV holds one sensor; write several sensors to HDF5")
    with EstimateWriter(p) as writer:
        writer.append(estimate)
