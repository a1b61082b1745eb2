"""Assembling the guided procedure's measurements into a calibration (000, Appendix B 14, 17, 18).

What :class:`~margtrack.calibration.guided.GuidedCalibration` hands over: the still poses by
paper step (1, 3, 5, ..., 13 for the accelerometer; 18 the reference position), the known
turns with their integrated angles (steps 2-12), the magnetometer extremes of the two full
turns (steps 15, 16) and every magnetometer sample. From them:

- gyroscope: null from step 1, scale factors averaged per axis over the +90 and -180 (etc.)
  turns (000 eq. 5), and the full matrix (scale and misalignment) fitted to every turn's
  three integrated axes, 360 deg spins included, which goes into the file;
- accelerometer: six-position null and scale (step 14, eqs. 1-2) and the 12-parameter
  least-squares fit with the poses' known directions, which goes into the file;
- magnetometer: min/max (step 17, eqs. 3-4: x from step 15, y and z from step 16) and,
  when the procedure's many turns determine it, an ellipsoid fit of all samples with its
  axes aligned to the accelerometer's by the constant dip over the still poses, which goes
  into the file (else min/max does, with the reason in the notes);
- reference vectors (step 18) from the calibrated means.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from margtrack.calibration.accelerometer import (
    AccelFit,
    SixPosition,
    fit_known_directions,
    six_position,
)
from margtrack.calibration.calibration_file import Calibration, TriadCalibration
from margtrack.calibration.gyroscope import (
    GyroNull,
    GyroScale,
    RotationEstimate,
    fit_gyro_matrix,
    gyro_scale,
)
from margtrack.calibration.magnetometer import (
    EllipsoidFit,
    MinMax,
    align_to_gravity,
    fit_ellipsoid,
    min_max,
)
from margtrack.calibration.reference import ReferenceVectors, reference_vectors

Array = NDArray[np.float64]

__all__ = ["ACC_POSE_STEPS", "GuidedResult", "PoseRecord", "assemble"]

#: Paper steps whose still pose feeds the accelerometer (each axis up and down, +z twice).
ACC_POSE_STEPS = (1, 3, 5, 7, 9, 11, 13)


@dataclass(frozen=True)
class PoseRecord:
    """Means over one still pose: pose ("+y" = +y axis down), time span s, sample count,
    gyr mean and std (3,) rad/s, acc mean (3,) m/s², mag mean (3,) µT (all raw)."""

    pose: str
    t_start_s: float
    t_end_s: float
    n_samples: int
    gyr: Array
    gyr_std: Array
    acc: Array
    mag: Array


@dataclass(frozen=True)
class GuidedResult:
    """Everything the guided procedure found; ``calibration`` is what gets saved."""

    calibration: Calibration
    gyro_null: GyroNull
    gyro_scale: GyroScale
    six_position: SixPosition
    accel_fit: AccelFit
    min_max: MinMax
    ellipsoid: EllipsoidFit | None
    ellipsoid_error: str
    reference: ReferenceVectors
    poses: dict[int, PoseRecord]


def assemble(
    poses: dict[int, PoseRecord],
    rotations: list[tuple[int, int, float, float]],
    extremes: dict[int, tuple[Array, Array]],
    mag_all: Array,
    gravity_m_s2: float,
    smooth_samples: int,
    use_ellipsoid: bool,
) -> GuidedResult:
    """The calibration from the procedure's measurements (module docstring).

    ``rotations``: (paper step, body axis, known deg, integrated deg) per accepted turn;
    ``extremes``: step 15 and 16 -> (max, min) (3,) of the smoothed magnetometer.
    """
    missing = [s for s in (*ACC_POSE_STEPS, 18) if s not in poses]
    if missing or 15 not in extremes or 16 not in extremes:
        raise ValueError(f"the procedure is incomplete: steps {missing or [15, 16]} missing")
    first = poses[1]
    null = GyroNull(first.gyr, first.gyr_std / np.sqrt(first.n_samples), first.n_samples)
    turns = [RotationEstimate(axis, known, float(turned[axis]))
             for step, axis, known, turned in rotations if step <= 12]
    scale = gyro_scale(turns, null.null_rad_s)  # (000 eq. 5, averaged per axis)
    true = np.zeros((len(rotations), 3))
    for k, (_, axis, known, _) in enumerate(rotations):
        true[k, axis] = np.radians(known)
    measured = np.radians([turned for *_, turned in rotations])
    gyr_triad = TriadCalibration("gyr", fit_gyro_matrix(measured, true), null.null_rad_s,
                                 "rad/s", "null + full matrix from known turns (000 eq. 5 "
                                 "extended to misalignment)")
    acc_means = np.array([poses[s].acc for s in ACC_POSE_STEPS])
    sixpos = six_position(acc_means, gravity_m_s2)  # step 14 (000 eqs. 1-2)
    fit = fit_known_directions(acc_means, gravity_m_s2=gravity_m_s2)
    (hi15, lo15), (hi16, lo16) = extremes[15], extremes[16]
    hi = np.array([hi15[0], hi16[1], hi16[2]])
    lo = np.array([lo15[0], lo16[1], lo16[2]])
    minmax = min_max(None, max_ut=hi, min_ut=lo)  # step 17 (000 eqs. 3-4)
    notes = [
        f"gyro null from {null.n_samples} still samples; scale factors from "
        f"{len(turns)} known turns (000 eq. 5)",
        f"accelerometer: 12-parameter fit over {fit.n_poses} poses, RMS residual "
        f"{fit.rms_residual_m_s2:.4f} m/s²",
    ]
    ellipsoid: EllipsoidFit | None = None
    reason = "not attempted"
    if use_ellipsoid:
        try:
            ellipsoid = fit_ellipsoid(mag_all)
            reason = ""
        except ValueError as exc:
            reason = str(exc)
    acc_triad = fit.triad()
    pose_steps = [*ACC_POSE_STEPS, 18]
    up = acc_triad.correct(np.array([poses[s].acc for s in pose_steps]))
    pose_mag = np.array([poses[s].mag for s in pose_steps])
    if ellipsoid is not None:
        mag_triad, angle, rms = align_to_gravity(ellipsoid.triad(), up, pose_mag)
        notes.append(
            f"magnetometer: ellipsoid fit of {ellipsoid.n_samples} samples, residual spread "
            f"{100 * ellipsoid.residual_spread:.2f} %, sphere coverage "
            f"{100 * ellipsoid.coverage:.0f} %; axes turned {angle:.2f} deg onto the "
            f"accelerometer's (vertical-field residual {rms:.3f} µT)"
        )
    else:
        mag_triad = minmax.triad()
        notes.append(f"magnetometer: min/max (000 eqs. 3-4); ellipsoid fit: {reason}")
    ref = reference_vectors(acc_triad.correct(poses[18].acc), mag_triad.correct(poses[18].mag))
    calibration = Calibration(
        gyr=gyr_triad,
        acc=acc_triad,
        mag=mag_triad,
        reference=ref,
        source="guided procedure (000 Appendix B)",
        notes=tuple(notes),
    )
    return GuidedResult(calibration, null, scale, sixpos, fit, minmax, ellipsoid, reason, ref,
                        dict(poses))
