"""Validation of orientation arrays given to the body model (private)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.body.skeleton import Skeleton

Array = NDArray[np.float64]

#: Largest accepted deviation of a quaternion's norm from 1. Filters renormalise every step
#: (errors ~1e-15) and the readers scale device quaternions to unit norm; anything further
#: off is not an orientation, and silently normalising it would hide a unit or column mix-up.
UNIT_NORM_TOLERANCE = 1e-6


def sensor_quaternions(q: ArrayLike, skeleton: Skeleton, name: str) -> Array:
    """``q`` as float64 (S, 4) or (N, S, 4), one unit quaternion per segment of ``skeleton``."""
    try:
        arr = np.asarray(q, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array of quaternions [w, x, y, z]") from None
    n_seg = len(skeleton)
    if arr.ndim not in (2, 3) or arr.shape[-1] != 4:
        raise ValueError(
            f"{name} must have shape (S, 4) or (N, S, 4) with S = {n_seg} sensors in the "
            f"skeleton's order ({', '.join(skeleton.names)}), got {arr.shape}"
        )
    if arr.shape[-2] != n_seg:
        raise ValueError(
            f"{name} has {arr.shape[-2]} sensors but the skeleton has {n_seg} segments "
            f"({', '.join(skeleton.names)}); give one quaternion per segment, in that order "
            "(Skeleton.order(names) reorders named sensors)"
        )
    norm = np.linalg.norm(arr, axis=-1)
    bad = ~np.isfinite(norm) | (np.abs(norm - 1.0) > UNIT_NORM_TOLERANCE)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        where = f"frame {idx[0]}, " if arr.ndim == 3 else ""
        raise ValueError(
            f"{name}{list(idx)} ({where}segment {skeleton.names[idx[-1]]}) is not a unit "
            f"quaternion: norm {float(norm[idx])!r}; orientations must have norm 1 within "
            f"{UNIT_NORM_TOLERANCE:g}: normalise them (margtrack.quaternion.normalize) or check "
            "the column order"
        )
    return arr


def frame_times(t_s: ArrayLike, n: int, name: str = "t_s") -> Array:
    """Timestamps (N,) s, finite and strictly increasing, one per frame."""
    try:
        t = np.asarray(t_s, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numeric timestamps in s") from None
    if t.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), one time per frame, got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{name} has a non-finite value at frame {int(np.argmin(np.isfinite(t)))}")
    steps = np.diff(t)
    if np.any(steps <= 0):
        i = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise ValueError(
            f"{name} must be strictly increasing: t[{i - 1}] = {t[i - 1]!r}, t[{i}] = {t[i]!r}"
        )
    return t
