"""Gait events and cycles from the shank (or foot) gyroscope: heel strike, toe off, cycles.

The shank's sagittal angular rate ``ω`` (rad/s, about the segment's medio-lateral axis
pointing to the subject's right: positive while the distal end swings forward,
:func:`sagittal_rate`) has one shape per stride (Aminian et al. 2002; Salarian et al.
2004):

- mid-swing: the large positive peak while the leg swings forward;
- heel strike (initial contact): the negative minimum that follows mid-swing, as the
  swing is stopped and the heel lands;
- toe off (final contact): the negative minimum before mid-swing, as the knee flexes and
  the shank turns backwards in pre-swing.

Detection (:func:`detect_events`): ``ω`` is low-passed without phase shift (Butterworth,
2nd order, forwards and backwards). Mid-swings are the peaks of a strongly smoothed copy
(``swing_cutoff_hz``: one peak per swing) above ``min_swing_rad_s``, at least
``min_stride_s`` apart (:func:`scipy.signal.find_peaks`). The minima are looked for in a
lightly smoothed copy (``event_cutoff_hz``: takes the sensor noise off without moving or
flattening the short heel-strike dip, which a soft last step before standing still shows
only as a small notch): the heel strike is the first local minimum below zero within
``search_s`` after mid-swing, the toe off the last one within ``search_s`` before it (as
Salarian et al. 2004 take the nearest minima on either side of each mid-swing). A swing
whose minimum is missing keeps NaN there.

Cycles (:func:`side_gait`): a cycle runs from a heel strike to the next heel strike of the
same side, when the two swings are consecutive and at most ``max_cycle_s`` apart (a longer
span holds a pause, not a stride); its toe off is that of the second swing.
``stance % = 100 (toe off - start) / (end - start)``; cadence counts two steps per stride,
``120 / (end - start)`` steps/min.

References: K. Aminian, B. Najafi, C. Büla, P.-F. Leyvraz, P. Robert (2002),
"Spatio-temporal parameters of gait measured by an ambulatory system using miniature
gyroscopes", Journal of Biomechanics 35(5): 689-699. A. Salarian, H. Russmann,
F. J. G. Vingerhoets, C. Dehollain, Y. Blanc, P. R. Burkhard, K. Aminian (2004), "Gait
assessment in Parkinson's disease: toward an ambulatory system for long-term monitoring",
IEEE Transactions on Biomedical Engineering 51(8): 1434-1443.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.body._checks import frame_times
from margtrack.body.segments import body_axes, positive
from margtrack.body.skeleton import Skeleton

Array = NDArray[np.float64]

__all__ = ["SIDES", "SideGait", "analyse_gait", "detect_events", "gait_segment",
           "gait_summary_lines", "normalise_cycles", "sagittal_rate", "segment_rates", "side_gait",
           "write_gait_cycles_csv"]

SIDES = ("left", "right")
#: Local minima shallower than this (rad/s, ~6 deg/s) are noise, not events.
_MIN_PROMINENCE_RAD_S = 0.1
#: Fewest samples the zero-phase filter works on (scipy's padding of a 2nd-order section).
_MIN_SAMPLES = 10


def sagittal_rate(gyr_segment_rad_s: ArrayLike, frame: str) -> Array:
    """Angular rate about the segment's medio-lateral axis, rad/s, (N,).

    Parameters
    ----------
    gyr_segment_rad_s : (N, 3) rad/s, the segment's angular rate in its own segment frame
        (a sensor's gyroscope turned by its calibration, ``rotate(q_offset*, gyr)``).
    frame : the skeleton's earth frame, ``"ENU"`` or ``"NED"`` (the segment axes are its
        :func:`body_axes` in the reference pose).

    Positive when the segment's distal end swings forward (hip flexion, the shank in swing).
    """
    gyr = np.asarray(gyr_segment_rad_s, dtype=np.float64)
    if gyr.ndim != 2 or gyr.shape[1] != 3:
        raise ValueError(f"gyr_segment_rad_s must have shape (N, 3), got {gyr.shape}")
    return gyr @ body_axes(frame)[0]


def segment_rates(t_s: ArrayLike, sensor_t_s: Sequence[ArrayLike],
                  gyr_rad_s: Sequence[ArrayLike], q_offset: ArrayLike) -> Array:
    """Every sensor's gyroscope in its segment's frame, on one time base, (N, S, 3) rad/s.

    ``q_segment = q_sensor ⊗ q_offset`` (000, eq. 7), so a sensor rate ``ω`` is
    ``rotate(q_offset*, ω)`` in the segment frame; each sensor is interpolated linearly
    from its own timestamps onto ``t_s`` (inside their span), non-finite samples left out.

    Parameters
    ----------
    t_s : (N,) s, the common time base.
    sensor_t_s, gyr_rad_s : per sensor (M_s,) s and (M_s, 3) rad/s, skeleton order.
    q_offset : (S, 4) the calibration's offsets (:class:`margtrack.body.Calibration`).
    """
    from margtrack import quaternion as quat

    t = np.asarray(t_s, dtype=np.float64)
    offsets = np.asarray(q_offset, dtype=np.float64)
    if len(sensor_t_s) != len(gyr_rad_s) or offsets.shape != (len(gyr_rad_s), 4):
        raise ValueError(f"need one timestamp array, gyroscope and offset per sensor; got "
                         f"{len(sensor_t_s)}, {len(gyr_rad_s)} and {offsets.shape}")
    out = np.empty((t.size, offsets.shape[0], 3))
    for s, (ts, g) in enumerate(zip(sensor_t_s, gyr_rad_s, strict=True)):
        ts, g = np.asarray(ts, dtype=np.float64), np.asarray(g, dtype=np.float64)
        ok = np.isfinite(ts) & np.all(np.isfinite(g), axis=1)
        if np.count_nonzero(ok) < 2:
            raise ValueError(f"sensor {s} has fewer than 2 finite gyroscope samples")
        w = quat.rotate(quat.conjugate(offsets[s]), g[ok])
        out[:, s] = np.stack([np.interp(t, ts[ok], w[:, k]) for k in range(3)], axis=1)
    return out


def _lowpass(x: Array, rate_hz: float, cutoff_hz: float) -> Array:
    from scipy.signal import butter, sosfiltfilt

    if cutoff_hz >= 0.5 * rate_hz:  # nothing above Nyquist to remove
        return x
    return sosfiltfilt(butter(2, cutoff_hz, fs=rate_hz, output="sos"), x)


def detect_events(
    t_s: ArrayLike,
    rate_rad_s: ArrayLike,
    *,
    min_swing_rad_s: float = 1.0,
    min_stride_s: float = 0.5,
    search_s: float = 0.5,
    swing_cutoff_hz: float = 3.0,
    event_cutoff_hz: float = 20.0,
) -> tuple[Array, Array, Array]:
    """Mid-swings, heel strikes and toe offs of one leg (module docstring).

    Parameters
    ----------
    t_s : (N,) s, strictly increasing and evenly spaced (one common time base).
    rate_rad_s : (N,) rad/s, the shank's (or foot's) sagittal angular rate
        (:func:`sagittal_rate`), positive while the leg swings forward.
    min_swing_rad_s : smallest mid-swing peak, rad/s (1 rad/s = 57 deg/s; walking swings
        peak at 3-6 rad/s); raising it ignores small shuffling steps.
    min_stride_s : least time between two mid-swings of one leg, s.
    search_s : how far before and after mid-swing the toe off and heel strike are looked
        for, s (about a swing's length).
    swing_cutoff_hz, event_cutoff_hz : low-pass cut-offs, Hz, for the mid-swing peaks and
        for the minima.

    Returns
    -------
    mid_swing_s, heel_strike_s, toe_off_s : (K,) s, one entry per swing; NaN where a swing
    has no minimum on that side.
    """
    from scipy.signal import find_peaks

    w = np.asarray(rate_rad_s, dtype=np.float64)
    if w.ndim != 1:
        raise ValueError(f"rate_rad_s must have shape (N,), got {w.shape}")
    t = frame_times(t_s, w.size)
    if not np.all(np.isfinite(w)):
        raise ValueError(f"rate_rad_s has a non-finite value at sample "
                         f"{int(np.argmin(np.isfinite(w)))}; drop or fill those samples first")
    for name, value in (("min_swing_rad_s", min_swing_rad_s), ("min_stride_s", min_stride_s),
                        ("search_s", search_s), ("swing_cutoff_hz", swing_cutoff_hz),
                        ("event_cutoff_hz", event_cutoff_hz)):
        positive(value, name)
    empty = (np.empty(0), np.empty(0), np.empty(0))
    if w.size < _MIN_SAMPLES:
        return empty
    dt = np.diff(t)
    step = float(np.median(dt))
    if np.max(np.abs(dt - step)) > 0.1 * step:
        i = int(np.argmax(np.abs(dt - step)))
        raise ValueError(f"t_s must be evenly spaced (one time base): step {dt[i]:.6g} s at "
                         f"sample {i + 1}, median {step:.6g} s; resample first")
    rate_hz = 1.0 / step
    smooth = _lowpass(w, rate_hz, swing_cutoff_hz)
    fine = _lowpass(w, rate_hz, event_cutoff_hz)
    swings, _ = find_peaks(smooth, height=min_swing_rad_s,
                           distance=max(1, round(min_stride_s * rate_hz)))
    minima, _ = find_peaks(-fine, height=0.0, prominence=_MIN_PROMINENCE_RAD_S)
    t_min = t[minima]
    mid = t[swings]
    heel = np.full(mid.size, np.nan)
    toe = np.full(mid.size, np.nan)
    for k, ms in enumerate(mid):
        after = t_min[(t_min > ms) & (t_min <= ms + search_s)]
        before = t_min[(t_min < ms) & (t_min >= ms - search_s)]
        if after.size:
            heel[k] = after[0]
        if before.size:
            toe[k] = before[-1]
    return mid, heel, toe


@dataclass(frozen=True, eq=False)
class SideGait:
    """Gait events and cycles of one leg (module docstring); times in s of the input clock.

    Attributes
    ----------
    side : ``"left"`` or ``"right"``.
    segment : the segment whose gyroscope gave the events (``left_shank``...).
    mid_swing_s, heel_strike_s, toe_off_s : (K,) s, one entry per swing, NaN where missing.
    start_s, end_s, cycle_toe_off_s : (C,) s, each cycle's heel strikes and toe off.
    """

    side: str
    segment: str
    mid_swing_s: Array
    heel_strike_s: Array
    toe_off_s: Array
    start_s: Array
    end_s: Array
    cycle_toe_off_s: Array

    @property
    def n_cycles(self) -> int:
        """Number of complete cycles (heel strike to heel strike)."""
        return int(self.start_s.size)

    @property
    def duration_s(self) -> Array:
        """(C,) s, stride time of each cycle."""
        return self.end_s - self.start_s

    @property
    def stance_pct(self) -> Array:
        """(C,) %, stance (heel strike to toe off) as a share of each cycle."""
        return 100.0 * (self.cycle_toe_off_s - self.start_s) / self.duration_s

    @property
    def cadence_steps_min(self) -> Array:
        """(C,) steps/min of each cycle (two steps per stride)."""
        return 120.0 / self.duration_s

    def message(self) -> str | None:
        """A plain sentence when the side has fewer than two cycles (no mean ± SD), else None."""
        if self.n_cycles >= 2:
            return None
        return (f"{self.side}: {self.n_cycles} gait cycle{'s' if self.n_cycles != 1 else ''} "
                f"found ({self.mid_swing_s.size} swings of the {self.segment} gyroscope); "
                "fewer than two, so no cycle average for this side")


def side_gait(side: str, segment: str, t_s: ArrayLike, rate_rad_s: ArrayLike,
              max_cycle_s: float = 2.0, **detect: float) -> SideGait:
    """Events (:func:`detect_events`, keyword arguments ``detect``) and cycles of one leg.

    ``max_cycle_s`` (s) is the longest accepted stride: heel strikes further apart belong
    to two walks with a pause between them, not to one cycle.
    """
    if side not in SIDES:
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    positive(max_cycle_s, "max_cycle_s")
    mid, heel, toe = detect_events(t_s, rate_rad_s, **detect)  # type: ignore[arg-type]
    start, end, off = heel[:-1], heel[1:], toe[1:]
    with np.errstate(invalid="ignore"):
        ok = (np.isfinite(start) & np.isfinite(end) & np.isfinite(off)
              & (start < off) & (off < end) & (end - start <= max_cycle_s))
    return SideGait(side, segment, mid, heel, toe, start[ok], end[ok], off[ok])


def gait_segment(skeleton: Skeleton, side: str) -> str | None:
    """The segment whose gyroscope gives one side's events: the shank, else the foot."""
    for seg in (f"{side}_shank", f"{side}_foot"):
        if seg in skeleton.names:
            return seg
    return None


def analyse_gait(t_s: ArrayLike, skeleton: Skeleton, gyr_segment_rad_s: ArrayLike,
                 **options: float) -> dict[str, SideGait]:
    """Gait of each leg that has a shank or foot sensor (events from its gyroscope).

    Parameters
    ----------
    t_s : (N,) s, evenly spaced.
    skeleton : the body model; its frame gives the segments' medio-lateral axis.
    gyr_segment_rad_s : (N, S, 3) rad/s, every segment's angular rate in its own segment
        frame, skeleton order.
    options : ``max_cycle_s`` and the keyword arguments of :func:`detect_events`.

    Returns
    -------
    side -> :class:`SideGait`, for the sides with a shank or foot (none for an arm).
    """
    gyr = np.asarray(gyr_segment_rad_s, dtype=np.float64)
    if gyr.ndim != 3 or gyr.shape[1:] != (len(skeleton), 3):
        raise ValueError(f"gyr_segment_rad_s must have shape (N, {len(skeleton)}, 3), one "
                         f"rate per segment ({', '.join(skeleton.names)}), got {gyr.shape}")
    out = {}
    for side in SIDES:
        seg = gait_segment(skeleton, side)
        if seg is not None:
            rate = sagittal_rate(gyr[:, skeleton.index(seg)], skeleton.frame)
            out[side] = side_gait(side, seg, t_s, rate, **options)
    return out


def normalise_cycles(t_s: ArrayLike, values: ArrayLike, start_s: ArrayLike, end_s: ArrayLike,
                     n_points: int = 101) -> Array:
    """``values`` over each cycle at ``n_points`` evenly spaced instants from 0 to 100 %.

    Parameters
    ----------
    t_s : (N,) s, strictly increasing.
    values : (N, ...) any signal sampled at ``t_s`` (e.g. joint angles in deg).
    start_s, end_s : (C,) s, the cycles, inside ``[t_s[0], t_s[-1]]``.
    n_points : samples per cycle (101: every whole percent).

    Returns
    -------
    (C, n_points, ...) linearly interpolated.
    """
    v = np.asarray(values, dtype=np.float64)
    t = frame_times(t_s, v.shape[0] if v.ndim else -1)
    start, end = np.atleast_1d(np.asarray(start_s, float)), np.atleast_1d(np.asarray(end_s, float))
    if start.shape != end.shape or start.ndim != 1 or np.any(~(start < end)):
        raise ValueError("start_s and end_s must be (C,) with start < end in every cycle")
    if start.size and (start.min() < t[0] or end.max() > t[-1]):
        raise ValueError(f"cycles span {start.min():g}-{end.max():g} s, outside the samples' "
                         f"{t[0]:g}-{t[-1]:g} s")
    if int(n_points) < 2:
        raise ValueError(f"n_points must be >= 2, got {n_points}")
    frac = np.linspace(0.0, 1.0, int(n_points))
    flat = v.reshape(v.shape[0], -1)
    out = np.empty((start.size, frac.size, flat.shape[1]))
    for c, (a, b) in enumerate(zip(start, end, strict=True)):
        ti = a + frac * (b - a)
        for k in range(flat.shape[1]):
            out[c, :, k] = np.interp(ti, t, flat[:, k])
    return out.reshape(start.size, frac.size, *v.shape[1:])


def write_gait_cycles_csv(path: str | Path, sides: Mapping[str, SideGait]) -> None:
    """One row per cycle: side, cycle, start, toe off and end (s), stance %, cadence."""
    lines = ["side,cycle,start (s),toe_off (s),end (s),duration (s),stance (%),"
             "cadence (steps/min)"]
    for side, g in sides.items():
        for c in range(g.n_cycles):
            lines.append(f"{side},{c + 1},{g.start_s[c]:.4f},{g.cycle_toe_off_s[c]:.4f},"
                         f"{g.end_s[c]:.4f},{g.duration_s[c]:.4f},{g.stance_pct[c]:.2f},"
                         f"{g.cadence_steps_min[c]:.2f}")
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def _mean_sd(x: Array) -> str:
    return f"{x.mean():.1f} ± {x.std(ddof=1):.1f}" if x.size > 1 else f"{x.mean():.1f}"


def gait_summary_lines(sides: Mapping[str, SideGait]) -> Sequence[str]:
    """Cycles, cadence and stance per side (mean ± SD over cycles), or why there are none."""
    if not sides:
        return ["gait: no shank or foot sensor, so no gait events"]
    lines = ["gait cycles (heel strike to heel strike, from the gyroscope; Aminian 2002, "
             "Salarian 2004):"]
    for side, g in sides.items():
        if g.n_cycles == 0:
            lines.append(f"  {side:<6} 0 cycles ({g.mid_swing_s.size} swings of "
                         f"{g.segment})")
            continue
        lines.append(f"  {side:<6} {g.n_cycles} cycle{'s' if g.n_cycles > 1 else ''} "
                     f"({g.segment}): stride {_mean_sd(g.duration_s)} s, cadence "
                     f"{_mean_sd(g.cadence_steps_min)} steps/min, stance "
                     f"{_mean_sd(g.stance_pct)} %")
    lines += [f"  {m}" for g in sides.values() if (m := g.message())]
    return lines
