"""HDF5 recordings in margtrack's own layout, and the estimates written by ``margtrack run``.

Recording layout (format ``"margtrack-recording"``, version 1), all float64 in SI units:

- datasets ``t`` (N,) s, ``gyr`` (N, 3) rad/s, ``acc`` (N, 3) m/s², optional ``mag`` (N, 3),
  ``quat_true`` (N, 4) ``[w, x, y, z]`` and ``movement`` (N,) bool;
- attributes ``format``, ``version``, ``frame``, ``name`` and ``meta`` (a JSON object string).

Datasets are stored bit for bit, so :func:`write_hdf5` then :func:`read_hdf5` is exact.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import ArrayLike

from margtrack.errors import InputError
from margtrack.io.output_units import output_unit
from margtrack.io.safe_output import atomic_output
from margtrack.recording import Recording
from margtrack.units import UnitError

__all__ = ["read_hdf5", "write_estimate_hdf5", "write_hdf5"]

RECORDING_FORMAT = "margtrack-recording"
ESTIMATE_FORMAT = "margtrack-estimate"
VERSION = 1
_OPTIONAL = ("mag", "quat_true", "movement")


def _existing_file(path: str | Path) -> Path:
    """``path`` as a Path, or ``FileNotFoundError`` naming it."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such file: {p}")
    return p


def _writable(path: str | Path) -> Path:
    """``path`` as a Path whose folder exists, or ``FileNotFoundError`` naming the folder."""
    p = Path(path)
    if not p.parent.is_dir():
        raise FileNotFoundError(f"cannot write {p}: folder {p.parent} does not exist")
    return p


@contextmanager
def _naming_path(path: Path) -> Iterator[None]:
    """Re-raise a ``ValueError`` from the block with ``path`` in front of its message."""
    try:
        yield
    except UnitError as exc:  # keep the type: callers tell unit mix-ups from other errors
        raise exc.prefixed(f"{path}: ") from None
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def meta_to_json(meta: Mapping[str, Any]) -> str:
    """Encode a ``meta`` mapping as one line of JSON (numpy values become Python values)."""
    try:
        return json.dumps(dict(meta), default=_json_default, sort_keys=True)
    except TypeError as exc:
        raise ValueError(
            f"meta cannot be written: {exc}; keep meta to str, numbers, bools, lists and dicts"
        ) from None


def write_hdf5(rec: Recording, path: str | Path) -> None:
    """Write ``rec`` to an HDF5 file in margtrack's layout (exact, all fields kept).

    Parameters
    ----------
    rec : the Recording (t s, gyr rad/s, acc m/s², optional mag, quat_true, movement).
    path : file to create or overwrite; its folder must exist.
    """
    p = _writable(path)
    meta = meta_to_json(rec.meta)  # fail before the file is touched
    with atomic_output(p) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["format"] = RECORDING_FORMAT
        f.attrs["version"] = VERSION
        f.attrs["frame"] = rec.frame
        f.attrs["name"] = rec.name
        f.attrs["meta"] = meta
        f.create_dataset("t", data=rec.t)
        f.create_dataset("gyr", data=rec.gyr)
        f.create_dataset("acc", data=rec.acc)
        for key in _OPTIONAL:
            value = getattr(rec, key)
            if value is not None:
                f.create_dataset(key, data=value)


def read_hdf5(path: str | Path) -> Recording:
    """Read a Recording written by :func:`write_hdf5`.

    Parameters
    ----------
    path : an HDF5 file with ``format="margtrack-recording"``, version 1.

    Returns
    -------
    Recording with t (N,) s, gyr (N, 3) rad/s, acc (N, 3) m/s² and the optional fields,
    frame, name and meta stored in the file.
    """
    p = _existing_file(path)
    with h5py.File(p, "r") as f:
        fmt = f.attrs.get("format")
        if fmt != RECORDING_FORMAT:
            if fmt == "margtrack-estimate":
                fix = "read it with margtrack.io.read_estimate(path)"
                what = "an orientation estimate, not a recording"
            else:
                fix = ("it looks like BROAD: use read_broad" if "imu_gyr" in f else
                       "margtrack.io.read picks the reader of the formats it knows")
                what = f"not a margtrack recording (attribute format is {fmt!r})"
            raise InputError(f"{p} is {what}; {fix}", fix=fix,
                             cli_fix="give a recording (margtrack info FILE says what one holds)")
        version = int(f.attrs.get("version", -1))
        if version != VERSION:
            raise ValueError(
                f"{p} has margtrack recording version {version}; this margtrack reads {VERSION}"
            )
        missing = [k for k in ("t", "gyr", "acc") if k not in f]
        if missing:
            raise ValueError(f"{p} has no dataset {missing[0]!r}; it has {sorted(f.keys())}")
        fields = {k: f[k][()] for k in ("t", "gyr", "acc", *_OPTIONAL) if k in f}
        frame = str(f.attrs.get("frame", ""))
        name = str(f.attrs.get("name", ""))
        meta_text = str(f.attrs.get("meta", "{}"))
    with _naming_path(p):
        meta = json.loads(meta_text)
        return Recording(frame=frame, name=name, meta=meta, **fields)  # type: ignore[arg-type]


def write_estimate_hdf5(
    path: str | Path,
    t: ArrayLike,
    quat: ArrayLike,
    outputs: Mapping[str, ArrayLike] | None = None,
    attrs: Mapping[str, Any] | None = None,
) -> None:
    """Write an orientation estimate: datasets ``t``, ``quat`` and one per output, plus attributes.

    Parameters
    ----------
    path : file to create or overwrite; its folder must exist.
    t : (N,) timestamps, s.
    quat : (N, 4) orientation ``[w, x, y, z]`` of the body in the estimator's earth frame.
    outputs : other per-sample series, name (with its unit, e.g. ``"bias_rad_s"``) to an array
        whose first axis is N; stored as datasets of that name, any shape and dtype.
    attrs : run description (method, parameters, frame...). Str, int, float and bool values
        become HDF5 attributes as they are; anything else is stored as a JSON string and its
        name is listed in the JSON list attribute ``json_attrs``.

    The file also carries ``format="margtrack-estimate"`` and ``version=1``; each dataset
    has a ``unit`` attribute (:mod:`margtrack.io.output_units`).
    """
    p = _writable(path)
    t_arr, q_arr = estimate_arrays(t, quat)
    datasets = estimate_outputs(outputs, t_arr.shape[0])
    plain, as_json = estimate_attrs(attrs)
    with atomic_output(p) as tmp, h5py.File(tmp, "w") as f:
        write_estimate_attrs(f, plain, as_json)
        for name, arr in {"t": t_arr, "quat": q_arr, **datasets}.items():
            f.create_dataset(name, data=arr).attrs["unit"] = output_unit(name, arr.dtype)


def estimate_arrays(t: ArrayLike, quat: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``t`` (N,) and ``quat`` (N, 4) as float64 arrays, shapes checked."""
    t_arr = np.asarray(t, dtype=np.float64)
    q_arr = np.asarray(quat, dtype=np.float64)
    if t_arr.ndim != 1:
        raise ValueError(f"t must have shape (N,), got {t_arr.shape}")
    n = t_arr.shape[0]
    if q_arr.shape != (n, 4):
        raise ValueError(f"quat must have shape ({n}, 4) to match t, got {q_arr.shape}")
    return t_arr, q_arr


def estimate_outputs(outputs: Mapping[str, ArrayLike] | None, n: int) -> dict[str, np.ndarray]:
    """The outputs of an estimate as arrays with first axis ``n``, names checked."""
    datasets: dict[str, np.ndarray] = {}
    for name, value in (outputs or {}).items():
        if name in ("t", "quat") or not name or "/" in name:
            raise ValueError(f"output name {name!r} is reserved or invalid; rename the output")
        arr = np.asarray(value)
        if arr.shape[:1] != (n,):
            raise ValueError(f"output {name!r} has shape {arr.shape}; its first axis must be N={n}")
        datasets[name] = arr
    return datasets


def estimate_attrs(attrs: Mapping[str, Any] | None) -> tuple[dict[str, Any], dict[str, str]]:
    """Split run attributes into plain HDF5 values and JSON strings (see write_estimate_hdf5)."""
    plain: dict[str, Any] = {}
    as_json: dict[str, str] = {}
    for key, value in (attrs or {}).items():
        if key in ("format", "version", "json_attrs"):
            raise ValueError(f"attribute name {key!r} is reserved; rename it")
        if isinstance(value, str | bool | int | float | np.bool_ | np.integer | np.floating):
            plain[key] = value
        else:
            try:
                as_json[key] = json.dumps(value, default=_json_default, sort_keys=True)
            except TypeError as exc:
                raise ValueError(f"attribute {key!r} cannot be written as JSON: {exc}") from None
    return plain, as_json


def write_estimate_attrs(
    f: h5py.File, plain: Mapping[str, Any], as_json: Mapping[str, str]
) -> None:
    """The file attributes of an estimate: format, version, ``json_attrs`` and the run's."""
    f.attrs["format"] = ESTIMATE_FORMAT
    f.attrs["version"] = VERSION
    f.attrs["json_attrs"] = json.dumps(sorted(as_json))
    for key, value in {**plain, **as_json}.items():
        f.attrs[key] = value
