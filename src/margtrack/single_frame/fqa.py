"""FQA, the factored quaternion algorithm (002 section II), with singularity avoidance.

Elevation from the accelerometer's x component, roll from its y and z components, then
azimuth from the magnetometer turned into the level plane, each as a half-angle
quaternion computed with square roots only (002 eqs. 17-41). Like TRIAD, the magnetometer
sets only the heading: a disturbed field never tilts the estimate (002 III-C). Only the
horizontal direction of the field is used (eqs. 36-39), so FQA needs no dip angle.

Near pitch ±90 deg roll and azimuth are computed from small numbers (``cos θ`` divides in
eqs. 30-31). When ``cos θ < epsilon`` the measurements are replaced by those of a virtual sensor
turned by ``alpha`` about the body y axis and the result is turned back (002 eqs. 43-46);
the ``switched`` output says when.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimator import param
from margtrack.single_frame.fqa_kernel import fqa_run
from margtrack.single_frame.prefilter import LowpassParams, SingleFrameEstimator, SingleFrameState

__all__ = ["Fqa", "FqaParams"]


@dataclass(frozen=True)
class FqaParams(LowpassParams):
    """FQA's parameters (plus the output ``frame`` and the prefilter of ``LowpassParams``).

    epsilon : switch threshold ε on ``cos θ`` (θ = pitch), in [0, tan(alpha/2)); default
        0.1, 002's value (pitch within about 84.3 deg of level uses the physical sensor).
        Raising it switches to the virtual sensor farther from ±90 deg; 0 never switches.
        The upper bound keeps the virtual sensor itself away from its singularity. As
        cos θ is computed here as ``sqrt(ā_y² + ā_z²)`` (equal to eq. 22 for a unit ā,
        but not rounded to 0 within 1e-7 deg of ±90 deg), the result is exact to rounding
        with or without switching; the switch reproduces 002 and its flag.
    alpha_deg : offset angle α of the virtual sensor about the body y axis, deg, in
        (0, 90]; default 20, 002's value (its Figs. 7-8 use epsilon 0.2, alpha 45).
    """

    epsilon: float = param(
        0.1, ge=0, help="use the virtual offset sensor while cos(pitch) is below this (002)"
    )
    alpha_deg: float = param(
        20.0, unit="deg", gt=0, le=90, help="offset of the virtual sensor about body y (002)"
    )

    def check(self) -> None:
        """epsilon < tan(alpha_deg / 2): the virtual sensor must stay off its singularity."""
        super().check()
        limit = math.tan(math.radians(self.alpha_deg) / 2.0)
        if not self.epsilon < limit:
            raise ValueError(
                f"parameter epsilon must be < tan(alpha_deg / 2) = {limit:.4g} for "
                f"alpha_deg = {self.alpha_deg:g}; got {self.epsilon!r}: beyond it the virtual "
                "sensor turned by alpha can itself reach pitch ±90 deg; raise alpha_deg or "
                "lower epsilon"
            )


class Fqa(SingleFrameEstimator[FqaParams, SingleFrameState]):
    """The factored quaternion algorithm (``--method fqa``); needs a magnetometer.

    Outputs, per sample: ``degenerate`` int8 (0 ok, 1 zero accelerometer: the previous
    orientation is repeated; 2 zero magnetometer, 3 accelerometer parallel to the field:
    levelled onto gravity, heading kept; mapped onto the flags, see ``prefilter``) and
    ``switched`` bool (the virtual offset sensor was used, ``cos θ <
    epsilon``). Quaternions have ``w >= 0``; :func:`margtrack.quaternion.continuous` makes
    a series sign-continuous.
    """

    name = "fqa"
    params_type = FqaParams

    def _process(
        self,
        state: SingleFrameState,
        gyr: NDArray[np.float64] | None,
        acc: NDArray[np.float64],
        mag: NDArray[np.float64] | None,
        dt: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], dict[str, NDArray[Any]]]:
        assert mag is not None  # guaranteed by mag_optional = False
        p = self.params
        acc_cut, mag_cut, order = self._lowpass_args(dt)
        # FQA is derived in NED; the output frame is one fixed rotation away
        frame_quat = frames.convert(np.array([1.0, 0.0, 0.0, 0.0]), "NED", p.frame)
        half = math.radians(p.alpha_deg) / 2.0
        shape = acc.shape[:2]
        out = np.empty((*shape, 4))
        flags = np.empty(shape, dtype=np.int8)
        switched = np.empty(shape, dtype=np.bool_)
        fqa_run(
            acc, mag, dt, frame_quat, p.epsilon, math.cos(half), math.sin(half),
            acc_cut, mag_cut, order,
            state.quat, state.lowpass_history, state.lowpass_ready, out, flags, switched,
        )
        return out, {"degenerate": flags, "switched": switched}
