"""QUEST: Shuster & Oh's quaternion estimator for Wahba's problem (as described in 002).

The optimal (weighted least-squares, 002 eq. 9) quaternion from gravity and the magnetic
field, in closed form: for two observations the largest eigenvalue of Davenport's K is
known exactly, and the eigenvector comes from Shuster & Oh's adjugate formula. That
formula is singular at rotations of 180 deg (the Gibbs vector, 002 eq. 42); near them the
method of sequential rotations solves the problem in a reference frame turned by 180 deg
about an earth axis and turns the answer back (the ``sequential_rotation`` output names
the axis). The result equals Davenport's q-method to rounding at every orientation.

As in every Wahba solution the field enters pitch and roll as well as the heading, so a
disturbed field tilts the estimate (002 III-C); FQA and TRIAD avoid this.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator.params import param
from margtrack.single_frame.davenport import WahbaParams
from margtrack.single_frame.prefilter import MeasuredDipState, SingleFrameEstimator
from margtrack.single_frame.quest_kernel import quest_run

__all__ = ["Quest", "QuestParams"]


@dataclass(frozen=True)
class QuestParams(WahbaParams):
    """QUEST's parameters: ``weights`` (a_gravity, a_field) and the reference dip
    ``mag_dip_ref_deg`` (see :class:`~margtrack.single_frame.davenport.WahbaParams`), the
    output ``frame``, the low-pass prefilter and how λ_max is found."""

    eigenvalue: str = param(
        "closed-form",
        choices=("closed-form", "newton"),
        help="largest eigenvalue of K: exact for two vectors, or Newton-Raphson on the "
        "characteristic equation as in Shuster & Oh's QUEST (002's timing)",
    )


class Quest(SingleFrameEstimator[QuestParams, MeasuredDipState]):
    """QUEST (``--method quest``) with sequential rotations near 180 deg.

    Outputs, per sample: ``degenerate`` int8 (0 ok, 1 zero accelerometer: the previous
    orientation is repeated; 2 zero magnetometer, 3 accelerometer parallel to the field:
    levelled onto gravity, heading kept; mapped onto the flags, see ``prefilter``) and
    ``sequential_rotation`` int8 (0 none, 1/2/3: the reference frame was turned by 180 deg
    about earth x/y/z). Quaternions have ``w >= 0``.
    """

    name = "quest"
    params_type = QuestParams

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
        shape = acc.shape[:2]
        out = np.empty((*shape, 4))
        flags = np.empty(shape, dtype=np.int8)
        rotation = np.empty(shape, dtype=np.int8)
        quest_run(
            acc, mag, dt, up, north, self._dip_rad(), p.weights[0], p.weights[1],
            p.eigenvalue == "newton", acc_cut, mag_cut, order,
            state.quat, state.dip_rad, state.lowpass_history, state.lowpass_ready,
            out, flags, rotation,
        )
        return out, {"degenerate": flags, "sequential_rotation": rotation}
