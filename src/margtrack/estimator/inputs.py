"""A run's inputs: recordings or arrays, checked and shaped (S, N, 3) for the estimator."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.recording import Recording

Array = NDArray[np.float64]

__all__ = ["Inputs", "recordings", "signal_array"]


@dataclass
class Inputs:
    """A run's validated inputs: t (N,) s; gyr, acc, mag (S, N, 3) float64 contiguous, in
    rad/s, m/s² and any field unit (gyr None for a method without one, mag when absent)."""

    t: Array
    gyr: Array | None
    acc: Array
    mag: Array | None


def recordings(data: object) -> list[Recording]:
    """``data`` as a list of Recordings, or a TypeError saying what to pass instead."""
    if hasattr(data, "columns") and hasattr(data, "iloc"):  # a pandas DataFrame (duck-typed)
        raise TypeError(
            "run() takes a Recording, not a pandas DataFrame: convert it first with "
            "margtrack.io.from_dataframe(df, columns={...}, gyr_unit=..., acc_unit=...)"
        )
    items = list(data) if isinstance(data, Iterable) and not isinstance(data, str) else None
    if items is None or not all(isinstance(r, Recording) for r in items):
        raise TypeError(
            f"run() takes a Recording or a list of Recordings, not {type(data).__name__}; "
            "for arrays use run(gyr=..., acc=..., mag=..., t=...)"
        )
    return items


def signal_array(value: ArrayLike, name: str, like: tuple[int, ...] | None = None) -> Array:
    """(S, N, 3) float64 contiguous; non-finite values are left to the screening."""
    try:
        arr = np.ascontiguousarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    if arr.ndim != 3 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (N, 3) or (S, N, 3), got {arr.shape}")
    if like is not None and arr.shape != like:
        raise ValueError(f"{name} has shape {arr.shape} but acc has {like}")
    return arr
