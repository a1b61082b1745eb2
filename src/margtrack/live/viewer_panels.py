"""What the live page's panels say: status, sensors in body order, joint angles, exports.

Pure functions and small buffers over the engine's snapshots (no viser here), so the text
of every panel is testable without a browser. Times on the page are *session* time: seconds
since the session's first frame (``Pose.session_t_s`` when the engine provides it, else the
pose time minus the first pose's); device clocks stay in recordings.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack import body
from margtrack.live.avatars import Avatars

Array = NDArray[np.float64]

__all__ = [
    "JointTrace",
    "end_notice",
    "export_recording",
    "joint_table",
    "sensor_order",
    "sensor_table",
    "status_text",
    "unique_stem",
]

_MAX_SENSOR_ROWS = 64  # four people of 15 sensors
#: per-sensor counters the engine's health may carry, with their column titles
_OPTIONAL = (("lost", "lost"), ("gaps", "gaps"), ("resyncs", "resyncs"),
             ("faults", "faults"), ("reinitialised", "re-init"), ("late", "late"),
             ("duplicates", "duplicates"), ("bad_time", "bad time"))


def sensor_order(names: Sequence[str], avatars: Avatars | None) -> list[int]:
    """Sensor indices in body order: per person, the skeleton's segment order (pelvis,
    trunk, head, arms, legs); sensors outside a body model keep the source's order."""
    order = [] if avatars is None else [int(i) for i in avatars.index.reshape(-1)]
    return order + [i for i in range(len(names)) if i not in set(order)]


def _column(health: Any, name: str, n: int) -> NDArray[Any] | None:
    """Counter ``name`` per sensor: ``health.counts[name]`` or ``health.<name>``, if any."""
    counts = getattr(health, "counts", None) or {}
    value = counts.get(name, getattr(health, name, None))
    if value is None:
        return None
    arr = np.asarray(value)
    return arr if arr.shape == (n,) else None


def sensor_table(health: Any, order: Sequence[int]) -> str:
    """Markdown table of the sensors' health in ``order``: rate, drops, magnetic norm, and a
    state: ``ok``, or stale and the non-zero loss / gap / resync / flag / re-initialisation
    counters when the engine reports them (``health.stale``, ``health.counts``)."""
    n = len(health.names)
    stale = _column(health, "stale", n)
    extra = [(title, col) for name, title in _OPTIONAL
             if (col := _column(health, name, n)) is not None]
    rows = ["| sensor | Hz | drops | \\|m\\|/\\|m₀\\| | state |", "|---|---|---|---|---|"]
    for i in list(order)[:_MAX_SENSOR_ROWS]:
        ratio = float(health.mag_norm_ratio[i])
        mark = "–" if not math.isfinite(ratio) else ("✓" if health.mag_ok[i] else "✗")
        issues = (["**stale**"] if stale is not None and bool(stale[i]) else []) + [
            f"{title} {int(col[i])}" for title, col in extra if int(col[i])]
        rows.append(f"| {health.names[i]} | {health.rate_hz[i]:.0f} | {int(health.dropped[i])} "
                    f"| {ratio:.2f} {mark} | {' · '.join(issues) or 'ok'} |")
    if n > _MAX_SENSOR_ROWS:
        rows.append(f"| … {n - _MAX_SENSOR_ROWS} more | | {int(health.dropped.sum())} | | |")
    errors = getattr(health, "errors", ()) or ()
    notes = [f"- {health.names[i]}: {errors[i]}" for i in order if i < len(errors) and errors[i]]
    return "\n".join(rows + (["", "last errors:", *notes] if notes else []))


def joint_table(angles: body.JointAngles) -> str:
    """Markdown table of one frame's joint angles in degrees, one row per joint."""
    deg = np.degrees(np.asarray(angles.angles_rad))
    rows = ["| joint | angles (deg) |", "|---|---|"]
    for j, name in enumerate(angles.names):
        parts = [f"{comp.replace('_', ' ')} {round(float(deg[j, c])):+d}"
                 for c, comp in enumerate(angles.components[j])]
        rows.append(f"| {name.replace('_', ' ')} | {' · '.join(parts)} |")
    return "\n".join(rows)


class JointTrace:
    """The last ``window_s`` of joint angles (first component, deg) for the scrolling plot."""

    def __init__(self, window_s: float = 10.0, max_points: int = 600) -> None:
        if not (math.isfinite(window_s) and window_s > 0):
            raise ValueError(f"window_s must be a finite number > 0, got {window_s}")
        self.window_s = float(window_s)
        self._t: deque[float] = deque(maxlen=max_points)
        self._deg: deque[Array] = deque(maxlen=max_points)
        self.names: tuple[str, ...] = ()

    def add(self, session_s: float, angles: body.JointAngles) -> None:
        """Append one frame (session time, s); a time going back (a restart) clears it."""
        if self._t and session_s < self._t[-1]:
            self.clear()
        self.names = tuple(angles.names)
        self._t.append(float(session_s))
        self._deg.append(np.degrees(np.asarray(angles.angles_rad)[:, 0]))
        while self._t and self._t[0] < session_s - self.window_s:
            self._t.popleft()
            self._deg.popleft()

    def clear(self) -> None:
        """Forget every point."""
        self._t.clear()
        self._deg.clear()

    def data(self, joints: Sequence[str]) -> tuple[Array, ...]:
        """(t_s, deg of each of ``joints``) arrays for uPlot; empty arrays before any point."""
        t = np.fromiter(self._t, float, len(self._t))
        if not self._deg:
            return (t, *[np.zeros(0) for _ in joints])
        deg = np.stack(list(self._deg))
        return (t, *[deg[:, self.names.index(j)] if j in self.names else np.full(t.size, np.nan)
                     for j in joints])


def unique_stem(folder: Path, stem: str, suffixes: Sequence[str]) -> str:
    """``stem``, or ``stem_2``, ``stem_3``... so that no ``folder/stem+suffix`` exists yet."""
    candidate, k = stem, 1
    while any((folder / f"{candidate}{s}").exists() for s in suffixes):
        k += 1
        candidate = f"{stem}_{k}"
    return candidate


def export_recording(recording: Any, folder: str | Path, stem: str | None = None,
                     person: int = 0, bvh_unit: str = "cm") -> list[Path]:
    """BVH, joint-angle CSV and OpenSim ``.sto`` of one person of a live recording.

    ``recording`` is what ``Engine.stop_recording()`` returns (``segment_orientations``,
    ``write_bvh``, ``write_joint_angles_csv``, ``t_s``, ``avatars``). The BVH's root walks
    as the live view's did (``root_m``), its lengths in ``bvh_unit`` (cm or m, as
    ``margtrack body --bvh-unit``). Files are new (a
    numbered stem instead of overwriting), each written to a temporary file in ``folder``
    and renamed into place. Returns the absolute paths written.
    """
    from margtrack.io.safe_output import atomic_output

    out = Path(folder).expanduser().resolve()
    out.mkdir(parents=True, exist_ok=True)
    suffixes = (".bvh", "_joints.csv", ".sto")
    stem = unique_stem(out, stem or time.strftime("live_%Y%m%d_%H%M%S"), suffixes)
    paths = [out / f"{stem}{s}" for s in suffixes]
    q_segment = recording.segment_orientations(person)  # raises ValueError without a body
    with atomic_output(paths[0]) as tmp:
        recording.write_bvh(tmp, person, bvh_unit)
    with atomic_output(paths[1]) as tmp:
        recording.write_joint_angles_csv(tmp, person)
    with atomic_output(paths[2]) as tmp:
        body.write_sto(tmp, recording.avatars.skeleton, recording.t_s, q_segment)
    return paths


def _session_text(session_s: float) -> str:
    return f"{session_s:.2f} s" if math.isfinite(session_s) else "-"


def status_text(stats: Any, poses_shown: int, session_s: float, message: str) -> str:
    """The *Status* panel: poses shown, session time (s), latency, drops, calibration, the
    last message and the engine's error (``stats``: :meth:`Engine.stats`)."""
    st = stats
    return (
        f"poses shown: {poses_shown}  \n"
        f"session time {_session_text(session_s)} · {st.frames} frames  \n"
        f"latency p50 {st.latency_p50_s * 1e3:.1f} ms · p95 {st.latency_p95_s * 1e3:.1f} ms"
        f"  \nprocessing {st.processing_s_per_sample * 1e6:.2f} µs/sample · "
        f"dropped {st.dropped_samples} · late frames {st.late_frames}  \n"
        f"calibration: {st.calibration}  \n{message}"
        + (f"  \n**{st.error}**" if st.error else "")
    )


def _cm(vec_m: Sequence[float], std_m: Sequence[float | None]) -> str:
    """``[x, y, z] ± [sx, sy, sz]`` in cm (no ± for given lever arms)."""
    text = "[" + ", ".join(f"{100 * v:.1f}" for v in vec_m) + "]"
    if std_m[0] is None:
        return text
    return text + " ± [" + ", ".join(f"{100 * float(v or 0.0):.1f}" for v in std_m) + "]"


def joints_lines(joints: Sequence[dict[str, Any]]) -> list[str]:
    """Lines for people about the constrained joints of ``--no-mag``
    (:attr:`Engine.joints`): per joint its sensors' lever arms (cm, joint centre to sensor,
    sensor frames; ± one std when estimated) and its state."""
    if not joints:
        return ["no magnetometer: no body model, so no joint constrains a sensor (each one "
                "6-D, its heading free)"]
    lines = [f"no magnetometer: {len(joints)} joints constrained, each segment chained to "
             "its parent (lever arms in cm, joint centre to sensor, sensor frames)"]
    for j in joints:
        who = f"{j['person']}/" if j["person"] else ""
        arms, std = j["lever_arms_m"], j["lever_arms_std_m"]
        if arms is None:
            text = "lever arms: not yet"
        else:
            text = (f"parent {_cm(arms[0], std[0])}, child {_cm(arms[1], std[1])} "
                    f"({j['lever_arms_source']})")
        lines.append(f"- {who}{j['joint']}: {text}; {j['state']}")
    return lines


def end_notice(stats: Any, session_s: float, fatal: str | None, replay: bool,
               again: bool) -> str:
    """The notice shown when the engine has ended: its fatal error, or the end of the
    source (a replay's, with the *Replay again* hint when ``again``)."""
    if fatal:
        return f"**{fatal}**: the page shows its last pose; restart `margtrack live`."
    what = "Replay" if replay else "The source"
    return (f"**{what} ended** at session time {_session_text(session_s)} "
            f"({stats.frames} frames)."
            + (" Press *Replay again*, ticking *Loop replay* to play it in a loop."
               if again else ""))
