"""Davenport's q-method: the exact least-squares (Wahba) orientation from gravity and field.

Wahba's loss (002 eq. 9) over the two pairs (accelerometer ↔ up, magnetometer ↔ reference
field) with weights a_i is minimised by the eigenvector of the largest eigenvalue of
Davenport's K (002 eq. 10). It is solved here with a full 4 x 4 symmetric eigen-
decomposition (Jacobi), exact to rounding: the reference QUEST, FQA, TRIAD and
Gauss-Newton are tested against. Unlike TRIAD and FQA, the field enters pitch and roll too,
so a disturbed field tilts the estimate (002 III-C).

The reference field needs the magnetic dip: give ``dip_deg`` or leave it None to measure
it from each sensor's first valid sample (as the angle between accelerometer and
magnetometer), kept in the state. Only magnetic north is known, so the heading is relative
to it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.estimators.prefilter import (
    LowpassParams,
    MeasuredDipState,
    SingleFrameEstimator,
    check_dip_deg,
    dip_rad_or_nan,
)
from margtrack.kernels.davenport import davenport_run

__all__ = ["Davenport", "DavenportParams", "WahbaParams"]


@dataclass(frozen=True)
class WahbaParams(LowpassParams):
    """Parameters of the Wahba-problem estimators (Davenport, QUEST).

    weights : (a_gravity, a_field), the weights a_i > 0 of the accelerometer and
        magnetometer pairs in Wahba's loss (002 eq. 9); default (1, 1). Only their ratio
        matters; raising a_field lets the field pull more on pitch and roll (with a
        disturbed field, for worse). Optimal: inversely proportional to each unit vector's
        error variance (Shuster & Oh).
    dip_deg : magnetic dip (inclination) of the reference field, deg, positive down, in
        [-90, 90]; default None: measured from each sensor's first valid sample.
    """

    weights: tuple[float, float] = (1.0, 1.0)
    dip_deg: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        w = self.weights
        if not isinstance(w, Sequence) or isinstance(w, str) or len(w) != 2:
            raise ValueError(f"weights must be two numbers (a_gravity, a_field), got {w!r}")
        try:
            values = tuple(float(x) for x in w)
        except (TypeError, ValueError):
            message = f"weights must be two numbers (a_gravity, a_field), got {w!r}"
            raise ValueError(message) from None
        if not all(np.isfinite(x) and x > 0 for x in values):
            raise ValueError(f"weights must be finite and > 0, got {w!r}")
        object.__setattr__(self, "weights", values)
        object.__setattr__(self, "dip_deg", check_dip_deg(self.dip_deg))


@dataclass(frozen=True)
class DavenportParams(WahbaParams):
    """Davenport's parameters: see :class:`WahbaParams` and ``LowpassParams``."""


class Davenport(SingleFrameEstimator[DavenportParams, MeasuredDipState]):
    """Davenport's q-method (``--method davenport``), the exact Wahba solution.

    Outputs: ``degenerate`` (N,) int8 (0 ok, 1 zero accelerometer, 2 zero magnetometer,
    3 accelerometer parallel to the field; the previous orientation is repeated).
    Quaternions have ``w >= 0``. The state's ``dip_rad`` holds the measured dip.
    """

    name = "davenport"
    params_type = DavenportParams

    def _new_state(self, quat0: NDArray[np.float64]) -> MeasuredDipState:
        return MeasuredDipState.fresh(quat0)  # type: ignore[return-value]

    def _process(
        self,
        state: MeasuredDipState,
        gyr: NDArray[np.float64] | None,
        acc: NDArray[np.float64],
        mag: NDArray[np.float64] | None,
        dt: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], dict[str, NDArray[Any]]]:
        assert mag is not None  # guaranteed by mag_optional = False
        p = self.params
        up, north = self._earth_axes()
        acc_cut, mag_cut, order = self._lowpass_args(dt)
        out = np.empty((acc.shape[0], acc.shape[1], 4))
        flags = np.empty(acc.shape[:2], dtype=np.int8)
        davenport_run(
            acc, mag, dt, up, north, dip_rad_or_nan(p.dip_deg), p.weights[0], p.weights[1],
            acc_cut, mag_cut, order,
            state.quat, state.dip_rad, state.lowpass_history, state.lowpass_ready, out, flags,
        )
        return out, {"degenerate": flags}
