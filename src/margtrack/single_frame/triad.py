"""TRIAD: orientation from one accelerometer and one magnetometer sample (002 eqs. 1-8).

The first triad is built on gravity, so pitch and roll come from the accelerometer alone
and the magnetometer sets only the heading (002, after eq. 8; 003 eqs. 10-13). The result
is exact for noise-free vectors and sub-optimal (not least-squares) with noise. Only the
horizontal direction of the field is used, so TRIAD needs no dip angle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator import triad_kernel as kernel
from margtrack.single_frame.prefilter import LowpassParams, SingleFrameEstimator, SingleFrameState

__all__ = ["Triad", "TriadParams"]


@dataclass(frozen=True)
class TriadParams(LowpassParams):
    """TRIAD's parameters: the output ``frame`` and the optional low-pass prefilter.

    See :class:`~margtrack.single_frame.prefilter.LowpassParams` for ``acc_lowpass_hz``,
    ``mag_lowpass_hz`` and ``lowpass_order``.
    """


class Triad(SingleFrameEstimator[TriadParams, SingleFrameState]):
    """Single-frame TRIAD estimator (``--method triad``); needs a magnetometer.

    Outputs: ``degenerate`` (N,) int8 per sample: 0 ok, 1 zero accelerometer (the previous
    orientation is repeated), 2 zero magnetometer, 3 accelerometer parallel to the field
    (levelled onto gravity, heading kept); mapped onto the flags (see ``prefilter``).
    Never NaN. Quaternions have ``w >= 0``.
    """

    name = "triad"
    params_type = TriadParams

    def _process(
        self,
        state: SingleFrameState,
        gyr: NDArray[np.float64] | None,
        acc: NDArray[np.float64],
        mag: NDArray[np.float64] | None,
        dt: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], dict[str, NDArray[Any]]]:
        assert mag is not None  # guaranteed by mag_optional = False
        up, north = self._earth_axes()
        acc_cut, mag_cut, order = self._lowpass_args(dt)
        out = np.empty((acc.shape[0], acc.shape[1], 4))
        flags = np.empty(acc.shape[:2], dtype=np.int8)
        kernel.triad_run(
            acc, mag, dt, up, north, acc_cut, mag_cut, order,
            state.quat, state.lowpass_history, state.lowpass_ready, out, flags,
        )
        return out, {"degenerate": flags}
