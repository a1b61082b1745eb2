"""What every single-frame estimator shares: the optional low-pass prefilter and its state.

Single-frame estimators (TRIAD, FQA, QUEST, Davenport, Gauss-Newton, Newton) turn each
accelerometer + magnetometer sample into an orientation on its own. An accelerometer also
measures linear acceleration, so 002 (Fig. 5) puts a low-pass filter in front of the
estimator for moving sensors. Here that filter is a parameter of every single-frame
estimator: a first- or second-order Butterworth low-pass with a cut-off in Hz, on the
accelerometer and, separately, on the magnetometer (``None`` switches it off). Its history
lives in the state, so ``update`` one sample at a time, one ``run`` and runs split
anywhere give the same result.

Degenerate samples (zero accelerometer or magnetometer, or the two parallel) are never
turned into NaN: they are flagged in the ``degenerate`` output and repeat the previous
orientation (the initial one, identity unless ``reset(q0)`` gave one, if none came before).
Every estimator returns quaternions with ``w >= 0``; :func:`margtrack.quaternion.continuous`
makes a series sign-continuous where that matters (002's closing remark on ``q`` and
``-q``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, TypeVar

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimators.base import Estimator, Params, State

Array = NDArray[np.float64]

__all__ = [
    "DEGENERATE_CODES",
    "LowpassParams",
    "MeasuredDipState",
    "SingleFrameEstimator",
    "SingleFrameState",
    "check_dip_deg",
    "dip_rad_or_nan",
]

#: meaning of the ``degenerate`` output codes (int8), shared by all single-frame estimators
DEGENERATE_CODES = {
    0: "ok",
    1: "zero accelerometer vector",
    2: "zero magnetometer vector",
    3: "accelerometer parallel to the magnetic field (less than 0.06 deg apart)",
    4: "iteration failed (singular normal equations)",
}


@dataclass(frozen=True)
class LowpassParams(Params):
    """Parameters of the low-pass prefilter (002 Fig. 5), common to single-frame estimators.

    acc_lowpass_hz : cut-off of the accelerometer low-pass, Hz, or None (default) for no
        filter. Lowering it rejects more linear acceleration and delays the inclination
        more (a second-order filter delays a slow rotation by about ``0.225 / f_c`` s).
        Must stay below half the sample rate (checked against every run's ``dt``).
    mag_lowpass_hz : the same for the magnetometer, Hz, or None (default).
    lowpass_order : 1 or 2 (default): order of the Butterworth filter.
    """

    acc_lowpass_hz: float | None = None
    mag_lowpass_hz: float | None = None
    lowpass_order: int = 2

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("acc_lowpass_hz", "mag_lowpass_hz"):
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(value, bool) or not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite cut-off > 0 Hz or None, got {value!r}")
            object.__setattr__(self, name, float(value))
        if self.lowpass_order not in (1, 2) or isinstance(self.lowpass_order, bool):
            raise ValueError(f"lowpass_order must be 1 or 2, got {self.lowpass_order!r}")


def check_dip_deg(dip_deg: float | None) -> float | None:
    """Validate a reference dip parameter: None (measure it) or a float in [-90, 90] deg."""
    if dip_deg is None:
        return None
    if isinstance(dip_deg, bool) or not (np.isfinite(dip_deg) and -90.0 <= dip_deg <= 90.0):
        raise ValueError(
            f"dip_deg must be in [-90, 90] deg (positive down) or None to measure it, "
            f"got {dip_deg!r}"
        )
    return float(dip_deg)


@dataclass(kw_only=True)
class SingleFrameState(State):
    """State of a single-frame estimator: the last orientation and the prefilter history.

    quat : (S, 4) last valid orientation (repeated by degenerate samples).
    lowpass_history : (S, 2, 4, 3) direct-form-I history of the accelerometer (index 0) and
        magnetometer (1) filters, rows ``[x[n-1], x[n-2], y[n-1], y[n-2]]``, sensor units.
    lowpass_ready : (S, 2) bool, whether each filter has started (it starts in steady state
        at its first sample).
    """

    lowpass_history: Array
    lowpass_ready: NDArray[np.bool_]

    @classmethod
    def fresh(cls, quat0: Array, **extra: Array) -> SingleFrameState:
        """A state for S = len(quat0) sensors with the filters not yet started."""
        n_sensors = quat0.shape[0]
        return cls(
            quat=np.array(quat0, dtype=np.float64),
            lowpass_history=np.zeros((n_sensors, 2, 4, 3)),
            lowpass_ready=np.zeros((n_sensors, 2), dtype=np.bool_),
            **extra,
        )


@dataclass(kw_only=True)
class MeasuredDipState(SingleFrameState):
    """State of an estimator that compares the field with a reference vector (QUEST, ...).

    dip_rad : (S,) reference dip (inclination, positive down) measured from each sensor's
        first valid sample when the ``dip_deg`` parameter is None, rad; NaN until measured.
    """

    dip_rad: Array

    @classmethod
    def fresh(cls, quat0: Array, **extra: Array) -> SingleFrameState:
        """A state for S sensors, filters not started, dip not yet measured."""
        extra.setdefault("dip_rad", np.full(quat0.shape[0], np.nan))
        return super().fresh(quat0, **extra)


P = TypeVar("P", bound=LowpassParams)
S = TypeVar("S", bound=SingleFrameState)


class SingleFrameEstimator(Estimator[P, S]):
    """Base of the single-frame estimators: no gyroscope, magnetometer required, prefilter.

    Subclasses implement ``_process`` with one kernel call that takes :meth:`_lowpass_args`.
    """

    uses_gyr: ClassVar[bool] = False
    mag_optional: ClassVar[bool] = False

    def _new_state(self, quat0: Array) -> S:
        return SingleFrameState.fresh(quat0)  # type: ignore[return-value]

    def _initial_quat(self, acc0: Array, mag0: Array | None) -> Array:
        # every sample is measured on its own: nothing to initialise; a degenerate first
        # sample is flagged by the kernel instead of raising here
        return np.tile([1.0, 0.0, 0.0, 0.0], (acc0.shape[0], 1))

    def _lowpass_args(self, dt: Array) -> tuple[float, float, int]:
        """(acc cut-off, mag cut-off, order) for the kernel, 0.0 meaning off.

        Raises ``ValueError`` if a cut-off is not below half the lowest sample rate of ``dt``.
        """
        p = self.params
        dt_max = float(dt.max())
        for name in ("acc_lowpass_hz", "mag_lowpass_hz"):
            cutoff = getattr(p, name)
            if cutoff is not None and cutoff * dt_max >= 0.5:
                raise ValueError(
                    f"{name} = {cutoff} Hz is not below half the sample rate "
                    f"({0.5 / dt_max:.6g} Hz at the longest sample interval {dt_max:.6g} s); "
                    "lower the cut-off"
                )
        return (
            p.acc_lowpass_hz or 0.0,
            p.mag_lowpass_hz or 0.0,
            p.lowpass_order,
        )

    def _earth_axes(self) -> tuple[Array, Array]:
        """Unit up and unit horizontal (magnetic) north of the output frame, (3,) each."""
        frame = self.params.frame
        return frames.up(frame), frames.mag_reference(frame, dip_deg=0.0)


def dip_rad_or_nan(dip_deg: float | None) -> float:
    """The kernel's encoding of a dip parameter: radians, or NaN for "measure it"."""
    return math.nan if dip_deg is None else math.radians(dip_deg)
