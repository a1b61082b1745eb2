"""BROAD benchmark trials (Laidig et al., Data 6(7), 2021; CC-BY-4.0).

One HDF5 file per trial with datasets ``imu_gyr`` (N, 3) rad/s, ``imu_acc`` (N, 3) m/s²,
``imu_mag`` (N, 3) µT, ``opt_quat`` (N, 4) ``[w, x, y, z]`` optical truth of the IMU frame in
ENU, ``opt_pos`` (N, 3) m (not read), ``movement`` (N,) bool, and attributes
``sampling_rate`` (Hz) and ``info`` (text). A folder of trials has a ``trials.json``
giving each trial's description and groups.

Truth gaps. ``opt_quat`` is NaN wherever the optical system lost the markers (every shipped
trial has such samples, some inside the movement phase). :func:`read_broad` keeps every IMU
sample and makes the truth usable: each NaN truth sample takes the value of the nearest
valid sample (ties go to the earlier one) and its ``movement`` flag is set False, so error
metrics never use a filled-in value. ``meta["truth_nan_samples"]`` counts the filled samples
and ``meta["truth_nan_movement_cleared"]`` how many of them had been movement samples.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from numpy.typing import NDArray

from margtrack.io.hdf5 import _existing_file, _naming_path
from margtrack.recording import Recording

__all__ = ["BroadTrial", "broad_trials", "read_broad"]

_DATASETS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement")


@dataclass(frozen=True)
class BroadTrial:
    """One BROAD trial listed in ``trials.json``.

    Attributes
    ----------
    name : trial name, the file stem (e.g. ``"01_undisturbed_slow_rotation_A"``).
    path : the trial's HDF5 file.
    description : the trial's description from ``trials.json`` ("" if unknown).
    groups : the groups it belongs to (``"all_trials"``, ``"undisturbed"``, ``"fast"``...).
    """

    name: str
    path: Path
    description: str
    groups: tuple[str, ...]


def broad_trials(folder: str | Path) -> list[BroadTrial]:
    """List the BROAD trials present in ``folder``, sorted by name.

    Parameters
    ----------
    folder : a folder holding ``trials.json`` and the trials' ``<name>.hdf5`` files.

    Returns
    -------
    The trials of ``trials.json`` whose file exists. Without ``trials.json`` every ``*.hdf5``
    file is listed with an empty description and ``groups=("all_trials",)``.
    """
    root = Path(folder)
    if not root.is_dir():
        raise FileNotFoundError(f"BROAD folder {root} does not exist")
    index = root / "trials.json"
    if not index.is_file():
        files = sorted(root.glob("*.hdf5"))
        if not files:
            raise FileNotFoundError(
                f"{root} has neither trials.json nor any .hdf5 trial file; "
                "point to the folder holding the BROAD trials"
            )
        return [BroadTrial(f.stem, f, "", ("all_trials",)) for f in files]
    try:
        trials = json.loads(index.read_text(encoding="utf-8"))["trials"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{index} is not a BROAD trials.json (no 'trials'): {exc}") from None
    found = []
    for name in sorted(trials):
        path = root / f"{name}.hdf5"
        if path.is_file():
            entry = trials[name]
            found.append(BroadTrial(
                name, path, str(entry.get("description", "")), tuple(entry.get("groups", ()))
            ))
    return found


def _fill_nearest(q: NDArray[np.float64], bad: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Replace rows ``bad`` by the nearest row that is not (ties: the earlier one)."""
    good = np.flatnonzero(~bad)
    missing = np.flatnonzero(bad)
    right = np.clip(np.searchsorted(good, missing), 0, good.size - 1)
    left = np.clip(right - 1, 0, good.size - 1)
    use_left = np.abs(missing - good[left]) <= np.abs(good[right] - missing)
    out = q.copy()
    out[missing] = q[np.where(use_left, good[left], good[right])]
    return out


def read_broad(path: str | Path) -> Recording:
    """Read one BROAD trial as a Recording with optical truth in ENU.

    Parameters
    ----------
    path : the trial's HDF5 file.

    Returns
    -------
    Recording with t = arange(N) / sampling_rate (s), gyr (N, 3) rad/s, acc (N, 3) m/s²,
    mag (N, 3) µT, quat_true (N, 4) ENU, movement (N,) bool, frame "ENU", name the file
    stem, and meta with ``source``, ``sampling_rate`` (Hz), ``info`` and the truth-gap
    counts (module docstring: NaN truth is filled and excluded from ``movement``).
    """
    p = _existing_file(path)
    with h5py.File(p, "r") as f:
        missing = [k for k in _DATASETS if k not in f]
        if missing:
            raise ValueError(f"{p} is not a BROAD trial: no dataset {missing[0]!r}")
        if "sampling_rate" not in f.attrs:
            raise ValueError(f"{p} is not a BROAD trial: no attribute 'sampling_rate'")
        rate_hz = float(f.attrs["sampling_rate"])
        info = str(f.attrs.get("info", ""))
        gyr, acc, mag = (f[k][()] for k in ("imu_gyr", "imu_acc", "imu_mag"))
        quat = np.asarray(f["opt_quat"][()], dtype=np.float64)
        movement = np.asarray(f["movement"][()], dtype=bool)
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"{p}: sampling_rate must be a finite number > 0, got {rate_hz}")
    if quat.ndim != 2 or quat.shape[1] != 4:
        raise ValueError(f"{p}: opt_quat must have shape (N, 4), got {quat.shape}")
    if movement.shape != (quat.shape[0],):
        raise ValueError(f"{p}: movement must have shape ({quat.shape[0]},), got {movement.shape}")
    nan = ~np.isfinite(quat).all(axis=1)
    if nan.all():
        raise ValueError(f"{p}: opt_quat has no valid sample; this trial has no usable truth")
    meta = {
        "source": str(p),
        "sampling_rate": rate_hz,
        "info": info,
        "units": {"gyr": "rad/s", "acc": "m/s2", "mag": "uT"},
        "truth_nan_samples": int(nan.sum()),
        "truth_nan_movement_cleared": int((nan & movement).sum()),
    }
    if nan.any():
        quat = _fill_nearest(quat, nan)
        movement = movement & ~nan
    with _naming_path(p):
        return Recording(
            t=np.arange(quat.shape[0]) / rate_hz, gyr=gyr, acc=acc, mag=mag, quat_true=quat,
            movement=movement, frame="ENU", name=p.stem, meta=meta,
        )
