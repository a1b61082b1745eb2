"""Gyroscope null from a still period and scale factors from known rotations (000 eq. 5).

Model (:mod:`margtrack.calibration.calibration_file`): ``y = K ω + b``. 000: "Determination
of the null point of an angular rate sensor can be accomplished by recording and averaging
over some time period the output of a static sensor"; the scale factor is
``known rotation / estimated rotation`` (eq. 5), "the estimated rotation term is the result
of integrating the output of the sensor with a scale factor of unity", and "it may be
desirable to make several estimates ... through several known positive and negative
rotations and then averaging the results". Integration follows the library's gyro
convention: sample ``i`` is the rate over ``(t[i-1], t[i]]``, so the angle turned over
samples ``start..stop-1`` is ``Σ_{i=start+1}^{stop-1} (y_i - b) (t_i - t_{i-1})``. A
rotation about body axis ``j`` is integrated on that axis alone, as the paper does.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.calibration.calibration_file import TriadCalibration

Array = NDArray[np.float64]

__all__ = [
    "GyroNull",
    "GyroScale",
    "GyroTurns",
    "RotationEstimate",
    "fit_gyro_matrix",
    "gyro_from_turns",
    "gyro_null",
    "gyro_scale",
    "integrate_rotation",
    "rotation_estimate",
]


@dataclass(frozen=True)
class GyroNull:
    """Null from a still period: null_rad_s (3,) mean rate; noise_floor_rad_s (3,) its
    standard error ``std / √n`` (the precision of the mean for white noise); n_samples."""

    null_rad_s: Array
    noise_floor_rad_s: Array
    n_samples: int


def gyro_null(gyr_still: ArrayLike) -> GyroNull:
    """Null point: the mean of a still sensor's readings (N, 3) rad/s, N >= 2 (000, Sensor
    Calibration)."""
    g = np.asarray(gyr_still, dtype=np.float64)
    if g.ndim != 2 or g.shape[1] != 3 or g.shape[0] < 2 or not np.all(np.isfinite(g)):
        raise ValueError(f"gyr_still must be a finite (N, 3) array with N >= 2, got {g.shape}")
    return GyroNull(g.mean(axis=0), g.std(axis=0, ddof=1) / np.sqrt(g.shape[0]), g.shape[0])


def integrate_rotation(t: ArrayLike, gyr: ArrayLike, null_rad_s: ArrayLike) -> Array:
    """Angle (3,) rad turned per axis from ``t[0]`` to ``t[-1]``, unity scale (module docstring).

    ``t`` (N,) s strictly increasing, ``gyr`` (N, 3) rad/s, ``null_rad_s`` (3,) subtracted.
    """
    t_arr = np.asarray(t, dtype=np.float64)
    g = np.asarray(gyr, dtype=np.float64)
    if t_arr.ndim != 1 or g.shape != (t_arr.shape[0], 3) or t_arr.shape[0] < 2:
        raise ValueError(f"t must be (N,) and gyr (N, 3) with N >= 2, got {t_arr.shape}, {g.shape}")
    dt = np.diff(t_arr)
    if np.any(dt <= 0.0):
        raise ValueError(f"t must be strictly increasing: see sample {int(np.argmin(dt)) + 1}")
    return ((g[1:] - np.asarray(null_rad_s, dtype=np.float64)) * dt[:, None]).sum(axis=0)


@dataclass(frozen=True)
class RotationEstimate:
    """One known rotation (000 eq. 5): axis (0, 1, 2 for x, y, z), known_deg (signed),
    integrated_deg (unity-scale integral on that axis), scale_factor = known / integrated."""

    axis: int
    known_deg: float
    integrated_deg: float

    @property
    def scale_factor(self) -> float:
        """000 eq. 5: ``known rotation / estimated rotation``."""
        return self.known_deg / self.integrated_deg


def rotation_estimate(
    t: ArrayLike, gyr: ArrayLike, null_rad_s: ArrayLike, known_deg: float,
    axis: int | None = None, tolerance: float = 0.25,
) -> RotationEstimate:
    """Eq. 5 for one rotation by ``known_deg`` (signed) about body ``axis`` (None: the axis
    that turned most), from samples spanning it (a still sample on each side is fine).

    Raises ``ValueError`` if the integral differs from ``known_deg`` by more than
    ``tolerance`` (a fraction: 0.25 = 25 %), which means a wrong axis, sign or angle.
    """
    angles = np.degrees(integrate_rotation(t, gyr, null_rad_s))
    j = int(np.argmax(np.abs(angles))) if axis is None else int(axis)
    if j not in (0, 1, 2):
        raise ValueError(f"axis must be 0, 1 or 2 (x, y, z), got {axis!r}")
    if not (np.isfinite(known_deg) and known_deg != 0.0):
        raise ValueError(f"known_deg must be a finite non-zero angle, got {known_deg!r}")
    if abs(angles[j] / known_deg - 1.0) > tolerance:
        raise ValueError(
            f"the {'xyz'[j]} gyro integrates to {angles[j]:.1f} deg but the rotation is "
            f"{known_deg:g} deg (more than {100 * tolerance:.0f} % off): wrong axis, direction "
            "or angle, or the null is wrong"
        )
    return RotationEstimate(j, float(known_deg), float(angles[j]))


@dataclass(frozen=True)
class GyroScale:
    """Per-axis scale factors averaged over the rotations about each axis (000 eq. 5).

    scale_factor (3,) : mean of eq. 5 over that axis's rotations (multiplier).
    spread (3,) : half the range of the per-rotation factors (0 with one rotation).
    rotations : the estimates used. null_rad_s (3,) : the null that was subtracted.
    """

    scale_factor: Array
    spread: Array
    rotations: tuple[RotationEstimate, ...]
    null_rad_s: Array

    def triad(self) -> TriadCalibration:
        """As a calibration: ``K = diag(1 / scale_factor)``, ``b = null``."""
        return TriadCalibration("gyr", np.diag(1.0 / self.scale_factor), self.null_rad_s,
                                "rad/s", "null + known rotations (000 eq. 5)")


def gyro_scale(rotations: Sequence[RotationEstimate], null_rad_s: ArrayLike) -> GyroScale:
    """Average eq. 5 per axis over positive and negative rotations (000: "averaging the results").

    Every axis needs at least one rotation, else ``ValueError`` naming the missing ones.
    """
    rotations = tuple(rotations)
    factors: list[list[float]] = [[], [], []]
    for r in rotations:
        factors[r.axis].append(r.scale_factor)
    missing = [a for a, f in zip("xyz", factors, strict=True) if not f]
    if missing:
        raise ValueError(f"no known rotation about the {', '.join(missing)} axis: turn about it")
    mean = np.array([np.mean(f) for f in factors])
    spread = np.array([0.5 * (max(f) - min(f)) for f in factors])
    return GyroScale(mean, spread, rotations, np.asarray(null_rad_s, dtype=np.float64))


def fit_gyro_matrix(measured_rad: ArrayLike, true_rad: ArrayLike) -> Array:
    """Full gyro matrix K (3, 3) from turns about known body axes: ``θ_measured = K θ_true``.

    ``measured_rad`` (T, 3): each turn's unity-scale integral of all three axes (null
    removed); ``true_rad`` (T, 3): its known rotation vector (axis · angle) in body axes.
    For a turn about a fixed axis the integrated body rate is exactly that rotation
    vector, so the model is linear: eq. 5 extended from the diagonal to the misalignment
    terms. Needs turns about three independent axes, else ``ValueError``.
    """
    meas = np.asarray(measured_rad, dtype=np.float64)
    true = np.asarray(true_rad, dtype=np.float64)
    if meas.ndim != 2 or meas.shape[1] != 3 or meas.shape != true.shape:
        raise ValueError(f"measured and true must both be (T, 3), got {meas.shape}, {true.shape}")
    if np.linalg.matrix_rank(true, tol=1e-6 * np.abs(true).max()) < 3:
        raise ValueError("the turns must be about three independent axes to determine K")
    solution, *_ = np.linalg.lstsq(true, meas, rcond=None)  # meas = true @ K^T
    return solution.T


@dataclass(frozen=True)
class GyroTurns:
    """Gyroscope null and eq. 5 scale factors found from a recording of turns between holds.

    null : from the first still period. rotations : the turns accepted, in time order,
    each a whole multiple of the known angle about one axis. skipped_deg : the integrated
    angles (3,) deg of the turns that were not (listed for the user). scale : eq. 5
    averaged per axis (:func:`gyro_scale`).
    """

    null: GyroNull
    rotations: tuple[RotationEstimate, ...]
    skipped_deg: tuple[Array, ...]
    scale: GyroScale


def gyro_from_turns(
    t: ArrayLike, gyr: ArrayLike, still_segments: Sequence[tuple[int, int]],
    angle_deg: float = 90.0, tolerance: float = 0.05,
) -> GyroTurns:
    """Null (first still period) and per-axis scale factors from the turns between holds.

    Parameters
    ----------
    t : (N,) s, increasing. gyr : (N, 3) rad/s, raw.
    still_segments : the holds as ``(start, stop)`` sample pairs in time order
        (:func:`margtrack.calibration.static.static_segments`); the first is the null's.
    angle_deg : every turn is a whole multiple of it about one body axis (90: from face to
        face of a box); a turn's known angle is the nearest non-zero multiple of its
        integral on the axis that turned most.
    tolerance : a turn whose integral is further than this fraction from that multiple
        is skipped (it was not about one axis, or not a multiple).

    Raises ``ValueError`` with fewer than two holds, or when an axis has no accepted turn.
    """
    t_arr = np.asarray(t, dtype=np.float64)
    g = np.asarray(gyr, dtype=np.float64)
    if not (np.isfinite(angle_deg) and angle_deg > 0.0):
        raise ValueError(f"angle_deg must be a finite angle > 0, got {angle_deg!r}")
    if len(still_segments) < 2:
        raise ValueError(f"found {len(still_segments)} still period(s); need a still start "
                         "and turns between holds")
    first = still_segments[0]
    null = gyro_null(g[first[0]:first[1]])
    turns: list[RotationEstimate] = []
    skipped: list[Array] = []
    for (_, stop), (start, _) in itertools.pairwise(still_segments):
        s = slice(stop - 1, start + 1)  # from the last still sample to the next one
        angles = np.degrees(integrate_rotation(t_arr[s], g[s], null.null_rad_s))
        axis = int(np.argmax(np.abs(angles)))
        known = angle_deg * round(angles[axis] / angle_deg)
        if known == 0.0 or abs(angles[axis] / known - 1.0) > tolerance:
            skipped.append(angles)
            continue
        turns.append(rotation_estimate(t_arr[s], g[s], null.null_rad_s, known, axis, tolerance))
    try:
        scale = gyro_scale(turns, null.null_rad_s)
    except ValueError as exc:
        listed = "; ".join(str(np.round(a, 1).tolist()) for a in skipped)
        hint = f" ({len(skipped)} turn(s) skipped, integrated deg: {listed})" if skipped else ""
        raise ValueError(f"{exc}{hint}") from None
    return GyroTurns(null, tuple(turns), tuple(skipped), scale)
