"""Plain gyroscope integration: the baseline every filter must beat.

No correction at all: the orientation drifts with gyro bias and noise. It starts from
``q0`` or from the first usable accelerometer/magnetometer sample (TRIAD), then integrates
``q_i = q_{i-1} ⊗ exp(ω_i dt_i / 2)`` exactly for piecewise-constant rates (the closed
form of ``q̇ = ½ q ⊗ (0, ω)``, 004 "Gyroscope Equations").

Input policy (:mod:`margtrack.estimator.screening`): a bad rate is replaced by the last
good one, ``dt = 0`` integrates nothing, and after a gap (``max_gap_s``) the orientation
is measured again from the first usable sample, as at the start (a ``q0`` given to
``reset`` applies to the first segment only): the integration cannot bridge a gap.
"""

from __future__ import annotations

from dataclasses import dataclass

from margtrack.estimator import Params
from margtrack.estimator.compiled import CompiledEstimator
from margtrack.methods.gyro import kernel

__all__ = ["GyroIntegration", "GyroParams"]


@dataclass(frozen=True)
class GyroParams(Params):
    """Gyro integration has no parameter of its own: only the shared ones of :class:`Params`
    (output ``frame`` and the input policy: sensor ranges, ``max_gap_s``, strict mode)."""


class GyroIntegration(CompiledEstimator[GyroParams]):
    """Orientation by integrating the gyroscope alone (``--method gyro``).

    The accelerometer and magnetometer, when given, are used only to set the initial
    orientation (and to set it again after a gap). State: the orientation only.
    """

    name = "gyro"
    params_type = GyroParams
    kernel = kernel
