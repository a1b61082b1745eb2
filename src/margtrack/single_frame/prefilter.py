"""What every single-frame estimator shares: the optional low-pass prefilter, state, flags.

Single-frame estimators (TRIAD, FQA, QUEST, Davenport, Gauss-Newton, Newton) turn each
accelerometer + magnetometer sample into an orientation on its own. An accelerometer also
measures linear acceleration, so 002 (Fig. 5) puts a low-pass filter in front of the
estimator for moving sensors. Here that filter is a parameter of every single-frame
estimator: a first- or second-order Butterworth low-pass with a cut-off in Hz, on the
accelerometer and, separately, on the magnetometer (``None`` switches it off). Its history
lives in the state, so ``update`` one sample at a time, one ``run`` and runs split
anywhere give the same result.

Unusable samples never turn into NaN. The input screening zeroes a vector it cannot use
(the magnetometer also when its norm or dip is far from the reference: these methods have
no disturbance rejection of their own); the prefilter passes such a "no measurement"
through without filtering it in. Then, per sample (``degenerate`` output, int8):

- no accelerometer (code 1): the previous orientation is repeated (the initial one,
  identity unless ``reset(q0)`` gave one, if none came before); flag ``ACC_IGNORED``;
- no field (2), or a field within 0.06 deg of the accelerometer's direction (3), or (the
  fits only) singular normal equations (4): the heading cannot be measured, so the
  previous orientation is levelled onto the measured gravity: inclination from the
  accelerometer, heading kept (``kernels.triad.level``). Codes 3 and 4 are flagged
  ``MAG_IGNORED``; code 2 already carries the screening's reason (``MAG_IGNORED``, or
  ``MAG_DISTURBED``, which is not relabelled).

Every estimator returns quaternions with ``w >= 0``; :func:`margtrack.quaternion.continuous`
makes a series sign-continuous where that matters (002's closing remark on ``q`` and
``-q``). The field's unit does not matter: the kernels use its direction only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimator import Estimator, Flag, Params, State, param, triad_kernel

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
    1: "zero accelerometer vector (orientation held; ACC_IGNORED)",
    2: "zero magnetometer vector (levelled onto gravity, heading kept; flagged by the "
    "screening)",
    3: "accelerometer parallel to the magnetic field, less than 0.06 deg apart (levelled "
    "onto gravity, heading kept; MAG_IGNORED)",
    4: "fit failed: singular normal equations (levelled onto gravity, heading kept; "
    "MAG_IGNORED)",
}


@dataclass(frozen=True)
class LowpassParams(Params):
    """Parameters of the low-pass prefilter (002 Fig. 5), common to single-frame estimators.

    acc_lowpass_hz : cut-off of the accelerometer low-pass, Hz, or None (default) for no
        filter. Lowering it rejects more linear acceleration and delays the inclination
        more (a second-order filter delays a slow rotation by about ``0.225 / f_c`` s).
        Must stay below half the sample rate (checked against the typical interval of
        every run; a single longer interval, dropped samples, restarts the filter).
    mag_lowpass_hz : the same for the magnetometer, Hz, or None (default).
    lowpass_order : 1 or 2 (default): order of the Butterworth filter.

    The reference dip the Wahba estimators and the fits need is the shared
    ``mag_dip_ref_deg`` (None: measured from each sensor's first valid sample).
    """

    acc_lowpass_hz: float | None = param(
        None, unit="Hz", gt=0, help="acceleration low-pass cut-off, below half the rate (None: off)"
    )
    mag_lowpass_hz: float | None = param(
        None, unit="Hz", gt=0, help="field low-pass cut-off, below half the rate (None: off)"
    )
    lowpass_order: int = param(2, ge=1, le=2, help="order of the Butterworth low-pass, 1 or 2")


def check_dip_deg(dip_deg: float | None) -> float | None:
    """Validate a reference dip parameter: None (measure it) or a float in [-90, 90] deg.

    Kept for ``methods/ekf/__init__.py`` only (the single-frame estimators use the declared
    ``mag_dip_ref_deg``); remove it once the EKF does too.
    """
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
        first valid sample when the ``mag_dip_ref_deg`` parameter is None, rad; NaN until
        measured. A property of the place, not of the orientation: kept when the
        estimator restarts after a gap.
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

    Subclasses implement ``_process`` with one kernel call that takes :meth:`_lowpass_args`
    and return the kernel's codes as the ``degenerate`` output, which :meth:`_method_flags`
    maps onto the flags (see the module docstring). A restart after a gap starts the
    low-pass filters afresh and keeps a measured dip (``kept_on_restart``).
    """

    uses_gyr: ClassVar[bool] = False
    mag_optional: ClassVar[bool] = False
    kept_on_restart: ClassVar[tuple[str, ...]] = ("dip_rad",)

    def _new_state(self, quat0: Array) -> S:
        return SingleFrameState.fresh(quat0)  # type: ignore[return-value]

    def _initial_quat(self, acc0: Array, mag0: Array | None) -> Array:
        # every sample is measured on its own: nothing to initialise; a degenerate first
        # sample is flagged by the kernel instead of raising here
        return np.tile([1.0, 0.0, 0.0, 0.0], (acc0.shape[0], 1))

    def _method_flags(self, outputs: Mapping[str, NDArray[Any]]) -> NDArray[np.uint16] | None:
        """ACC_IGNORED for code 1, MAG_IGNORED for codes 3 and 4 of ``degenerate``.

        Code 2 (no field) adds nothing: every zero field the kernel sees was zeroed by the
        screening, which flagged why (MAG_IGNORED, or MAG_DISTURBED, not relabelled).
        """
        code = outputs["degenerate"]
        flags = np.where(code == triad_kernel.ZERO_ACC, np.uint16(Flag.ACC_IGNORED), np.uint16(0))
        no_heading = (code == triad_kernel.PARALLEL) | (code == triad_kernel.SOLVER_FAILED)
        flags[no_heading] |= np.uint16(Flag.MAG_IGNORED)
        base = super()._method_flags(outputs)
        return flags if base is None else flags | base

    def _lowpass_args(self, dt: Array) -> tuple[float, float, int]:
        """(acc cut-off, mag cut-off, order) for the kernel, 0.0 meaning off.

        Raises ``ValueError`` if a cut-off is not below half the sample rate: that of the
        typical (median) interval when ``dt`` has at least two, else ``rate_hz`` if the
        estimator was built with one. Intervals of 0 (first sample, gaps) do not count; a
        single longer interval (dropped samples) restarts the filter in the kernel instead.
        """
        p = self.params
        if p.acc_lowpass_hz is None and p.mag_lowpass_hz is None:
            return 0.0, 0.0, p.lowpass_order
        steps = dt[dt > 0.0]
        if steps.size >= 2:
            typical = float(np.median(steps))
            where = f"the typical sample interval {typical:.6g} s"
        elif self.rate_hz is not None:
            typical = 1.0 / self.rate_hz
            where = f"rate_hz = {self.rate_hz:g}"
        else:
            typical = 0.0
            where = ""
        for name in ("acc_lowpass_hz", "mag_lowpass_hz"):
            cutoff = getattr(p, name)
            if cutoff is not None and cutoff * typical >= 0.5:
                raise ValueError(
                    f"{name} = {cutoff} Hz is not below half the sample rate "
                    f"({0.5 / typical:.6g} Hz at {where}); lower the cut-off"
                )
        return p.acc_lowpass_hz or 0.0, p.mag_lowpass_hz or 0.0, p.lowpass_order

    def _dip_rad(self) -> float:
        """The kernel's encoding of ``mag_dip_ref_deg``: radians, or NaN for "measure it"."""
        return dip_rad_or_nan(self.params.mag_dip_ref_deg)

    def _earth_axes(self) -> tuple[Array, Array]:
        """Unit up and unit horizontal (magnetic) north of the output frame, (3,) each."""
        frame = self.params.frame
        return frames.up(frame), frames.mag_reference(frame, dip_deg=0.0)


def dip_rad_or_nan(dip_deg: float | None) -> float:
    """The kernel's encoding of a dip parameter: radians, or NaN for "measure it"."""
    return math.nan if dip_deg is None else math.radians(dip_deg)
