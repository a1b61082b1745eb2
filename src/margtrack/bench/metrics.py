"""Orientation error metrics as used for BROAD: total, heading and inclination, in degrees.

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

Array = NDArray[np.float64]

__all__ = ["ErrorSeries", "ErrorSummary", "error_series", "rmse_deg", "summarize"]


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
