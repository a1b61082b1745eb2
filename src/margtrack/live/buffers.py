"""Reusable batch arrays of the live engine: (S, N, k) blocks kept across batches.

A batch of N frames of S sensors needs C-contiguous (S, N, k) arrays (the compiled
kernels' inputs and outputs, :meth:`~margtrack.estimator.compiled.CompiledEstimator.run_into`).
Allocating them anew for every batch costs the allocation and, for large S, the page
faults of touching fresh memory, as much as a cheap filter's own work. :class:`BatchBuffers`
keeps one flat block per named array, sized for the largest batch so far (grown to the
frames asked or twice its size, whichever is more), and hands out its first S·N·k
elements as a contiguous (S, N, k) view (or (S, N) for k = 0). A view is valid until the
next call for that name with another N; the caller copies what it keeps.

A batch's inputs are copied in one call (:meth:`BatchBuffers.contiguous_all`), shared among
threads over the sensors when the batch is large: the copy of frame-major samples is
bounded by one core's memory traffic (1.27 ms per array of 139,215 sensors x 4 frames on
one thread, 0.72 on two), a quarter of the live engine's time at that scale.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import DTypeLike, NDArray

from margtrack.estimator.sensor_threads import in_threads
from margtrack.live.frames_copy_kernel import frames_to_sensors

__all__ = ["BatchBuffers", "frames_of"]

#: samples (sensors x frames) from which a batch's copies are shared among threads
THREADED_COPY_MIN_SAMPLES = 50_000


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
        as sources deliver them, by :func:`~margtrack.live.frames_copy_kernel.frames_to_sensors`,
        four times numpy's speed)."""
        return self.contiguous_all([(name, values)])[0]

    def contiguous_all(self, items: Sequence[tuple[str, NDArray[np.generic] | None]],
                       n_threads: int = 1) -> list[NDArray[np.generic] | None]:
        """:meth:`contiguous` of each ``(name, values)`` (None stays None); the frame-major
        copies shared among ``n_threads`` threads, each a contiguous part of the sensors,
        when there are at least ``THREADED_COPY_MIN_SAMPLES`` samples per array."""
        outs: list[NDArray[np.generic] | None] = []
        moves: list[tuple[NDArray[np.generic], NDArray[np.generic]]] = []
        for name, values in items:
            dtype = self.layout[name][1]
            if values is None or (values.flags.c_contiguous and values.dtype == dtype):
                outs.append(values)
                continue
            out = self.get(name, values.shape[1])
            frames = frames_of(values)
            if frames is not None and dtype == np.float64:
                moves.append((frames, out))
            else:
                np.copyto(out, values)
            outs.append(out)
        if moves:
            size = moves[0][1].shape[0] * moves[0][1].shape[1]
            _copy_threaded(moves, n_threads if size >= THREADED_COPY_MIN_SAMPLES else 1)
        return outs


def frames_of(values: NDArray[np.generic]) -> NDArray[np.float64] | None:
    """The C-contiguous (N, S, 3) float64 block of which ``values`` (S, N, 3) is the
    swapped view (as sources deliver frames), or None if it is not one."""
    frames = np.swapaxes(values, 0, 1)
    frame_major = values.ndim == 3 and frames.flags.c_contiguous and values.dtype == np.float64
    return frames if frame_major else None


def _copy_threaded(moves: list[tuple[NDArray[np.generic], NDArray[np.generic]]],
                   n_threads: int) -> None:
    """``frames_to_sensors(frames, out)`` of each pair, the sensors split among threads
    (the kernel releases the GIL)."""
    n_sensors = moves[0][1].shape[0]
    edges = [n_sensors * k // n_threads for k in range(n_threads + 1)]

    def part(k: int) -> None:
        a, b = edges[k], edges[k + 1]
        for frames, out in moves:
            frames_to_sensors(frames[:, a:b], out[a:b])

    in_threads(part, n_threads, "margtrack-copy")
