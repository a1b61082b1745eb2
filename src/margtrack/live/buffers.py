"""Reusable batch arrays of the live engine: (S, N, k) blocks kept across batches.

A batch of N frames of S sensors needs C-contiguous (S, N, k) arrays (the compiled
kernels' inputs and outputs, :meth:`~margtrack.estimator.compiled.CompiledEstimator.run_into`).
Allocating them anew for every batch costs the allocation and, for large S, the page
faults of touching fresh memory, as much as a cheap filter's own work. :class:`BatchBuffers`
keeps one flat block per named array, sized for the largest batch so far (grown to the
frames asked or twice its size, whichever is more), and hands out its first S·N·k
elements as a contiguous (S, N, k) view (or (S, N) for k = 0). A view is valid until the
next call for that name with another N; the caller copies what it keeps.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import DTypeLike, NDArray

from margtrack.kernels.frames_copy import frames_to_sensors

__all__ = ["BatchBuffers"]


class BatchBuffers:
    """Named reusable (S, N, k) arrays (module docstring).

    Parameters
    ----------
    n_sensors : S.
    layout : name -> (k, dtype): the width of each array's last axis (0: an (S, N) array).
    """

    def __init__(self, n_sensors: int, layout: Mapping[str, tuple[int, DTypeLike]]) -> None:
        self.n_sensors = int(n_sensors)
        self.layout = {name: (int(k), np.dtype(dtype)) for name, (k, dtype) in layout.items()}
        self._blocks: dict[str, NDArray[np.generic]] = {}
        self._frames: dict[str, int] = {}  # frames each block holds

    def get(self, name: str, n_frames: int) -> NDArray[np.generic]:
        """A C-contiguous (S, n_frames, k) view of block ``name`` (contents undefined)."""
        k, dtype = self.layout[name]
        width = max(k, 1)
        held = self._frames.get(name, 0)
        if held < n_frames:
            held = self._frames[name] = max(n_frames, 2 * held)
            self._blocks[name] = np.empty(self.n_sensors * held * width, dtype=dtype)
        used = self._blocks[name][: self.n_sensors * n_frames * width]
        return used.reshape((self.n_sensors, n_frames, k) if k else (self.n_sensors, n_frames))

    def contiguous(self, name: str, values: NDArray[np.generic]) -> NDArray[np.generic]:
        """``values`` (S, N, k) itself if C-contiguous of the block's dtype, else a copy of it
        in block ``name`` (of frame-major samples, the (S, N, k) view of an (N, S, k) block
        as sources deliver them, by :func:`~margtrack.kernels.frames_copy.frames_to_sensors`,
        four times numpy's speed)."""
        dtype = self.layout[name][1]
        if values.flags.c_contiguous and values.dtype == dtype:
            return values
        out = self.get(name, values.shape[1])
        frames = np.swapaxes(values, 0, 1)
        if values.ndim == 3 and frames.flags.c_contiguous and values.dtype == dtype == np.float64:
            frames_to_sensors(frames, out)
        else:
            np.copyto(out, values)
        return out
