"""Orientations of a body of x-IMU3 sensors on one time base, ready for the body model.

An x-IMU3 body recording (e.g. ../shared/data/xio_lower_body: pelvis, left/right
upper_leg, lower_leg, foot) holds one folder per sensor, each with the device's own
orientation estimate ``Quaternion.csv`` sampled on its own clock with dropped packets. This
module brings them onto common timestamps (slerp) and into margtrack's earth frame.

The device's earth frame is a setting of the x-IMU3 (NWU, ENU or NED; x-io's default is NWU:
x north, y west, z up). The shipped lower-body recording is NWU: at rest the specific force
rotated to earth is ``+z`` and the magnetic field's horizontal part points along ``+x``
(checked in ``tests/body/test_body_xio.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from margtrack import quaternion as quat
from margtrack.body.kinematics import resample_orientations
from margtrack.frames import check_frame, convert

Array = NDArray[np.float64]

__all__ = ["DEVICE_FRAMES", "from_device_frame", "read_xio_orientations"]

DEVICE_FRAMES = ("NWU", "ENU", "NED")

# NWU coordinates -> ENU coordinates: east = -west, north = north, up = up, i.e. a quarter
# turn about z: rotate(_NWU_TO_ENU, [1, 0, 0]) = [0, 1, 0] (north stays north).
_NWU_TO_ENU = np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])


def from_device_frame(q: Array, device_frame: str, frame: str) -> Array:
    """Orientations ``q`` (..., 4) relative to ``device_frame`` re-expressed in ``frame``."""
    device = str(device_frame).upper()
    if device not in DEVICE_FRAMES:
        raise ValueError(
            f"device_frame must be one of {', '.join(DEVICE_FRAMES)}, got {device_frame!r}"
        )
    target = check_frame(frame)
    if device == "NWU":
        q = quat.multiply(_NWU_TO_ENU, q)
        device = "ENU"
    return convert(q, device, target)


def read_xio_orientations(
    folder: str | Path,
    rate_hz: float,
    device_frame: str = "NWU",
    frame: str = "ENU",
) -> tuple[Array, list[str], Array]:
    """Device orientations of every sensor folder, resampled onto one time base.

    Parameters
    ----------
    folder : an x-IMU3 body recording (a folder of sensor folders with ``Quaternion.csv``).
    rate_hz : output rate, Hz (the shipped recording is sampled at about 50 Hz).
    device_frame : the earth frame the devices were set to (``"NWU"``, x-io's default).
    frame : ``"ENU"`` or ``"NED"``, the earth frame of the result.

    Returns
    -------
    t_s : (N,) s on the devices' clock, from the latest first sample to the earliest last
        sample of all sensors, spaced ``1 / rate_hz``.
    names : sensor folder names, sorted.
    q : (N, S, 4) sensor to earth (``frame``), slerp between each sensor's neighbouring samples.
    """
    from margtrack.io import read_xio_quaternion

    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz}")
    root = Path(folder)
    if not root.is_dir():
        raise FileNotFoundError(f"x-IMU3 body folder {root} does not exist")
    names = sorted(d.name for d in root.iterdir() if (d / "Quaternion.csv").is_file())
    if not names:
        raise FileNotFoundError(f"{root} has no sensor folder with a Quaternion.csv")
    series = [read_xio_quaternion(root / n) for n in names]
    start = max(t[0] for t, _ in series)
    stop = min(t[-1] for t, _ in series)
    if stop - start < 1.0 / rate_hz:
        raise ValueError(f"the sensors of {root} share no common time span")
    t_new = start + np.arange(int(np.floor((stop - start) * rate_hz)) + 1) / rate_hz
    q = np.stack([resample_orientations(t, qs, t_new) for t, qs in series], axis=1)
    return t_new, names, from_device_frame(q, device_frame, frame)
