"""A PNG of one orientation estimate: Euler angles, gyro bias, health flags, error vs truth.

Panels, top to bottom, over time in s:

1. ZYX Euler angles ``yaw, pitch, roll`` (deg, 002's sequence, :func:`quaternion.to_euler`)
   of the body in the estimate's earth frame; the truth dashed when there is one;
2. the gyroscope bias estimate ``gyr_bias_rad_s`` in deg/s, when the method has one;
3. the health flags: one band per bit of :class:`margtrack.estimator.Flag`, filled where
   the bit is set, with its sample count;
4. the error against the truth (total, heading, inclination in deg, DESIGN's BROAD
   metrics) with its RMSE over the motion mask, when there is a truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.accuracy import ErrorSeries, error_series
from margtrack.estimator.estimate import Estimate
from margtrack.estimator.flags import Flag
from margtrack.io.safe_output import atomic_output
from margtrack.recording import Recording

Array = NDArray[np.float64]

__all__ = ["EstimatePlot", "aligned_truth", "flag_spans", "plot_estimate"]


@dataclass(frozen=True)
class EstimatePlot:
    """What :func:`plot_estimate` drew: the file and the figures shown in its legends.

    panels : panel titles top to bottom. flag_counts : samples per set flag bit.
    rmse_deg : total/heading/inclination RMSE (deg) over the counted samples, or None.
    """

    path: Path
    panels: tuple[str, ...]
    flag_counts: dict[str, int]
    rmse_deg: dict[str, float] | None


def flag_spans(flags: ArrayLike, bit: int) -> list[tuple[int, int]]:
    """Runs ``[start, stop)`` of consecutive samples whose ``flags`` have ``bit`` set."""
    on = (np.asarray(flags).astype(np.int64) & int(bit)) != 0
    edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def aligned_truth(estimate: Estimate, truth: Recording) -> Recording:
    """``truth`` checked to share the estimate's samples (same N, same times to 1 µs).

    Raises ``ValueError`` naming the first sample where they differ, or when the
    recording has no ``quat_true``.
    """
    if truth.quat_true is None:
        raise ValueError(f"the truth recording {truth.name!r} has no quat_true")
    if truth.n_samples != estimate.n_samples:
        raise ValueError(
            f"the truth has {truth.n_samples} samples, the estimate {estimate.n_samples}: "
            "give the recording the estimate was computed from"
        )
    off = np.abs(truth.t - estimate.t) > 1e-6
    if np.any(off):
        i = int(np.argmax(off))
        raise ValueError(
            f"the truth's time at sample {i} is {float(truth.t[i])!r} s, the estimate's "
            f"{float(estimate.t[i])!r} s: give the recording the estimate was computed from"
        )
    return truth


def _break_wraps(t: Array, deg: Array) -> tuple[Array, Array]:
    """``t`` and angles (N, 3) deg with a NaN row inserted where one jumps by > 180 deg.

    A yaw going from 179 to -179 deg is a small turn; the gap keeps the line from drawing
    a vertical stroke across the panel there.
    """
    jumps = np.flatnonzero(np.any(np.abs(np.diff(deg, axis=0)) > 180.0, axis=1)) + 1
    t_out = np.insert(t.astype(np.float64), jumps, np.nan)
    return t_out, np.insert(deg, jumps, np.nan, axis=0)


def _rmse(errors: ErrorSeries, mask: NDArray[np.bool_]) -> dict[str, float]:
    out = {}
    for key, series in (("total", errors.total_rad), ("heading", errors.heading_rad),
                        ("inclination", errors.inclination_rad)):
        values = series[mask]
        out[key] = float(np.degrees(np.sqrt(np.mean(values * values)))) if values.size else np.nan
    return out


def plot_estimate(
    path: str | Path,
    estimate: Estimate,
    truth: Recording | None = None,
    title: str = "",
) -> EstimatePlot:
    """Save a PNG of ``estimate`` (module docstring) and return what it shows.

    Parameters
    ----------
    path : the PNG to write, atomically (a temporary file renamed into place); an existing
        file is replaced, so check it first (:func:`margtrack.io.safe_output.check_output`).
    estimate : one sensor's estimate, ``quat`` (N, 4) ``[w, x, y, z]`` body to
        ``estimate.frame``; ``outputs["gyr_bias_rad_s"]`` (N, 3) rad/s is drawn when present.
    truth : the recording the estimate was computed from, with ``quat_true`` (any earth
        frame, converted): adds the dashed truth and the error panel. Samples where the
        truth is not finite are left out of the error and its RMSE, as are samples outside
        ``movement`` when the recording has that mask.
    title : figure title (default: method, frame, sample count).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if estimate.quat.ndim != 2:
        raise ValueError(f"plot one sensor's estimate: quat must be (N, 4), got "
                         f"{estimate.quat.shape}")
    t = estimate.t
    euler_deg = np.degrees(quat.to_euler(estimate.quat))
    bias = estimate.outputs.get("gyr_bias_rad_s")
    q_true, true_frame, movement = None, estimate.frame, None
    if truth is not None:
        aligned_truth(estimate, truth)
        q_true = np.asarray(truth.quat_true, dtype=np.float64)
        true_frame, movement = truth.frame, truth.movement
    panels = ["orientation: ZYX Euler angles (deg)"]
    if bias is not None:
        panels.append("gyroscope bias estimate (deg/s)")
    panels.append("health flags")
    if q_true is not None:
        panels.append("error against the truth (deg)")
    heights = [3.0, *([2.0] if bias is not None else []), 1.6]
    heights += [2.2] if q_true is not None else []
    fig, axes = plt.subplots(len(panels), 1, figsize=(11, sum(heights) + 1.0), sharex=True,
                             layout="constrained", gridspec_kw={"height_ratios": heights})
    axes = list(np.atleast_1d(axes))
    ax = axes.pop(0)
    for k, name in enumerate(("yaw", "pitch", "roll")):
        ax.plot(*_break_wraps(t, euler_deg[:, [k]]), color=f"C{k}", lw=1.0, label=name)
    if q_true is not None:
        finite = np.all(np.isfinite(q_true), axis=1)
        shown = np.full_like(q_true, np.nan)
        shown[finite] = frames.convert(q_true[finite], true_frame, estimate.frame)
        true_deg = np.degrees(quat.to_euler(np.where(finite[:, None], shown, [1.0, 0, 0, 0])))
        true_deg[~finite] = np.nan
        for k, name in enumerate(("yaw", "pitch", "roll")):
            ax.plot(*_break_wraps(t, true_deg[:, [k]]), color=f"C{k}", lw=0.8, ls="--",
                    label=f"{name} truth")
    ax.set_ylabel("deg")
    ax.set_title(f"{panels[0]}, body to {estimate.frame}", fontsize=9, loc="left")
    ax.legend(fontsize=7, ncol=6 if q_true is not None else 3, loc="upper right")
    ax.grid(alpha=0.3)
    if bias is not None:
        ax = axes.pop(0)
        for k, axis in enumerate("xyz"):
            ax.plot(t, np.degrees(np.asarray(bias)[:, k]), color=f"C{k}", lw=1.0,
                    label=f"gyr {axis}")
        ax.set_ylabel("deg/s")
        ax.set_title(panels[1] + ", body axes", fontsize=9, loc="left")
        ax.legend(fontsize=7, ncol=3, loc="upper right")
        ax.grid(alpha=0.3)
    counts: dict[str, int] = {}
    ax = axes.pop(0)
    flags = estimate.flags if estimate.flags is not None else np.zeros(t.shape, np.uint16)
    bits = list(Flag)
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2] if t.size > 1 else 1.0))
    for row, bit in enumerate(bits):
        spans = flag_spans(flags, int(bit))
        n = sum(b - a for a, b in spans)
        if n:
            counts[str(bit.name)] = n
        ax.broken_barh([(t[a], t[b - 1] + dt[b - 1] - t[a]) for a, b in spans],
                       (row - 0.4, 0.8), color=f"C{row % 10}")
    ax.set_yticks(range(len(bits)),
                  [f"{b.name} ({counts.get(str(b.name), 0)})" for b in bits], fontsize=7)
    ax.set_ylim(-0.6, len(bits) - 0.4)
    ax.invert_yaxis()
    where = "" if estimate.flags is not None else " (the estimate carries none)"
    ax.set_title(f"health flags, samples set per bit{where}", fontsize=9, loc="left")
    ax.grid(alpha=0.3, axis="x")
    rmse = None
    if q_true is not None:
        ax = axes.pop(0)
        usable = np.all(np.isfinite(q_true), axis=1)
        mask = usable & (movement if movement is not None else True)
        errors = error_series(estimate.quat[usable], q_true[usable], estimate.frame, true_frame)
        full = {k: np.full(t.shape, np.nan) for k in ("total", "heading", "inclination")}
        for key, series in zip(full, (errors.total_rad, errors.heading_rad,
                                      errors.inclination_rad), strict=True):
            full[key][usable] = series
        rmse = _rmse(ErrorSeries(full["total"], full["heading"], full["inclination"]), mask)
        for k, key in enumerate(full):
            ax.plot(t, np.degrees(full[key]), lw=0.9, color=f"C{k}",
                    label=f"{key}: RMSE {rmse[key]:.2f}")
        counted = "movement samples" if movement is not None else "all samples"
        ax.set_title(f"{panels[-1]}; RMSE over {counted} with a truth", fontsize=9, loc="left")
        ax.set_ylabel("deg")
        ax.legend(fontsize=7, ncol=3, loc="upper right")
        ax.grid(alpha=0.3)
    fig.axes[-1].set_xlabel("t (s)")
    fig.suptitle(title or f"{estimate.method or 'estimate'}: {estimate.n_samples} samples, "
                 f"frame {estimate.frame}", fontsize=10)
    out = Path(path)
    try:
        with atomic_output(out) as tmp:
            fig.savefig(tmp, dpi=100, format="png")
    finally:
        plt.close(fig)
    return EstimatePlot(out, tuple(panels), counts, rmse)
