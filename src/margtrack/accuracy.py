"""Orientation error metrics as used for BROAD: total, heading and inclination, in degrees;
and their running sums over a recording read in chunks (:class:`ErrorAccumulator`).

With ``e = q_est ⊗ q_true*`` (the error rotation in the earth frame, whose z axis is
vertical in both NED and ENU):

- total = ``2·acos(|e_w|)``
- heading = ``2·atan(|e_z / e_w|)`` (rotation about the vertical)
- inclination = ``2·acos(sqrt(e_w² + e_z²))`` (tilt of the vertical axis)

computed here in the equivalent ``atan2`` forms, which keep full precision for small
errors where ``acos`` near 1 loses half the digits.

Truth holes (NaN rows of ``quat_true``, where an optical system lost the markers) give NaN
errors, and :func:`rmse_deg` / :func:`summarize` skip them: an RMSE is over the samples that
are both counted (the mask) and known.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.recording import Recording

Array = NDArray[np.float64]

#: samples per block of :class:`ErrorAccumulator`'s error computation (bounds its temporary
#: arrays)
ERROR_BLOCK = 1 << 17

__all__ = ["ErrorAccumulator", "ErrorSeries", "ErrorSummary", "error_series", "rmse_deg",
           "summarize"]


@dataclass(frozen=True)
class ErrorSeries:
    """Per-sample errors (N,) in rad: total, heading and inclination."""

    total_rad: Array
    heading_rad: Array
    inclination_rad: Array


@dataclass(frozen=True)
class ErrorSummary:
    """RMSE of the errors over the counted samples, in degrees."""

    total_rmse_deg: float
    heading_rmse_deg: float
    inclination_rmse_deg: float
    n_samples: int

    def as_dict(self) -> dict[str, float]:
        """The three RMSE figures (and the sample count) as a dict."""
        return asdict(self)


def error_series(
    quat_est: ArrayLike,
    quat_true: ArrayLike,
    est_frame: str = "ENU",
    true_frame: str = "ENU",
) -> ErrorSeries:
    """Total, heading and inclination error (N,) rad of an estimate against the truth.

    Both (N, 4) [w, x, y, z], body to their earth frame; the estimate is converted to the
    truth's frame first. ``q`` and ``-q`` give the same errors. A truth row with a NaN (a
    hole) gives NaN errors at that sample.
    """
    est = frames.convert(quat_est, est_frame, true_frame)
    e = quat.multiply(est, quat.conjugate(np.asarray(quat_true, dtype=np.float64)))
    w, x, y, z = np.moveaxis(np.abs(e), -1, 0)
    total = 2.0 * np.arctan2(np.sqrt(x * x + y * y + z * z), w)
    heading = 2.0 * np.arctan2(z, w)
    inclination = 2.0 * np.arctan2(np.hypot(x, y), np.hypot(w, z))
    return ErrorSeries(total, heading, inclination)


def rmse_deg(error_rad: ArrayLike, mask: ArrayLike | None = None) -> float:
    """Root mean square of ``error_rad`` over ``mask`` (all samples if None), in degrees.

    NaN errors (truth holes) are skipped. Raises ``ValueError`` if no sample is left.
    """
    err = np.asarray(error_rad, dtype=np.float64)
    if mask is not None:
        err = err[np.asarray(mask, dtype=bool)]
    if err.size == 0:
        raise ValueError("no sample to evaluate: the mask selects none")
    err = err[~np.isnan(err)]
    if err.size == 0:
        raise ValueError("no sample to evaluate: the truth is missing (NaN) on every one")
    return float(np.degrees(np.sqrt(np.mean(err * err))))


def summarize(series: ErrorSeries, mask: ArrayLike | None = None) -> ErrorSummary:
    """RMSE in degrees of each error over ``mask`` (the BROAD ``movement`` samples).

    Samples whose truth is a hole (NaN error) are skipped; ``n_samples`` counts the samples
    used: in the mask and with truth.
    """
    known = ~np.isnan(series.total_rad)
    if mask is not None:
        known &= np.asarray(mask, dtype=bool)
    n = int(np.count_nonzero(known))
    return ErrorSummary(
        total_rmse_deg=rmse_deg(series.total_rad, mask),
        heading_rmse_deg=rmse_deg(series.heading_rad, mask),
        inclination_rmse_deg=rmse_deg(series.inclination_rad, mask),
        n_samples=n,
    )


class ErrorAccumulator:
    """Squared total/heading/inclination errors (rad²) summed over the scored samples.

    A sample is scored when it is in the recording's ``movement`` mask (every sample
    without one) and its truth is known (a NaN row of ``quat_true`` is a hole, skipped).
    :meth:`add` takes a whole recording or its successive chunks (each a Recording slice
    with its estimate); the RMSE is ``sqrt(sum / count)`` either way, so the figures of a
    chunked run equal those of the whole run to rounding (1e-12 relative).
    Errors follow :func:`error_series` (BROAD convention).
    """

    def __init__(self) -> None:
        self.sums_rad2 = np.zeros(3)
        self.count = 0  # scored samples
        self.selected = 0  # samples in the mask, with or without truth
        self.has_truth = False

    def add(self, recording: Recording, quat: ArrayLike, frame: str = "ENU") -> None:
        """Add the errors of ``quat`` (N, 4), body to ``frame``, against ``recording``.

        A recording without truth adds nothing (and :attr:`has_truth` stays False).
        """
        if recording.quat_true is None:
            return
        q = np.asarray(quat, dtype=np.float64)
        if q.shape != (recording.n_samples, 4):
            raise ValueError(
                f"the estimate has shape {q.shape}; recording {recording.name!r} needs "
                f"({recording.n_samples}, 4) quaternions [w, x, y, z]"
            )
        self.has_truth = True
        for start in range(0, recording.n_samples, ERROR_BLOCK):
            part = np.s_[start : start + ERROR_BLOCK]
            e = error_series(q[part], recording.quat_true[part], frame, recording.frame)
            mask = np.ones(e.total_rad.shape[0], dtype=bool)
            if recording.movement is not None:
                mask = np.asarray(recording.movement[part], dtype=bool)
            self.selected += int(np.count_nonzero(mask))
            mask = mask & ~np.isnan(e.total_rad)  # truth holes are skipped
            for k, err in enumerate((e.total_rad, e.heading_rad, e.inclination_rad)):
                counted = err[mask]
                self.sums_rad2[k] += float(np.dot(counted, counted))
            self.count += int(np.count_nonzero(mask))

    def summary(self) -> ErrorSummary:
        """The RMSE figures, deg; ``ValueError`` when no sample was scored (and why)."""
        if not self.has_truth:
            raise ValueError("no ground truth (quat_true) was given: no error to report")
        if self.selected == 0:
            raise ValueError("no sample to evaluate: the mask selects none")
        if self.count == 0:
            raise ValueError("no sample to evaluate: the truth is missing (NaN) on every one")
        total, heading, inclination = np.degrees(np.sqrt(self.sums_rad2 / self.count))
        return ErrorSummary(float(total), float(heading), float(inclination), self.count)

    def rmse_deg(self) -> tuple[float | None, float | None, float | None]:
        """(total, heading, inclination) RMSE, deg; Nones when no sample was scored."""
        if self.count == 0:
            return None, None, None
        s = self.summary()
        return s.total_rmse_deg, s.heading_rmse_deg, s.inclination_rmse_deg
