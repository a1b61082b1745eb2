"""One time base for several sensors on their own clocks, and their flags carried onto it.

Sensors logged by separate devices (a body's seven x-IMU3s, the two sensors across a joint)
have their own timestamps, rates and starts. :func:`common_time_base` gives the frames every
consumer of several recordings uses (``margtrack body``, ``margtrack joint``): the span
*every* sensor covers, at the slowest sensor's rate rounded to a whole Hz when within 1 %
(so 99.97 Hz and 100.02 Hz devices meet on 100 Hz), starting at the latest first sample.
Signals are then interpolated onto it (:func:`margtrack.recording.resample`, or slerp for
orientations) and :func:`flags_on_time_base` gives each common frame the health flags of
the two sensor samples around it, plus ``GAP`` where it lies inside a sensor's gap.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator.flags import Flag
from margtrack.recording import Recording

Array = NDArray[np.float64]

__all__ = ["common_rate_hz", "common_time_base", "flags_on_time_base"]


def common_rate_hz(recordings: Mapping[str, Recording]) -> float:
    """The slowest recording's rate, rounded to a whole Hz when within 1 % of it, Hz."""
    slowest = min(r.rate_hz for r in recordings.values())
    whole = float(round(slowest))
    return whole if whole > 0 and abs(whole - slowest) <= 0.01 * slowest else slowest


def common_time_base(recordings: Mapping[str, Recording], rate_hz: float | None = None
                     ) -> tuple[Array, list[str]]:
    """Timestamps over the span every recording covers, and notes on what was left out.

    Parameters
    ----------
    recordings : sensor name -> :class:`~margtrack.recording.Recording` (own clocks, s).
    rate_hz : rate of the time base, Hz (default :func:`common_rate_hz`).

    Returns
    -------
    t : (N,) s, ``start + k / rate_hz`` from the latest first sample to the earliest last.
    notes : for people: the sensors that set the span and the seconds each lost (when one
        lost more than 0.5 s), merged rates (when they differ by more than 10 %).

    Raises
    ------
    ValueError : a recording with fewer than 2 samples, a bad ``rate_hz``, or no common
        span (the clocks are not synchronised: the message gives each span and the fix).
    """
    short = [n for n, r in recordings.items() if r.n_samples < 2]
    if short:
        raise ValueError(f"sensor {short[0]} has {recordings[short[0]].n_samples} sample(s); "
                         "every sensor needs at least 2")
    start = max(r.t[0] for r in recordings.values())
    stop = min(r.t[-1] for r in recordings.values())
    rate = common_rate_hz(recordings) if rate_hz is None else float(rate_hz)
    if not (np.isfinite(rate) and rate > 0):
        raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz}")
    if stop - start < 2.0 / rate:
        spans = "; ".join(f"{n} {r.t[0]:.3f}-{r.t[-1]:.3f} s" for n, r in recordings.items())
        raise ValueError(
            f"the sensors share no common time span ({spans}); their clocks are not "
            "synchronised: if they started together, re-time each from its first sample "
            "(align_start=True, --align-start), else synchronise the clocks first"
        )
    t = start + np.arange(int(np.floor((stop - start) * rate + 1e-9)) + 1) / rate
    notes = []
    lost = {n: (start - r.t[0]) + (r.t[-1] - stop) for n, r in recordings.items()}
    if max(lost.values()) > 0.5:
        first = max(recordings, key=lambda n: recordings[n].t[0])
        last = min(recordings, key=lambda n: recordings[n].t[-1])
        notes.append(
            f"the span all sensors cover is set by {first} (start) and {last} (end); left out: "
            + ", ".join(f"{n} {s:.2f} s" for n, s in lost.items() if s > 0.5))
    rates = [r.rate_hz for r in recordings.values()]
    if max(rates) > 1.1 * min(rates):
        notes.append(f"sensor rates {min(rates):.1f}-{max(rates):.1f} Hz merged onto "
                     f"{rate:g} Hz")
    return t, notes


def flags_on_time_base(rec_t: Array, flags: NDArray[np.uint16] | None, t: Array,
                       max_gap_s: float) -> NDArray[np.uint16]:
    """One sensor's flags on the common frames ``t``.

    rec_t (M,) s, the sensor's own timestamps (M >= 2); flags (M,) uint16 bits of
    :class:`~margtrack.estimator.flags.Flag` on them (None: none); t (N,) s. A frame gets
    the bits of the two samples around it, and ``GAP`` when they are more than
    ``max_gap_s`` (s) apart. Returns (N,) uint16.
    """
    i = np.clip(np.searchsorted(rec_t, t, side="right") - 1, 0, rec_t.size - 2)
    out = np.zeros(t.size, dtype=np.uint16)
    if flags is not None:
        out |= flags[i] | flags[i + 1]
    gap = (rec_t[i + 1] - rec_t[i]) > max_gap_s
    out[gap] |= np.uint16(Flag.GAP)
    return out
