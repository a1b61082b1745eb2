"""The gyroscope null point taken from the still start of a recording (000, Appendix B step 1).

000 calibrates each rate sensor's null point by averaging its output while the sensor is
stationary ("Sensor Calibration"; Appendix B, step 1) and notes that an uncompensated
bias "will cause a steady state error in a complementary filter" ("Rate Sensor Bias
Compensation"): a bias b leaves an error of about b/k. Filters without a bias state
(Bachmann's, Marins' EKF) therefore take the null from the still period that starts a
recording, online and causally:

- from the first sample after a reset the sensor counts as still while each gyro sample is
  within :data:`GYR_TOLERANCE_DEG_S` of the mean so far and the accelerometer (and
  magnetometer) direction stays within :data:`ACC_TOLERANCE_DEG` (:data:`MAG_TOLERANCE_DEG`)
  of its mean so far;
- while still, the running mean is subtracted (the sensor is at rest, so the output holds);
- at the first moving sample the mean is frozen and used from then on, unless the still
  start lasted less than ``min_rest_s``, in which case no null is used.

The null is calibration, not orientation: a filter restarting after a gap keeps it (and,
if the still start was still being measured, goes on measuring it). Screened samples
(``margtrack.estimator.screening``) with a zero accelerometer or magnetometer vector say
nothing about the direction: they neither extend nor end the still start by that signal.

Give a calibrated gyroscope instead (``margtrack run --calibration``) and switch this off
with ``min_rest_s = 0``. Limitation: a rotation that is already under way at the first
sample at a constant rate (no gyro change) is only told from a bias by the turning
accelerometer and field, after 2 deg of tilt or 10 deg of field direction away from their
means: below about 4 deg/s about a horizontal axis (20 deg/s about the field without
gravity change) it would be taken for a null. Start recordings still, as 000 does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.methods import rest_null_kernel as kernel

Array = NDArray[np.float64]

#: Largest deviation of a still gyro sample from the mean so far, deg/s: above MEMS noise
#: (~0.1-0.5 deg/s per sample), below deliberate motion.
GYR_TOLERANCE_DEG_S = 3.0
#: Largest change of the accelerometer direction while still, deg.
ACC_TOLERANCE_DEG = 2.0
#: Largest change of the magnetometer direction while still, deg: BROAD's magnetometers
#: scatter by 3-5 deg from sample to sample at rest.
MAG_TOLERANCE_DEG = 10.0
#: A rate beyond this (rad/s, any axis) is no sensor's: such a sample is left out of the
#: null (the screening replaces it before; this keeps the kernel finite on its own).
MAX_RATE_RAD_S = 1e6


@dataclass
class RestNullState:
    """Progress of the initial-rest null for S sensors (arrays updated by the kernel).

    total_rad_s : (S, 3) sum of the still gyro samples, rad/s. count : (S,) their number.
    duration_s : (S,) their time span, s. acc_sum, mag_sum : (S, 3) the sums of their
    accelerometer and magnetometer vectors. still : (S,) True while the start is
    still (the null is being measured).
    """

    total_rad_s: Array
    count: NDArray[np.int64]
    duration_s: Array
    acc_sum: Array
    mag_sum: Array
    still: NDArray[np.bool_]

    @classmethod
    def new(cls, n_sensors: int) -> RestNullState:
        """Nothing measured yet, every sensor still."""
        return cls(
            total_rad_s=np.zeros((n_sensors, 3)),
            count=np.zeros(n_sensors, dtype=np.int64),
            duration_s=np.zeros(n_sensors),
            acc_sum=np.zeros((n_sensors, 3)),
            mag_sum=np.zeros((n_sensors, 3)),
            still=np.ones(n_sensors, dtype=np.bool_),
        )

    def copy(self) -> RestNullState:
        """An independent copy."""
        return RestNullState(
            self.total_rad_s.copy(), self.count.copy(), self.duration_s.copy(),
            self.acc_sum.copy(), self.mag_sum.copy(), self.still.copy(),
        )  # fmt: skip


def rest_null_rad_s(state: RestNullState, n_sensors: int) -> Array:
    """(S, 3) the null the state currently subtracts, rad/s (0 where none)."""
    if state.count.shape != (n_sensors,):
        return np.zeros((n_sensors, 3))
    count = np.maximum(state.count, 1)[:, None]
    return np.where(state.count[:, None] > 0, state.total_rad_s / count, 0.0)


def rest_null_coefficients(min_rest_s: float) -> Array:
    """The kernel's coefficients (``kernels.rest_null.N_RC``) for a minimum still start, s."""
    c = np.empty(kernel.N_RC)
    c[kernel.RC_MIN_REST] = min_rest_s
    c[kernel.RC_GYR_TOL] = np.radians(GYR_TOLERANCE_DEG_S)
    c[kernel.RC_ACC_COS] = np.cos(np.radians(ACC_TOLERANCE_DEG))
    c[kernel.RC_MAG_COS] = np.cos(np.radians(MAG_TOLERANCE_DEG))
    c[kernel.RC_MAX_RATE] = MAX_RATE_RAD_S
    return c


_FIELDS = (
    ("total_rad_s", kernel.RN_TOTAL, 3),
    ("count", kernel.RN_COUNT, 1),
    ("duration_s", kernel.RN_DURATION, 1),
    ("acc_sum", kernel.RN_ACC_SUM, 3),
    ("mag_sum", kernel.RN_MAG_SUM, 3),
    ("still", kernel.RN_STILL, 1),
)


def subtract_rest_null(
    state: RestNullState,
    gyr: Array,
    acc: Array,
    mag: Array | None,
    dt: Array,
    min_rest_s: float,
) -> tuple[Array, Array]:
    """Gyro minus its initial-rest null, and the null used, both (S, N, 3) rad/s.

    gyr, acc, mag (S, N, 3) body frame (mag None without a magnetometer), dt (N,) s; the
    state advances (an empty state, e.g. of a state set by hand, starts from scratch).
    ``min_rest_s <= 0`` returns the gyro unchanged and a zero null. The same per-sample
    step as the filters' compiled kernels (``kernels.rest_null.step_one``).
    """
    if state.count.size == 0:  # a state built without this part starts measuring now
        fresh = RestNullState.new(gyr.shape[0])
        for name, _, _ in _FIELDS:
            setattr(state, name, getattr(fresh, name))
    if state.count.shape != (gyr.shape[0],):
        raise ValueError(
            f"the rest-null state holds {state.count.shape[0]} sensor(s), the data "
            f"{gyr.shape[0]}; reset() first"
        )
    if min_rest_s <= 0.0:
        return gyr, np.zeros_like(gyr)
    blocks = np.zeros((gyr.shape[0], kernel.N_REST_NULL))
    for name, offset, width in _FIELDS:
        blocks[:, offset : offset + width] = np.asarray(getattr(state, name)).reshape(-1, width)
    blocks[:, kernel.RN_NULL : kernel.RN_NULL + 3] = rest_null_rad_s(state, gyr.shape[0])
    out = np.empty_like(gyr)
    null = np.empty_like(gyr)
    kernel.subtract_rest_null(
        gyr, acc, np.empty((gyr.shape[0], 0, 3)) if mag is None else mag, dt, blocks,
        rest_null_coefficients(float(min_rest_s)), out, null,
    )  # fmt: skip
    for name, offset, width in _FIELDS:
        part = blocks[:, offset : offset + width]
        current = getattr(state, name)
        current[...] = part.reshape(current.shape).astype(current.dtype)
    return out, null


# -- shared by the compiled filters that keep the null in their rows (bachmann, ekf) -------
def rest_null_layout(offset: int) -> dict[str, tuple[int, int]]:
    """Named slots of a null block at ``offset`` of a row (``state_layout`` entries)."""
    return {
        "rest_null_total_rad_s": (offset + kernel.RN_TOTAL, 3),
        "rest_null_count": (offset + kernel.RN_COUNT, 1),
        "rest_null_duration_s": (offset + kernel.RN_DURATION, 1),
        "rest_null_acc_sum": (offset + kernel.RN_ACC_SUM, 3),
        "rest_null_mag_sum": (offset + kernel.RN_MAG_SUM, 3),
        "rest_null_still": (offset + kernel.RN_STILL, 1),
    }


def check_rows(state: Any, n_row: int, q_offset: int, ready: NDArray[np.bool_]) -> None:
    """Refuse a state set by hand whose rows are not ``n_row`` wide or whose quaternion
    (4 slots at ``q_offset``) is zero or not finite in a started (``ready``) sensor."""
    rows = np.asarray(state.rows)
    if rows.ndim != 2 or rows.shape[1] != n_row:
        raise ValueError(f"the state rows must have shape (S, {n_row}), got {rows.shape}")
    q = rows[ready, q_offset : q_offset + 4]
    norms = np.linalg.norm(q, axis=1)
    if not np.all(np.isfinite(norms) & (norms > 0)):
        raise ValueError("the state quaternion must be finite and non-zero")
