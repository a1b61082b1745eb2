"""Argument checks shared by the sim modules, with messages naming the argument."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def number(value: float, name: str, above: float | None = None, or_equal: bool = False) -> float:
    """``float(value)``, finite and ``> above`` (``>=`` with ``or_equal``), else ValueError."""
    x = float(value)
    if not np.isfinite(x) or (above is not None and (x < above or (x == above and not or_equal))):
        bound = "" if above is None else f" {'>=' if or_equal else '>'} {above:g}"
        raise ValueError(f"{name} must be a finite number{bound}, got {value!r}")
    return x


def check_seed(seed: int) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    return int(seed)


def unit_axis(axis: ArrayLike, name: str = "axis") -> Array:
    a = np.asarray(axis, dtype=np.float64)
    norm = np.linalg.norm(a) if a.shape == (3,) else 0.0
    if a.shape != (3,) or not (np.isfinite(norm) and norm > 0.0):
        raise ValueError(f"{name} must be a finite non-zero 3-vector, got {axis!r}")
    return a / norm
