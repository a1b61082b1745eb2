""""Calibrate now": find the next still second in the live stream and calibrate on it.

After a request, the processed frames' sensor orientations are searched for the first
window of ``duration_s`` of data time in which no sensor turned more than
``max_motion_deg`` from the window's first frame (:func:`margtrack.body.still_window`;
frames of the last ``duration_s`` are kept between batches); the body model is calibrated
on it
(:meth:`margtrack.live.avatars.Avatars.calibrate`, 000 eq. 10). If no such window comes
within ``timeout_s`` of data time after the request's first frame, the request fails.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import body
from margtrack import quaternion as quat
from margtrack.body.offsets import Heading
from margtrack.live.avatars import Avatars

Array = NDArray[np.float64]

__all__ = ["CalibrationOutcome", "CalibrationRequest"]


@dataclass(frozen=True, eq=False)
class CalibrationOutcome:
    """The end of a request: ``calibrations`` (None if it failed), the window and a message."""

    calibrations: list[body.Calibration] | None
    window_s: tuple[float, float] | None
    status: str


@dataclass
class CalibrationRequest:
    """A pending "calibrate now" (module docstring); :meth:`feed` it every processed batch."""

    duration_s: float = 1.0
    max_motion_deg: float = 2.0
    timeout_s: float = 10.0
    _t_start: float = math.nan
    _t: Array = field(default_factory=lambda: np.zeros(0))
    _q: Array | None = None

    def __post_init__(self) -> None:
        if not (self.duration_s > 0 and self.max_motion_deg > 0
                and self.timeout_s >= self.duration_s):
            raise ValueError(
                "need duration_s > 0, max_motion_deg > 0 and timeout_s >= duration_s; got "
                f"{self.duration_s}, {self.max_motion_deg}, {self.timeout_s}"
            )

    def feed(self, avatars: Avatars, t_s: Array, q: Array, heading: Heading = "north",
             forward_axis: ArrayLike | None = None) -> CalibrationOutcome | None:
        """Add frames ``t_s`` (N,) with orientations ``q`` (N, S, 4); an outcome once done.

        The frames kept from earlier batches and the new ones are searched for the first
        still window (:func:`margtrack.body.still_window`: ``duration_s`` from a frame, every
        sensor within ``max_motion_deg`` of that frame).
        """
        if math.isnan(self._t_start):
            self._t_start = float(t_s[0])
        t_all = np.concatenate([self._t, t_s])
        q_all = q if self._q is None else np.concatenate([self._q, q])
        try:
            window = body.still_window(t_all, q_all, self.duration_s, self.max_motion_deg)
        except ValueError:
            keep = t_all >= t_all[-1] - self.duration_s  # a window may start here
            self._t, self._q = t_all[keep], q_all[keep]
        else:
            t_win, q_win = t_all[window], q_all[window]
            span = (float(t_win[0]), float(t_win[-1]))
            motion = float(np.degrees(quat.angle_between(q_win[:1], q_win).max()))
            try:
                calibrations = avatars.calibrate(q_win, heading, forward_axis)
            except ValueError as exc:
                return CalibrationOutcome(None, span, f"calibration failed: {exc}")
            return CalibrationOutcome(
                calibrations, span,
                f"calibrated on {span[0]:.2f}-{span[1]:.2f} s (moved {motion:.2f} deg)")
        if t_s[-1] - self._t_start > self.timeout_s:
            return CalibrationOutcome(
                None, None,
                f"calibration failed: no still {self.duration_s} s within {self.timeout_s} s "
                f"(max {self.max_motion_deg} deg)")
        return None
