"""Drawings of body-model results: stick figures, joint-angle curves over time and over the
gait cycle (matplotlib, imported lazily)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.body.gait import SideGait, normalise_cycles
from margtrack.body.joints import JointAngles
from margtrack.body.skeleton import Skeleton, body_axes

Array = NDArray[np.float64]

__all__ = ["bones", "plot_gait_cycles", "plot_joint_angles", "plot_stick_figures"]

_SIDE_COLOURS = {"left": "tab:blue", "right": "tab:red"}


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


def plot_joint_angles(
    path: str | Path,
    t_s: ArrayLike,
    angles: JointAngles,
    window_s: tuple[float, float] | None = None,
    title: str = "",
) -> None:
    """Save a PNG of joint-angle curves: one row per joint kind, one column per component.

    Parameters
    ----------
    path : the PNG to write (written as PNG whatever its extension).
    t_s : (N,) s, the time axis.
    angles : :class:`JointAngles` over N frames; left joints in blue, right in red.
    window_s : (start, end) s of the calibration, shaded grey; None for no shading.
    title : figure title.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(t_s, dtype=np.float64)
    a = np.asarray(angles.angles_rad)
    if a.ndim != 3 or t.shape != (a.shape[0],) or not angles.names:
        raise ValueError(f"need angles over N frames (N, J, 3) with J >= 1 and t_s (N,); "
                         f"got {a.shape} and {t.shape}")
    kinds = list(dict.fromkeys(n.split("_", 1)[1] for n in angles.names))
    height_in = 0.9 + 2.2 * len(kinds)
    fig, axes = plt.subplots(len(kinds), 3, figsize=(12, height_in), sharex=True,
                             squeeze=False)  # fixed margins: a layout engine costs seconds
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.55 / height_in,
                        top=1.0 - 0.6 / height_in, wspace=0.18, hspace=0.35)
    for j, (name, comps) in enumerate(zip(angles.names, angles.components, strict=True)):
        side, kind = name.split("_", 1)
        row = kinds.index(kind)
        for k, comp in enumerate(comps):
            ax = axes[row, k]
            ax.plot(t, np.degrees(a[:, j, k]), color=_SIDE_COLOURS.get(side, "k"), lw=1,
                    label=side)
            ax.set_title(f"{kind} {comp.replace('_', ' ')}", fontsize=9)
    for ax in axes.flat:
        if window_s is not None:
            ax.axvspan(window_s[0], window_s[1], color="0.85", zorder=0)
        ax.grid(alpha=0.3)
    for ax in axes[:, 0]:
        ax.set_ylabel("deg")
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    axes[0, 0].legend(fontsize=8, loc="upper right")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=100, format="png")
    plt.close(fig)


def plot_gait_cycles(
    path: str | Path,
    t_s: ArrayLike,
    angles: JointAngles,
    gait: Mapping[str, SideGait],
    title: str = "",
) -> None:
    """Save a PNG of the leg joint angles over 0-100 % of the gait cycle, mean ± SD per side.

    Each side's joints are normalised over that side's cycles (heel strike to heel strike,
    :func:`margtrack.body.gait.normalise_cycles`); left in blue, right in red, overlaid,
    the mean toe off as a dashed line. A side with fewer than two cycles is left out (its
    :meth:`SideGait.message` says why); ``ValueError`` when no side has two.

    Parameters
    ----------
    path : the PNG to write (written as PNG whatever its extension).
    t_s : (N,) s, the time axis of ``angles`` and of the cycles.
    angles : :class:`JointAngles` over N frames (hip, knee, ankle per side).
    gait : side -> :class:`SideGait` (:func:`margtrack.body.gait.analyse_gait`).
    title : figure title; default one naming the cycles per side.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(t_s, dtype=np.float64)
    a = np.degrees(np.asarray(angles.angles_rad))
    sides = {s: g for s, g in gait.items() if g.n_cycles >= 2}
    legs = [j for j, n in enumerate(angles.names) if n.split("_", 1)[0] in sides
            and n.split("_", 1)[1] in ("hip", "knee", "ankle")]
    if not sides or not legs:
        raise ValueError("no side has two gait cycles with hip, knee or ankle angles: "
                         "nothing to average")
    kinds = [k for k in ("hip", "knee", "ankle")
             if any(angles.names[j].endswith(f"_{k}") for j in legs)]
    height_in = 0.9 + 2.2 * len(kinds)
    fig, axes = plt.subplots(len(kinds), 3, figsize=(12, height_in), sharex=True,
                             squeeze=False)
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.55 / height_in,
                        top=1.0 - 0.6 / height_in, wspace=0.18, hspace=0.35)
    pct = np.linspace(0.0, 100.0, 101)
    for side, g in sides.items():
        cycles = normalise_cycles(t, a, g.start_s, g.end_s, pct.size)  # (C, 101, J, 3)
        mean, sd = cycles.mean(axis=0), cycles.std(axis=0, ddof=1)
        colour = _SIDE_COLOURS.get(side, "k")
        for j in legs:
            name = angles.names[j]
            if not name.startswith(f"{side}_"):
                continue
            kind = name.split("_", 1)[1]
            for k, comp in enumerate(angles.components[j]):
                ax = axes[kinds.index(kind), k]
                ax.fill_between(pct, mean[:, j, k] - sd[:, j, k], mean[:, j, k] + sd[:, j, k],
                                color=colour, alpha=0.2, lw=0)
                ax.plot(pct, mean[:, j, k], color=colour, lw=1.2,
                        label=f"{side} ({g.n_cycles} cycles)")
                ax.axvline(float(g.stance_pct.mean()), color=colour, ls="--", lw=0.8)
                ax.set_title(f"{kind} {comp.replace('_', ' ')}", fontsize=9)
    for ax in axes.flat:
        ax.grid(alpha=0.3)
        ax.set_xlim(0.0, 100.0)
    for ax in axes[:, 0]:
        ax.set_ylabel("deg")
    for ax in axes[-1]:
        ax.set_xlabel("gait cycle (%), heel strike to heel strike")
    axes[0, 0].legend(fontsize=8, loc="upper right")
    fig.suptitle(title or "joint angles over the gait cycle: mean ± SD, toe off dashed")
    fig.savefig(path, dpi=100, format="png")
    plt.close(fig)
