"""OpenSim ``.sto`` orientation table (the quaternion table OpenSense's IMU tools read).

File layout (OpenSim Storage version 3, as OpenSense writes ``*_orientations.sto``)::

    DataRate=100.000000
    DataType=Quaternion
    version=3
    OpenSimVersion=4.5
    endheader
    time<TAB>pelvis_imu<TAB>femur_r_imu ...
    0.00000000<TAB>w,x,y,z<TAB>w,x,y,z ...

one row per time, one column per segment whose cell is the quaternion ``w,x,y,z`` (scalar
first, comma separated). ``DataRate`` is the median frame rate in Hz.

Axes (``axes="opensim"``, default): OpenSim's ground and body frames are ``X`` forward,
``Y`` up, ``Z`` right. Earth and segment axes are both re-expressed that way:
``q_os = c ⊗ q ⊗ c*`` with ``c`` the rotation taking earth coordinates to (north, up, east),
so a segment in the reference pose facing north is the identity, the default pose of an
OpenSim model, and OpenSense's ``sensor_to_opensim_rotations`` is ``0 0 0``.
``axes="earth"`` writes ``q`` unchanged (earth frame ``skeleton.frame``, margtrack segment
axes).

Column names (``names="opensense"``, default) follow the body names of the OpenSim full-body
models used with OpenSense (Rajagopal 2015): pelvis_imu, torso_imu, head_imu, humerus_r_imu,
radius_r_imu, hand_r_imu, femur_r_imu, tibia_r_imu, calcn_r_imu (``_l_`` on the left);
``names="segment"`` uses margtrack's segment names.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.body._checks import frame_times, sensor_quaternions
from margtrack.body.skeleton import Skeleton, body_axes

Array = NDArray[np.float64]

__all__ = ["OPENSENSE_NAMES", "opensim_axes", "read_sto", "write_sto"]

_BODY = {"upper_arm": "humerus", "forearm": "radius", "hand": "hand",
         "thigh": "femur", "shank": "tibia", "foot": "calcn"}

#: margtrack segment name -> OpenSense IMU column name.
OPENSENSE_NAMES: Mapping[str, str] = MappingProxyType({
    "pelvis": "pelvis_imu", "trunk": "torso_imu", "head": "head_imu",
    **{f"{side}_{seg}": f"{body}_{side[0]}_imu"
       for side in ("left", "right") for seg, body in _BODY.items()},
})


def opensim_axes(frame: str) -> Array:
    """(3, 3) matrix ``C`` with ``v_opensim = C @ v_frame``: rows north (X), up (Y), east (Z)."""
    right, forward, upward = body_axes(frame)
    return np.stack([forward, upward, right])


def write_sto(
    path: str | Path,
    skeleton: Skeleton,
    t_s: ArrayLike,
    q_segment: ArrayLike,
    axes: str = "opensim",
    names: str = "opensense",
) -> None:
    """Write segment orientations as an OpenSim quaternion ``.sto`` table (module docstring).

    Parameters
    ----------
    path : the file to create or overwrite.
    skeleton : the body model (segment names and frame).
    t_s : (N,) s, strictly increasing.
    q_segment : (N, S, 4) segment to earth orientations, skeleton order.
    axes : ``"opensim"`` (X forward, Y up, Z right) or ``"earth"`` (unchanged).
    names : ``"opensense"`` (pelvis_imu, femur_r_imu, ...) or ``"segment"``.
    """
    q = sensor_quaternions(q_segment, skeleton, "q_segment")
    if q.ndim != 3:
        raise ValueError(f"q_segment must have shape (N, S, 4), got {q.shape}")
    t = frame_times(t_s, q.shape[0])
    if axes == "opensim":
        c = quat.from_matrix(opensim_axes(skeleton.frame))
        q = quat.multiply(quat.multiply(c, q), quat.conjugate(c))
    elif axes != "earth":
        raise ValueError(f"axes must be 'opensim' or 'earth', got {axes!r}")
    if names == "opensense":
        labels = [OPENSENSE_NAMES[n] for n in skeleton.names]
    elif names == "segment":
        labels = list(skeleton.names)
    else:
        raise ValueError(f"names must be 'opensense' or 'segment', got {names!r}")
    rate = 1.0 / float(np.median(np.diff(t))) if t.size > 1 else 0.0
    header = [f"DataRate={rate:.6f}", "DataType=Quaternion", "version=3",
              "OpenSimVersion=4.5", "endheader", "\t".join(["time", *labels])]
    cells = np.char.mod("%.10f", q)
    joined = np.char.add(np.char.add(np.char.add(cells[..., 0], ","), cells[..., 1]), ",")
    joined = np.char.add(np.char.add(np.char.add(joined, cells[..., 2]), ","), cells[..., 3])
    rows = [f"{ti:.8f}\t" + "\t".join(r) for ti, r in zip(t, joined.tolist(), strict=True)]
    with open(path, "w", encoding="ascii", newline="\n") as f:
        f.write("\n".join(header + rows) + "\n")


def read_sto(path: str | Path) -> tuple[dict[str, str], list[str], Array, Array]:
    """Read a quaternion ``.sto`` table written by :func:`write_sto` (or OpenSense).

    Returns
    -------
    header : the ``key=value`` lines before ``endheader``.
    labels : the column names after ``time``.
    t_s : (N,) s.
    quat : (N, S, 4) ``[w, x, y, z]`` as stored.
    """
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    try:
        end = next(i for i, line in enumerate(lines) if line.strip() == "endheader")
    except StopIteration:
        raise ValueError(f"{path}: no 'endheader' line; not an OpenSim .sto table") from None
    header = dict(line.split("=", 1) for line in lines[:end] if "=" in line)
    if header.get("DataType") != "Quaternion":
        raise ValueError(f"{path}: DataType is {header.get('DataType')!r}, expected Quaternion")
    columns = lines[end + 1].split("\t")
    if columns[0] != "time":
        raise ValueError(f"{path}: first column must be 'time', got {columns[0]!r}")
    rows = [line.split("\t") for line in lines[end + 2:] if line.strip()]
    t = np.array([float(r[0]) for r in rows])
    q = np.array([[[float(v) for v in cell.split(",")] for cell in r[1:]] for r in rows])
    return header, columns[1:], t, q.reshape(len(rows), len(columns) - 1, 4)
