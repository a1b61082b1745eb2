"""TRIAD: orientation from one accelerometer and one magnetometer sample (002 eqs. 1-8).

The first triad is built on gravity, so pitch and roll come from the accelerometer alone
and the magnetometer sets only the heading (002, after eq. 8; 003 eqs. 10-13). The result
is exact for noise-free vectors and sub-optimal (not least-squares) with noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimators.base import Estimator, Params, State
from margtrack.kernels import triad as kernel

__all__ = ["Triad", "TriadParams"]


@dataclass(frozen=True)
class TriadParams(Params):
    """TRIAD has no parameter beyond the output ``frame``."""


class Triad(Estimator[TriadParams, State]):
    """Single-frame TRIAD estimator (``--method triad``); needs a magnetometer.

    Outputs: ``degenerate`` (N,) int8 per sample: 0 ok, 1 zero accelerometer, 2 zero
    magnetometer, 3 accelerometer parallel to the field. A degenerate sample repeats the
    previous orientation instead of producing NaN.
    """

    name = "triad"
    params_type = TriadParams
    uses_gyr = False
    mag_optional = False

    def _new_state(self, quat0: NDArray[np.float64]) -> State:
        return State(quat=np.array(quat0, dtype=np.float64))

    def _initial_quat(self, acc0: NDArray[np.float64], mag0: NDArray[np.float64] | None):
        # no initialisation needed: every sample is measured on its own; a degenerate
        # first sample is flagged by the kernel instead of raising here
        return np.tile([1.0, 0.0, 0.0, 0.0], (acc0.shape[0], 1))

    def _process(
        self,
        state: State,
        gyr: NDArray[np.float64] | None,
        acc: NDArray[np.float64],
        mag: NDArray[np.float64] | None,
        dt: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], dict[str, NDArray[Any]]]:
        assert mag is not None  # guaranteed by mag_optional = False
        frame = self.params.frame
        up = frames.up(frame)
        north = frames.mag_reference(frame, dip_deg=0.0)
        n_sensors, n = acc.shape[0], acc.shape[1]
        out = np.empty((n_sensors, n, 4))
        flags = np.empty((n_sensors, n), dtype=np.int8)
        for s in range(n_sensors):
            kernel.triad(acc[s], mag[s], up, north, out[s], flags[s])
            # a degenerate leading sample holds the previous run's last orientation
            bad_lead = np.flatnonzero(flags[s] != kernel.OK)
            good = np.flatnonzero(flags[s] == kernel.OK)
            first_good = good[0] if good.size else n
            lead = bad_lead[bad_lead < first_good]
            out[s, lead] = state.quat[s]
            state.quat[s] = out[s, -1]
        return out, {"degenerate": flags}
