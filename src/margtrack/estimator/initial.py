"""The orientation a sensor starts from: measured from one accelerometer (and
magnetometer) sample, and which samples can give it."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.estimator import triad_kernel

Array = NDArray[np.float64]

__all__ = ["initial_orientation", "usable_for_init"]


def initial_orientation(acc: ArrayLike, mag: ArrayLike | None, frame: str) -> Array:
    """Orientation measured from one accelerometer (and magnetometer) sample per sensor.

    acc (S, 3) any units, mag (S, 3) or None; returns (S, 4) body-to-``frame``. With a
    magnetometer this is TRIAD (heading from the horizontal field); without one it is the
    shortest arc taking the measured acceleration to up (heading left as it falls).
    Raises ``ValueError`` for a zero accelerometer vector or one parallel to the field.
    """
    acc = np.ascontiguousarray(acc, dtype=np.float64).reshape(-1, 3)
    up = frames.up(frame)
    norms = np.linalg.norm(acc, axis=1)
    if np.any(~(norms > 0)):
        s = int(np.flatnonzero(~(norms > 0))[0])
        raise ValueError(
            f"cannot initialise sensor {s}: its accelerometer sample is zero; "
            "pass q0 to reset() or drop the leading samples"
        )
    if mag is None:
        return quat.shortest_arc(acc, up)
    mag = np.ascontiguousarray(mag, dtype=np.float64).reshape(-1, 3)
    north = frames.mag_reference(frame, dip_deg=0.0)
    out = np.empty((acc.shape[0], 4))
    flags = np.empty(acc.shape[0], dtype=np.int8)
    triad_kernel.triad(acc, mag, up, north, out, flags)
    if np.any(flags != triad_kernel.OK):
        s = int(np.flatnonzero(flags != triad_kernel.OK)[0])
        why = {
            triad_kernel.ZERO_MAG: "its magnetometer sample is zero",
            triad_kernel.PARALLEL: "its accelerometer and magnetometer are parallel",
        }.get(int(flags[s]), "its sample is degenerate")
        raise ValueError(
            f"cannot initialise sensor {s} from its sample: {why}; "
            "pass q0 to reset() or drop the leading samples"
        )
    return out


def usable_for_init(acc: Array, mag: Array | None) -> NDArray[np.bool_]:
    """(S, N) samples that can initialise: acc non-zero and, with mag, not parallel to it."""
    acc_norm = np.linalg.norm(acc, axis=-1)
    ok = acc_norm > 0
    if mag is not None:
        mag_norm = np.linalg.norm(mag, axis=-1)
        cross = np.linalg.norm(np.cross(acc, mag), axis=-1)
        ok &= cross >= triad_kernel.PARALLEL_SINE * acc_norm * mag_norm * (1 + 1e-9)
        ok &= mag_norm > 0
    return ok
