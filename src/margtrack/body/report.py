"""The printed summary of a body workflow run (plain text, one line per item).

Calibration spread per sensor (largest angle of a pose-window sample from the sensor's
mean, deg: how still the pose was held), the sensors' rates, magnetometers and flags, the
joints ``--no-mag`` constrained with their lever arms (mm ± std), the
range of motion of every joint angle (after the calibration window, or with the online joint
chain from when every joint was found), knee flexion peaks, the
gait cycles per side (:func:`margtrack.body.gait.gait_summary_lines`), the root's path
(start, end, drift and path length over the floor), and the notes (warnings) of
:func:`margtrack.body.workflow.process_body`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from margtrack.body.gait import gait_summary_lines

if TYPE_CHECKING:
    from margtrack.body.workflow import BodyResult

__all__ = ["constrained_lines", "summary_lines"]


def _axis_name(axis: np.ndarray) -> str:
    k = int(np.argmax(np.abs(axis)))
    if np.isclose(abs(axis[k]), 1.0):
        return f"{'-' if axis[k] < 0 else '+'}{'xyz'[k]}"
    return ",".join(f"{v:.3g}" for v in axis)


def _faults_and_states(counts: dict[str, int]) -> str:
    """``"MAG_DISTURBED 12; REST 300"``: the fault flags' counts (``0 faults`` when none),
    then the states' (rest, initialising: normal, not faults)."""
    from margtrack.estimator.flags import STATE_FLAGS, Flag

    states = {k: v for k, v in counts.items() if Flag[k] & STATE_FLAGS}
    faults = ", ".join(f"{k} {v}" for k, v in counts.items() if k not in states) or "0 faults"
    return "; ".join([faults, *(f"{k} {v}" for k, v in states.items())])


def constrained_lines(result: BodyResult) -> list[str]:
    """The joints ``--no-mag`` constrained, with their lever arms (mm ± one std), or none."""
    if not result.constrained:
        return []
    kind = result.constrained[0].method.removeprefix("joint_")
    lines = [f"constrained joints ({kind}; no magnetometer): lever arms joint centre to "
             "sensor, mm ± std, in each sensor's frame (x, y, z)"]
    for j in result.constrained:
        arms = j.lever_arms
        for row, sensor in enumerate((j.parent_sensor, j.child_sensor)):
            xyz = ", ".join(f"{1000 * r:.0f} ± {1000 * s:.0f}" if np.isfinite(s) else
                            f"{1000 * r:.0f}" for r, s in zip(arms.r_m[row], arms.std_m[row],
                                                              strict=True))
            head = f"  {j.joint:<16}" if row == 0 else f"  {'':<16}"
            lines.append(f"{head} {sensor:<18} ({xyz})")
        lines.append(f"  {'':<16} fit residual {arms.residual_m_s2:.2f} m/s² over "
                     f"{arms.samples} samples")
    return lines


def summary_lines(result: BodyResult) -> list[str]:
    """The summary of ``result`` as lines of text (module docstring)."""
    t = result.t_rel_s
    cal = result.calibration
    w = result.window
    lines = [
        f"body: {len(result.sensors)} sensors, {t.size} frames at {result.rate_hz:g} Hz "
        f"({t[-1]:.1f} s), method {result.method}, earth frame {result.skeleton.frame}",
    ]
    if cal.heading == "pelvis" and result.forward_axis is not None:
        facing = (f"heading from the pelvis sensor's {_axis_name(result.forward_axis)} axis: "
                  f"the subject faced {cal.facing_deg:.1f} deg (compass)")
    else:
        facing = "heading: the subject faced magnetic north"
    lines.append(f"calibration on {t[w.start]:.2f}-{t[w.stop - 1]:.2f} s "
                 f"({w.stop - w.start} frames); {facing}")
    lines.append(f"{'sensor':<18} {'segment':<16} {'rate Hz':>7} {'spread deg':>10} "
                 f"{'mag unusable':>12}  faults; states")
    for r, spread in zip(result.sensors, cal.spread_deg, strict=True):
        flags = _faults_and_states(r.flag_counts)
        if r.gap_frames:
            flags += f"; {r.gap_frames} frames across gaps"
        mag = "not used" if result.constrained else f"{100 * r.mag_unusable_share:.0f}%"
        lines.append(f"{r.sensor:<18} {r.segment:<16} {r.rate_hz:7.1f} {spread:10.2f} "
                     f"{mag:>12}  {flags}")
    lines += constrained_lines(result)
    lines.append(f"range of motion from {result.range_from_s:.2f} s (deg):")
    lines.append(f"{'joint':<16} {'component':<18} {'min':>7} {'max':>7} {'range':>7}")
    for joint, comp, lo, hi in result.range_of_motion():
        lines.append(f"{joint:<16} {comp:<18} {lo:7.1f} {hi:7.1f} {hi - lo:7.1f}")
    knees = [j for j in result.angles.names if j.endswith("_knee")]
    if knees:
        lines.append("knee flexion peaks (> 20 deg, >= 0.5 s apart):")
        for joint in knees:
            times, values = result.peaks(joint)
            found = "; ".join(f"{v:.0f} at {s:.1f} s" for s, v in zip(times, values,
                                                                      strict=True))
            lines.append(f"  {joint:<11} {found or 'none'}")
    lines += gait_summary_lines(result.gait)
    if result.root is not None:
        root = result.root
        h = root.position_m[:, :2]  # the horizontal axes of both frames
        axes = "east, north" if root.frame == "ENU" else "north, east"
        lines.append(
            f"{result.skeleton.root} path from the foot contacts ({axes}; m): start "
            f"({h[0, 0]:.2f}, {h[0, 1]:.2f}), end ({h[-1, 0]:.2f}, {h[-1, 1]:.2f}): "
            f"{root.drift_m:.2f} m from the start, {root.path_length_m:.2f} m walked")
        if root.guessed.any():
            lines.append(f"  no foot in stance by the gait events in "
                         f"{100 * root.guessed.mean():.0f} % of the frames: the foot that "
                         "looked planted (lower, turning slower) was the anchor there")
    lines += [f"note: {n}" for n in result.notes]
    return lines
