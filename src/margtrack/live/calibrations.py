"""The body calibrations a live engine has in force, and its pending "calibrate now".

Thread-safe: the viewer or a replay sets calibrations or asks for one; the worker feeds the
pending request with every processed batch (:class:`~margtrack.live.reference_pose.
CalibrationRequest`, 000 eq. 10) and reads the offsets in force for the body model
(:meth:`margtrack.live.avatars.Avatars.offsets`, (A, K, 4)). Before any calibration every
person has identity offsets.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.body.offsets import Heading
from margtrack.live.avatars import Avatars
from margtrack.live.reference_pose import CalibrationRequest

Array = NDArray[np.float64]

__all__ = ["Calibrations"]


class Calibrations:
    """Calibrations of the people of ``avatars`` (None: no body model; module docstring)."""

    def __init__(self, avatars: Avatars | None, heading: Heading = "north",
                 forward_axis: ArrayLike | None = None) -> None:
        self.avatars = avatars
        self.heading: Heading = heading
        self.forward_axis = forward_axis
        self._lock = threading.Lock()
        self._in_force = avatars.identity() if avatars is not None else []
        self._offsets = Avatars.offsets(self._in_force) if avatars is not None else None
        self._request: CalibrationRequest | None = None
        self._status = "not calibrated (identity offsets)"
        #: (first, last) time of the frames of the last successful calibration, s
        self.window_s: tuple[float, float] | None = None
        #: how many calibrations were put in force (0: identity offsets)
        self.count = 0

    def request(self, duration_s: float = 1.0, max_motion_deg: float = 2.0,
                timeout_s: float = 10.0) -> None:
        """Calibrate on the next still ``duration_s`` (:class:`CalibrationRequest`)."""
        if self.avatars is None:
            raise ValueError("no body model: the sensor names name no skeleton segments")
        request = CalibrationRequest(duration_s, max_motion_deg, timeout_s)
        with self._lock:
            self._request = request
            self._status = "waiting for a still second in the reference pose"

    @property
    def pending(self) -> CalibrationRequest | None:
        """The request waiting for a still window, if any."""
        with self._lock:
            return self._request

    @property
    def status(self) -> str:
        """What the last request did."""
        with self._lock:
            return self._status

    @property
    def in_force(self) -> list[Any]:
        """Per person, the :class:`margtrack.body.Calibration` in force."""
        with self._lock:
            return list(self._in_force)

    @property
    def offsets(self) -> Array | None:
        """(A, K, 4) the offsets in force (None without a body model)."""
        with self._lock:
            return self._offsets

    def set(self, calibrations: Sequence[Any]) -> None:
        """Put per-person calibrations in force (a replayed or saved calibration)."""
        if self.avatars is None or len(calibrations) != self.avatars.n_people:
            raise ValueError(f"need one calibration per person of the body model, got "
                             f"{len(calibrations)}")
        with self._lock:
            self._in_force = list(calibrations)
            self._offsets = Avatars.offsets(self._in_force)
            self.count += 1

    def feed(self, request: CalibrationRequest, t_s: Array, q: Array) -> None:
        """Give ``request`` the frames ``t_s`` (N,) and orientations ``q`` (N, S, 4) of a batch;
        once it ends, put its calibrations in force (if it succeeded) and say so."""
        if self.avatars is None:
            return
        outcome = request.feed(self.avatars, t_s, q, self.heading, self.forward_axis)
        if outcome is None:
            return
        with self._lock:
            if self._request is request:
                self._request = None
            if outcome.calibrations is not None:
                self._in_force = outcome.calibrations
                self._offsets = Avatars.offsets(outcome.calibrations)
                self.window_s = outcome.window_s
                self.count += 1
            self._status = outcome.status
