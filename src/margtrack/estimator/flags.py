"""Health flags: one bit-flag schema, the same names for every method.

Every :class:`~margtrack.estimator.Estimate` carries ``flags`` (N,) or (S, N) ``uint16``:
the bits below, set by the input screening (what was wrong with the sample and what was
done about it) and by the method (rest, rejected disturbances). ``flags == 0`` is a clean
sample. Outputs stay aligned sample for sample whatever the flags say.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "DATA_FLAGS",
    "FAULT_FLAGS",
    "STATE_FLAGS",
    "Flag",
    "count_flags",
    "describe",
    "format_summary",
    "percent",
    "summary",
]


class Flag(enum.IntFlag):
    """Bits of the per-sample health flags (``Estimate.flags``)."""

    #: a non-finite value (NaN, inf) in the sample: that signal was not used
    INVALID = 1 << 0
    #: timestamp non-finite, repeated or going back: the sample was skipped (output held)
    CLOCK = 1 << 1
    #: more than ``max_gap_s`` since the previous sample (or a clock reset): not
    #: integrated; the filter restarted from the first usable sample here
    GAP = 1 << 2
    #: a rate at or beyond ``gyr_range_deg_s`` (or non-finite): the last good rate was used
    GYR_CLIPPED = 1 << 3
    #: the accelerometer was not used for correction (zero, non-finite, beyond
    #: ``acc_range_g``, or rejected by the method)
    ACC_IGNORED = 1 << 4
    #: the magnetometer was not used (zero, non-finite, a clipped or stuck axis)
    MAG_IGNORED = 1 << 5
    #: the field's norm or dip was far from its reference: magnetometer not used
    MAG_DISTURBED = 1 << 6
    #: the method detected rest
    REST = 1 << 7
    #: no usable sample since the start (the output is held), or inside a restart's window
    #: after a gap (the output is the window's orientation so far)
    INITIALISING = 1 << 8
    #: a restart after a gap kept the heading of the orientation before the gap: the field
    #: after the gap did not agree with the reference learned before it (or none was
    #: usable), so the heading is a guess until the method corrects it from the field again
    HEADING_CARRIED = 1 << 9


#: flags that say something was wrong with the input (``strict=True`` raises on these)
DATA_FLAGS = (
    Flag.INVALID | Flag.CLOCK | Flag.GAP | Flag.GYR_CLIPPED | Flag.ACC_IGNORED | Flag.MAG_IGNORED
)

#: flags that say a sample was not measured or used as it should have been: the input's faults
#: and the disturbances the method rejected. A recording with none of them is clean data;
#: the summaries count them apart from the states.
FAULT_FLAGS = DATA_FLAGS | Flag.MAG_DISTURBED

#: flags that describe a normal state of the sensor or the method, not a fault
STATE_FLAGS = Flag.REST | Flag.INITIALISING | Flag.HEADING_CARRIED

_FIXES = {
    Flag.INVALID: "remove or interpolate non-finite values",
    Flag.CLOCK: "check the timestamps (they must increase)",
    Flag.GAP: "the recording has missing samples there (raise max_gap_s to integrate across "
    "gaps); if most intervals are gaps, the timestamps are not in s: declare their unit",
    Flag.GYR_CLIPPED: "check gyr units (rad/s) and gyr_range_deg_s",
    Flag.ACC_IGNORED: "check acc units (m/s²), acc_range_g and zero samples",
    Flag.MAG_IGNORED: "the magnetometer is zero, clipped or stuck there",
}


def describe(bits: int) -> str:
    """Names of the bits set in one flag value, ``"GAP|ACC_IGNORED"`` (``"OK"`` for 0)."""
    names = [f.name for f in Flag if int(bits) & f and f.name]
    return "|".join(names) if names else "OK"


def count_flags(flags: ArrayLike) -> dict[str, int]:
    """How many samples have each flag set: ``{"GAP": 1, ...}`` (flags that occur only)."""
    arr = np.asarray(flags).astype(np.uint16, copy=False)
    out = {}
    for f in Flag:
        n = int(np.count_nonzero(arr & int(f)))
        if n:
            out[str(f.name)] = n
    return out


def percent(share: float) -> str:
    """A share in percent for people: ``"35"``, ``"0.19"``, ``"100"`` (never ``"1e+02"``)."""
    if share >= 10.0 or share == 0.0:
        return f"{share:.0f}"
    if share >= 0.01:
        return f"{share:.2g}"
    return "<0.01"


def format_summary(
    total: int, faulty: int, counts: Mapping[Flag, int], first: Mapping[Flag, str]
) -> str:
    """The summary line from tallies: ``total`` samples, ``faulty`` of them with a fault
    flag, per flag its count and where it first occurs (``"sample 12"``).

    Faults (:data:`FAULT_FLAGS`) and states (:data:`STATE_FLAGS`, normal: rest,
    initialising) are listed apart, so ``faults: 0 of N samples`` means clean data.
    """

    def listed(group: Flag, with_share: bool) -> str:
        parts = []
        for f in Flag:
            n = counts.get(f, 0)
            if n and f & group:
                share = f"{percent(100.0 * n / total)} %, " if with_share else ""
                parts.append(f"{f.name} {n} ({share}first at {first[f]})")
        return ", ".join(parts)

    text = f"faults: {faulty} of {total} samples"
    if faulty:
        text += f" ({percent(100.0 * faulty / total)} %): {listed(FAULT_FLAGS, False)}"
    states = listed(STATE_FLAGS, True)
    return f"{text}; states: {states}" if states else text


def summary(flags: ArrayLike) -> str:
    """One line for people: faulty samples of the total, per flag the count and first sample.

    ``"faults: 108 of 56940 samples (0.19 %): MAG_DISTURBED 108 (first at sample 9948);
    states: REST 19865 (35 %, first at sample 429)"``; faults and states apart
    (:func:`format_summary`). With S sensors the sample index is per sensor and the sensor
    is named.
    """
    arr = np.asarray(flags).astype(np.uint16, copy=False)
    counts: dict[Flag, int] = {}
    first: dict[Flag, str] = {}
    for f in Flag:
        hits = np.argwhere(arr & int(f))
        if hits.size == 0:
            continue
        where = f"sample {int(hits[0][-1])}"
        if arr.ndim == 2:
            where = f"sensor {int(hits[0][0])}, {where}"
        counts[f], first[f] = int(hits.shape[0]), where
    faulty = int(np.count_nonzero(arr & int(FAULT_FLAGS)))
    return format_summary(int(arr.size), faulty, counts, first)


def first_problem(flags: ArrayLike, mask: int = int(DATA_FLAGS)) -> str | None:
    """A sentence naming the first sample with a data flag and its fix, or None if none."""
    arr = np.asarray(flags).astype(np.uint16, copy=False)
    hits = np.argwhere(arr & mask)
    if hits.size == 0:
        return None
    first = tuple(int(v) for v in hits[0])
    bits = int(arr[first]) & mask
    where = f"sample {first[-1]}" if arr.ndim == 1 else f"sensor {first[0]}, sample {first[-1]}"
    fixes = "; ".join(fix for f, fix in _FIXES.items() if bits & f)
    return f"{where} is flagged {describe(bits)}: {fixes}"
