"""Two recordings across a joint on one clock, screened by the input policy.

:func:`pair_inputs` turns the parent's and the child's :class:`~margtrack.recording.Recording`
into :class:`JointInputs`: one time base, both sensors' rates and specific forces on it, and
per-sample health flags (:class:`~margtrack.estimator.flags.Flag`):

- the same timestamps in both: used as they are;
- different ones (other rates, other starts): the span both cover at the slower rate,
  exactly as ``margtrack body`` builds its common time base
  (:func:`margtrack.time_base.common_time_base`: cropping noted, no common span refused
  with the fix), the signals interpolated linearly onto it
  (:func:`margtrack.recording.resample`), each frame carrying the flags of the samples
  around it and ``GAP`` when interpolated across a sensor's gap;
- a value a reader held over a hole (``meta["invalid_samples"]``, :mod:`margtrack.io.mapped`)
  is ``INVALID`` (and ``ACC_IGNORED`` for the accelerometer); a rate at or beyond the
  gyroscope range is ``GYR_CLIPPED`` and replaced by the last good one; a specific force at
  or beyond the accelerometer range is ``ACC_IGNORED``; an interval longer than
  ``max_gap_s`` is ``GAP`` (not integrated over);
- magnitudes that look like deg/s or g are refused with the fix (:mod:`margtrack.units`).

A sample's accelerometers are used only when nothing is flagged within two samples of it
(the five-point derivative of the rate reaches that far): ``meas_ok``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator.flags import Flag
from margtrack.recording import Recording, resample
from margtrack.time_base import common_time_base, flags_on_time_base
from margtrack.units import UnitError, check_unit_magnitudes

Array = NDArray[np.float64]

__all__ = ["JointInputs", "pair_inputs"]

_G = 9.80665
_ROLES = ("parent", "child")


@dataclass(frozen=True)
class JointInputs:
    """Both sensors on one time base.

    t : (N,) s. gyr, acc : (2, N, 3) rad/s and m/s², parent's then child's, sensor frames.
    flags : (N,) uint16 bits of :class:`~margtrack.estimator.flags.Flag` (either sensor).
    meas_ok : (N,) bool, accelerometers usable (nothing flagged within two samples).
    restart : (N,) bool, a gap ends at the sample: not integrated over.
    notes : what was done to the inputs (cropping, resampling), for people.
    """

    t: Array
    gyr: Array
    acc: Array
    flags: NDArray[np.uint16]
    meas_ok: NDArray[np.bool_]
    restart: NDArray[np.bool_]
    notes: tuple[str, ...] = ()

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.shape[0])


def _own_flags(rec: Recording, gyr_range: float, acc_range: float) -> NDArray[np.uint16]:
    """Per-sample flags of one recording on its own clock."""
    flags = np.zeros(rec.n_samples, dtype=np.uint16)
    held = rec.meta.get("invalid_samples") or {}
    for signal, bits in (("gyr", Flag.INVALID), ("acc", Flag.INVALID | Flag.ACC_IGNORED)):
        rows = np.asarray(held.get(signal, []), dtype=np.intp)
        flags[rows[(rows >= 0) & (rows < flags.size)]] |= np.uint16(bits)
    flags[np.abs(rec.gyr).max(axis=1) >= gyr_range] |= np.uint16(Flag.GYR_CLIPPED)
    flags[np.einsum("ij,ij->i", rec.acc, rec.acc) >= acc_range**2] |= np.uint16(
        Flag.ACC_IGNORED)
    return flags


def _hold_clipped(gyr: Array, clipped: NDArray[np.bool_]) -> Array:
    """``gyr`` with clipped rows replaced by the last good row (the first good one first)."""
    if not clipped.any() or clipped.all():
        return gyr
    idx = np.where(clipped, -1, np.arange(gyr.shape[0]))
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = int(np.argmin(clipped))
    return gyr[idx]


def _check_units(rec: Recording, role: str) -> None:
    def fix(signal: str, suspected: str) -> str:
        return (f"convert the {role} recording first: "
                f"rec.with_units({signal}={suspected!r})")

    try:
        check_unit_magnitudes(rec.gyr, rec.acc, fix=fix)
    except UnitError as exc:
        raise UnitError(f"{role}: {exc}", signal=exc.signal,
                        suspected=exc.suspected) from None


def pair_inputs(
    parent: Recording,
    child: Recording,
    *,
    max_gap_s: float = 0.25,
    gyr_range_deg_s: float = 2000.0,
    acc_range_g: float = 16.0,
    rate_hz: float | None = None,
    align_start: bool = False,
    check_units: bool = True,
) -> JointInputs:
    """The two recordings on one clock with their flags (module docstring).

    Parameters
    ----------
    parent, child : the two sensors' recordings (SI units; the magnetometer is not used).
    max_gap_s : a longer interval is flagged ``GAP`` and not integrated over, s.
    gyr_range_deg_s, acc_range_g : the sensors' ranges (input policy).
    rate_hz : rate of the common time base when the timestamps differ (default: the slower
        sensor's, rounded to a whole Hz within 1 %), Hz.
    align_start : re-time both from their first sample (started together on unsynchronised
        clocks).
    check_units : refuse magnitudes that look like deg/s or g (with the fix).
    """
    recs = []
    for role, rec in zip(_ROLES, (parent, child), strict=True):
        if not isinstance(rec, Recording):
            raise TypeError(f"{role} must be a margtrack Recording (margtrack.io.read or "
                            f"Recording.from_arrays), got {type(rec).__name__}")
        if rec.n_samples < 5:
            raise ValueError(f"{role} has {rec.n_samples} sample(s); at least 5 are needed")
        if check_units:
            _check_units(rec, role)
        if align_start:
            rec = replace(rec, t=rec.t - rec.t[0])
        recs.append(rec)
    gyr_range = np.radians(gyr_range_deg_s)
    acc_range = acc_range_g * _G
    own = [_own_flags(r, gyr_range, acc_range) for r in recs]
    gyrs = [_hold_clipped(r.gyr, (f & int(Flag.GYR_CLIPPED)) != 0) for r, f in zip(recs, own,
                                                                                   strict=True)]
    same = recs[0].t.shape == recs[1].t.shape and np.array_equal(recs[0].t, recs[1].t)
    notes: list[str] = []
    if same and rate_hz is None:
        t = recs[0].t
        gyr = np.stack(gyrs)
        acc = np.stack([r.acc for r in recs])
        flags = own[0] | own[1]
        restart = np.concatenate([[False], np.diff(t) > max_gap_s])
    else:
        t, notes = common_time_base(dict(zip(_ROLES, recs, strict=True)), rate_hz)
        gyr = np.stack([resample(r.t, g, t) for r, g in zip(recs, gyrs, strict=True)])
        acc = np.stack([resample(r.t, r.acc, t) for r in recs])
        flags = flags_on_time_base(recs[0].t, own[0], t, max_gap_s) | flags_on_time_base(
            recs[1].t, own[1], t, max_gap_s)
        restart = (flags & int(Flag.GAP)) != 0
    restart[0] = False
    flags = flags.copy()
    flags[restart] |= np.uint16(Flag.GAP)
    bad = flags != 0
    if bad.any():  # the five-point derivative reaches two samples each way
        meas_ok = np.convolve(bad, np.ones(5), mode="same") == 0
    else:
        meas_ok = np.ones(t.shape[0], dtype=bool)
    return JointInputs(t, gyr, acc, flags, meas_ok, restart, tuple(notes))
