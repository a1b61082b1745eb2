"""CSV of joint angles in degrees, one row per frame, units in the column headers.

Header: ``t (s)``, then ``<joint>_<component> (deg)`` for every joint of a
:class:`~margtrack.body.joints.JointAngles` (e.g. ``right_knee_flexion (deg)``), in its
order; comma separated, ``.`` decimal point.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.body._checks import frame_times
from margtrack.body.joints import JointAngles

Array = NDArray[np.float64]

__all__ = ["read_joint_angles_csv", "write_joint_angles_csv"]


def write_joint_angles_csv(path: str | Path, t_s: ArrayLike, angles: JointAngles) -> None:
    """Write joint angles (converted to deg) with their times.

    Parameters
    ----------
    path : the file to create or overwrite.
    t_s : (N,) s, strictly increasing.
    angles : :class:`JointAngles` with ``angles_rad`` of shape (N, J, 3).
    """
    a = np.asarray(angles.angles_rad)
    if a.ndim != 3:
        raise ValueError(f"angles must cover N frames, shape (N, J, 3); got {a.shape}")
    t = frame_times(t_s, a.shape[0])
    header = ",".join(["t (s)", *(f"{c} (deg)" for c in angles.columns())])
    data = np.concatenate([t[:, None], np.degrees(a.reshape(a.shape[0], -1))], axis=1)
    np.savetxt(path, data, fmt="%.10g", delimiter=",", header=header, comments="")


def read_joint_angles_csv(path: str | Path) -> tuple[Array, list[str], Array]:
    """Read a file of :func:`write_joint_angles_csv`: ``t_s`` (N,), column names, (N, C) deg."""
    with open(path, encoding="utf-8") as f:
        header = f.readline().rstrip("\n").split(",")
    if not header or header[0] != "t (s)":
        raise ValueError(f"{path}: first column must be 't (s)', got {header[:1]}")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    names = [h.removesuffix(" (deg)") for h in header[1:]]
    return data[:, 0], names, data[:, 1:]
