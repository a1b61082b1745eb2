"""Stick-figure drawings of body-model frames (matplotlib, imported lazily)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.body.skeleton import Skeleton, body_axes

Array = NDArray[np.float64]

__all__ = ["bones", "plot_stick_figures"]


def bones(skeleton: Skeleton, joints_m: Array, ends_m: Array) -> Array:
    """Line segments (..., B, 2, 3) m of a stick figure.

    Every segment is drawn from its joint to its distal end, and every child is joined to its
    parent's distal end (the hips to the pelvis, the shoulders to the neck); zero-length
    lines are kept so the count is fixed.
    """
    parents = skeleton.parents[1:]
    own = np.stack([joints_m, ends_m], axis=-2)
    links = np.stack([ends_m[..., parents, :], joints_m[..., 1:, :]], axis=-2)
    return np.concatenate([own, links], axis=-3)


def plot_stick_figures(
    path: str | Path,
    skeleton: Skeleton,
    joints_m: ArrayLike,
    ends_m: ArrayLike,
    frames: Sequence[int],
    labels: Sequence[str] | None = None,
    heading_quat: ArrayLike | None = None,
    title: str = "",
) -> None:
    """Save a PNG of selected frames seen from the side and from the front, side by side.

    Parameters
    ----------
    path : the PNG to write.
    skeleton : the body model of the positions.
    joints_m, ends_m : (N, S, 3) m, from :func:`margtrack.body.positions`.
    frames : indices of the frames to draw, left to right.
    labels : one label per drawn frame (e.g. the time); default the frame index.
    heading_quat : (4,) the facing rotation of the calibration (``Calibration.heading_quat``):
        the views are taken relative to the direction the subject faced; default north.
    title : figure title.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    joints = np.asarray(joints_m, dtype=np.float64)
    ends = np.asarray(ends_m, dtype=np.float64)
    if joints.ndim != 3 or joints.shape != ends.shape or joints.shape[1:] != (len(skeleton), 3):
        raise ValueError(
            f"joints_m and ends_m must both have shape (N, {len(skeleton)}, 3), "
            f"got {joints.shape} and {ends.shape}"
        )
    idx = [int(i) for i in frames]
    if not idx or min(idx) < -joints.shape[0] or max(idx) >= joints.shape[0]:
        raise ValueError(f"frames must be indices in [0, {joints.shape[0]}), got {list(frames)}")
    labels = [f"frame {i}" for i in idx] if labels is None else list(labels)
    if len(labels) != len(idx):
        raise ValueError(f"need one label per frame: {len(idx)} frames, {len(labels)} labels")
    right, forward, upward = body_axes(skeleton.frame)
    q_h = quat.identity() if heading_quat is None else np.asarray(heading_quat, dtype=float)
    right, forward = quat.rotate(q_h, right), quat.rotate(q_h, forward)
    lines = bones(skeleton, joints, ends)[idx]
    spacing = 1.2 * max(float(np.ptp(lines @ forward)), float(np.ptp(lines @ right)), 0.5)
    fig, axes = plt.subplots(
        2, 1, figsize=(max(6.0, 1.6 * len(idx)), 6.0), sharex=True, layout="constrained"
    )
    for ax, axis, view in ((axes[0], forward, "side view (forward →)"),
                           (axes[1], right, "front view (subject's right →)")):
        for k, (frame_lines, label) in enumerate(zip(lines, labels, strict=True)):
            x = frame_lines @ axis + k * spacing
            y = frame_lines @ upward
            for seg_x, seg_y in zip(x, y, strict=True):
                ax.plot(seg_x, seg_y, color=f"C{k % 10}", lw=2, marker="o", ms=2.5)
            if ax is axes[0]:
                ax.text(k * spacing, float(y.max()) + 0.05, label, ha="center", fontsize=8)
        ax.set_aspect("equal")
        ax.set_ylabel("up (m)")
        ax.set_title(view, fontsize=9)
        ax.grid(alpha=0.3)
    axes[1].set_xlabel("horizontal (m); frames spaced apart")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
