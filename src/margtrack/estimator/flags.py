"""Health flags: one bit-flag schema, the same names for every method.

Every :class:`~margtrack.estimator.Estimate` carries ``flags`` (N,) or (S, N) ``uint16``:
the bits below, set by the input screening (what was wrong with the sample and what was
done about it) and by the method (rest, rejected disturbances). ``flags == 0`` is a clean
sample. Outputs stay aligned sample for sample whatever the flags say.
"""

from __future__ import annotations

import enum

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["DATA_FLAGS", "Flag", "count_flags", "describe", "summary"]


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
    #: no usable sample since the start or the last restart: the output is held
    INITIALISING = 1 << 8


#: flags that say something was wrong with the input (``strict=True`` raises on these)
DATA_FLAGS = (
    Flag.INVALID | Flag.CLOCK | Flag.GAP | Flag.GYR_CLIPPED | Flag.ACC_IGNORED | Flag.MAG_IGNORED
)

_FIXES = {
    Flag.INVALID: "remove or interpolate non-finite values",
    Flag.CLOCK: "check the timestamps (they must increase)",
    Flag.GAP: "the recording has missing samples; raise max_gap_s to integrate across gaps",
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


def summary(flags: ArrayLike) -> str:
    """One line for people: flagged samples of the total and per flag with the first sample.

    ``"flags: 12 of 9000 samples (0.13 %): GAP 1 (first at sample 4500), ..."``; with
    S sensors the sample index is per sensor and the sensor is named.
    """
    arr = np.asarray(flags).astype(np.uint16, copy=False)
    total = arr.size
    flagged = int(np.count_nonzero(arr))
    if flagged == 0:
        return f"flags: none of {total} samples"
    parts = []
    for f in Flag:
        hits = np.argwhere(arr & int(f))
        if hits.size == 0:
            continue
        first = hits[0]
        where = f"sample {int(first[-1])}"
        if arr.ndim == 2:
            where = f"sensor {int(first[0])}, {where}"
        parts.append(f"{f.name} {hits.shape[0]} (first at {where})")
    share = 100.0 * flagged / total
    return f"flags: {flagged} of {total} samples ({share:.2g} %): " + ", ".join(parts)


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
