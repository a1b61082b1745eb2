"""Davenport's q-method: the exact least-squares (Wahba) orientation from gravity and field.

Wahba's loss (002 eq. 9) over the two pairs (accelerometer ↔ up, magnetometer ↔ reference
field) with weights a_i is minimised by the eigenvector of the largest eigenvalue of
Davenport's K (002 eq. 10). It is solved here with a full 4 x 4 symmetric eigen-
decomposition (Jacobi), exact to rounding: the reference QUEST, FQA, TRIAD and
Gauss-Newton are tested against. Unlike TRIAD and FQA, the field enters pitch and roll too,
so a disturbed field tilts the estimate (002 III-C).

The reference field needs the magnetic dip: give the shared ``mag_dip_ref_deg`` (which
also centres the input screening's dip gate) or leave it None to measure it from each
sensor's first valid sample (as the angle between accelerometer and magnetometer), kept in
the state. Only magnetic north is known, so the heading is relative to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator import param
from margtrack.single_frame.davenport_kernel import davenport_run
from margtrack.single_frame.prefilter import LowpassParams, MeasuredDipState, SingleFrameEstimator

__all__ = ["Davenport", "DavenportParams", "WahbaParams"]


@dataclass(frozen=True)
class WahbaParams(LowpassParams):
    """Parameters of the Wahba-problem estimators (Davenport, QUEST).

    weights : (a_gravity, a_field), the weights a_i > 0 of the accelerometer and
        magnetometer pairs in Wahba's loss (002 eq. 9); default (1, 1). Only their ratio
        matters; raising a_field lets the field pull more on pitch and roll (with a
        disturbed field, for worse). Optimal: inversely proportional to each unit vector's
        error variance (Shuster & Oh).

    The reference field's dip is the shared ``mag_dip_ref_deg``, deg, positive down
    (None, the default: measured from each sensor's first valid sample).
    """

    weights: tuple[float, float] = param(
        (1.0, 1.0), gt=0, help="Wahba weights (a_gravity, a_field); only their ratio matters"
    )

    def check(self) -> None:
        """weights are two numbers."""
        super().check()
        if len(self.weights) != 2:
            raise ValueError(
                f"parameter weights must be two numbers (a_gravity, a_field); got {self.weights!r}"
            )


@dataclass(frozen=True)
class DavenportParams(WahbaParams):
    """Davenport's parameters: see :class:`WahbaParams` and ``LowpassParams``."""


class Davenport(SingleFrameEstimator[DavenportParams, MeasuredDipState]):
    """Davenport's q-method (``--method davenport``), the exact Wahba solution.

    Outputs: ``degenerate`` (N,) int8 (0 ok, 1 zero accelerometer: the previous
    orientation is repeated; 2 zero magnetometer, 3 accelerometer parallel to the field:
    levelled onto gravity, heading kept; mapped onto the flags, see ``prefilter``).
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
            acc, mag, dt, up, north, self._dip_rad(), p.weights[0], p.weights[1],
            acc_cut, mag_cut, order,
            state.quat, state.dip_rad, state.lowpass_history, state.lowpass_ready, out, flags,
        )
        return out, {"degenerate": flags}
