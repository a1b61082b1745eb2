"""Accelerometer calibration from still poses: six-position (000 eqs. 1-2) and least squares.

Model (:mod:`margtrack.calibration.calibration_file`): ``y = K a + b`` with ``a`` the true
specific force (at rest ``g · u``, ``u`` the body-frame unit vector pointing up) and ``b``
the null. Three estimators, from the mean readings of still poses:

- :func:`six_position`: each axis up and down once; null and scale per axis (000 eqs. 1-2),
  ``K`` diagonal. Misalignment stays in the data (it is second order in the axis readings).
- :func:`fit_known_directions`: the 12-parameter linear model (all of ``K`` and ``b``) by
  linear least squares when the up direction of each pose is known in body axes, e.g. the
  faces of a box on a level table (nearest signed axis, checked within ``max_tilt_deg``).
- :func:`fit_norm`: any set of at least 9 poses in unknown orientations, fitting
  ``|K⁻¹ (y_k - b)| = g``. Gravity's magnitude cannot reveal a rotation of the whole triad,
  so 3 of the 12 parameters are fixed by convention: ``K`` lower triangular (the sensor's x
  axis defines body x, its x-y plane body x-y, as in :class:`margtrack.sim.SensorErrors`).

:func:`choose_accel_model` fits all three and picks the one with the most parameters that
the poses determine (``margtrack calibrate accel`` and ``benchmarks/calibration_report.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from margtrack.calibration.calibration_file import TriadCalibration
from margtrack.frames import STANDARD_GRAVITY_M_S2

Array = NDArray[np.float64]

__all__ = ["ACCEL_MODELS", "AccelFit", "AccelModelChoice", "SixPosition", "choose_accel_model",
           "fit_known_directions", "fit_norm", "nearest_axes", "six_position"]

_AXES = "xyz"


def _poses(pose_means: ArrayLike, minimum: int) -> Array:
    y = np.asarray(pose_means, dtype=np.float64)
    if y.ndim != 2 or y.shape[1] != 3 or not np.all(np.isfinite(y)):
        raise ValueError(f"pose_means must be a finite (K, 3) array, got shape {y.shape}")
    if y.shape[0] < minimum:
        raise ValueError(f"need at least {minimum} still poses, got {y.shape[0]}")
    if np.any(np.linalg.norm(y, axis=1) == 0.0):
        raise ValueError("a pose mean is the zero vector; is the accelerometer connected?")
    return y


def nearest_axes(pose_means: ArrayLike, max_tilt_deg: float = 10.0) -> Array:
    """(K, 3) signed unit body axis nearest to each pose's measured up direction.

    Raises ``ValueError`` naming the pose if its reading is more than ``max_tilt_deg`` from
    every axis (the pose is not a face of the box).
    """
    y = _poses(pose_means, 1)
    u = y / np.linalg.norm(y, axis=1)[:, None]
    axis = np.argmax(np.abs(u), axis=1)
    rows = np.arange(u.shape[0])
    tilt = np.degrees(np.arccos(np.clip(np.abs(u[rows, axis]), 0.0, 1.0)))
    bad = np.flatnonzero(tilt > max_tilt_deg)
    if bad.size:
        k = int(bad[0])
        raise ValueError(
            f"pose {k} is tilted {tilt[k]:.1f} deg from the nearest axis (> {max_tilt_deg} "
            "deg): place the sensor flat on one face, or use fit_norm for free poses"
        )
    out = np.zeros_like(u)
    out[rows, axis] = np.sign(u[rows, axis])
    return out


@dataclass(frozen=True)
class SixPosition:
    """Six-position result (000 eqs. 1-2), per axis (3,).

    max_m_s2 / min_m_s2 : mean reading with that axis up / down (specific force points up,
        so "up" reads +g). null_m_s2 : eq. 1, ``(max + min) / 2``. scale : eq. 2, the
        multiplier ``2 g / (max - min)`` that makes the nulled reading ±g.
    """

    max_m_s2: Array
    min_m_s2: Array
    null_m_s2: Array
    scale: Array
    gravity_m_s2: float

    def triad(self) -> TriadCalibration:
        """As a calibration: ``K = diag(1 / scale)``, ``b = null``."""
        return TriadCalibration("acc", np.diag(1.0 / self.scale), self.null_m_s2, "m/s2",
                                "six-position (000 eqs. 1-2)")


def six_position(
    pose_means: ArrayLike, gravity_m_s2: float = STANDARD_GRAVITY_M_S2, max_tilt_deg: float = 10.0
) -> SixPosition:
    """Null and scale per axis (000 eqs. 1-2) from still poses with each axis up and down.

    ``pose_means`` (K, 3) m/s², K >= 6: mean reading of each still pose, in any order. For
    each axis the poses within ``max_tilt_deg`` of it pointing up (down) are averaged into
    its max (min) reading; a missing direction raises ``ValueError`` saying which.
    """
    y = _poses(pose_means, 6)
    up = nearest_axes(y, max_tilt_deg)
    hi, lo = np.empty(3), np.empty(3)
    for i in range(3):
        for sign, out, word in ((1.0, hi, "up"), (-1.0, lo, "down")):
            sel = up[:, i] == sign
            if not np.any(sel):
                raise ValueError(
                    f"no still pose with the +{_AXES[i]} axis pointing {word}: the six-position "
                    "method needs each axis up once and down once"
                )
            out[i] = y[sel, i].mean()
    null = 0.5 * (hi + lo)  # (000, eq. 1)
    scale = 2.0 * gravity_m_s2 / (hi - lo)  # (000, eq. 2), "accel units" = g in m/s²
    return SixPosition(hi, lo, null, scale, float(gravity_m_s2))


@dataclass(frozen=True)
class AccelFit:
    """Least-squares accelerometer model ``y = K g u + b`` and its residuals.

    matrix : K (3, 3). bias : b (3,) m/s². residuals_m_s2 : (K, 3) reading minus model
    (:func:`fit_known_directions`) or (K,) ``|K⁻¹ (y - b)| - g`` (:func:`fit_norm`).
    rms_residual_m_s2 : their root mean square. n_poses : K. model : which fit.
    """

    matrix: Array
    bias: Array
    residuals_m_s2: Array
    rms_residual_m_s2: float
    n_poses: int
    model: str
    gravity_m_s2: float

    def triad(self) -> TriadCalibration:
        """As a calibration (``K``, ``b``)."""
        return TriadCalibration("acc", self.matrix, self.bias, "m/s2", self.model)


def fit_known_directions(
    pose_means: ArrayLike,
    up_body: ArrayLike | None = None,
    gravity_m_s2: float = STANDARD_GRAVITY_M_S2,
    max_tilt_deg: float = 10.0,
) -> AccelFit:
    """All 12 parameters (K and b) by linear least squares, poses' up directions known.

    ``pose_means`` (K, 3) m/s², K >= 4; ``up_body`` (K, 3) unit up vectors in body axes, or
    None for the nearest signed axis of each pose (:func:`nearest_axes`). Each pose gives
    ``y_k = K (g u_k) + b``: three equations linear in ``[K | b]``. The directions must span
    3-D with an offset (``[g u_k, 1]`` of rank 4), else ``ValueError``.
    """
    y = _poses(pose_means, 4)
    u = nearest_axes(y, max_tilt_deg) if up_body is None else np.asarray(up_body, dtype=float)
    if u.shape != y.shape:
        raise ValueError(f"up_body must have the shape of pose_means {y.shape}, got {u.shape}")
    design = np.hstack([gravity_m_s2 * u, np.ones((y.shape[0], 1))])
    if np.linalg.matrix_rank(design, tol=1e-6 * gravity_m_s2) < 4:
        raise ValueError(
            "the poses' up directions do not determine the model: use poses with each axis "
            "up and down (or at least four non-coplanar directions)"
        )
    solution, *_ = np.linalg.lstsq(design, y, rcond=None)
    k, b = solution[:3].T, solution[3]
    residuals = y - design @ solution
    return AccelFit(k, b, residuals, float(np.sqrt(np.mean(residuals**2))), y.shape[0],
                    "12-parameter least squares, known pose directions", float(gravity_m_s2))


def _lower(p: Array) -> Array:
    return np.array([[p[0], 0.0, 0.0], [p[1], p[2], 0.0], [p[3], p[4], p[5]]])


def fit_norm(
    pose_means: ArrayLike, gravity_m_s2: float = STANDARD_GRAVITY_M_S2,
    start: TriadCalibration | None = None,
) -> AccelFit:
    """Lower-triangular K and b from >= 9 still poses in any orientations (module docstring).

    Minimises ``Σ_k (|K⁻¹ (y_k - b)| - g)²`` (Levenberg-Marquardt, from ``start`` or from
    ``K = I``, ``b = 0``). Raises ``ValueError`` if the poses do not determine the 9
    parameters (too few, or not spread over enough directions: the Jacobian is rank
    deficient), saying to add tilted poses.
    """
    y = _poses(pose_means, 9)
    k0 = np.eye(3) if start is None else start.K
    b0 = np.zeros(3) if start is None else start.b
    if start is not None and np.any(np.triu(k0, 1) != 0.0):
        k0 = np.linalg.cholesky(k0 @ k0.T)  # the lower-triangular K with the same K K^T
    p0 = np.concatenate([k0[np.tril_indices(3)], b0])

    def residual(p: Array) -> Array:
        x = np.linalg.solve(_lower(p[:6]), (y - p[6:]).T).T
        return np.linalg.norm(x, axis=1) - gravity_m_s2

    sol = least_squares(residual, p0, method="lm", x_scale="jac")
    sv = np.linalg.svd(sol.jac, compute_uv=False)
    if sv[-1] < 1e-6 * sv[0]:
        raise ValueError(
            f"the {y.shape[0]} poses do not determine the 9-parameter model (their directions "
            "are too alike): add poses with the sensor tilted between the axes"
        )
    k = _lower(sol.x[:6])
    if np.any(np.diag(k) < 0.0):  # the sign of each axis is fixed by K's positive diagonal
        k = k * np.sign(np.diag(k))[None, :]
    res = residual(np.concatenate([k[np.tril_indices(3)], sol.x[6:]]))
    return AccelFit(k, sol.x[6:], res, float(np.sqrt(np.mean(res**2))), y.shape[0],
                    "9-parameter norm fit, lower-triangular K", float(gravity_m_s2))


@dataclass(frozen=True)
class AccelModelChoice:
    """Every accelerometer model fitted to one set of still poses, and the one to use.

    fits : the least-squares fits that succeeded, by name ("known directions", "norm").
    six : the six-position result (000 eqs. 1-2), or None when the poses lack an axis.
    failures : why a model could not be fitted, by name (the ``ValueError`` message).
    chosen_name : the model used; chosen : it as a calibration.
    """

    fits: dict[str, AccelFit]
    six: SixPosition | None
    failures: dict[str, str]
    chosen_name: str
    chosen: TriadCalibration


#: the order of preference of :func:`choose_accel_model`: the most parameters first
ACCEL_MODELS = ("known directions", "norm", "six-position")


def choose_accel_model(
    pose_means: ArrayLike, gravity_m_s2: float = STANDARD_GRAVITY_M_S2
) -> AccelModelChoice:
    """Fit every model to the still poses and choose the one with the most parameters.

    The order is :data:`ACCEL_MODELS`: the 12-parameter fit with the poses' directions
    known (faces of a box), else the 9-parameter norm fit (free poses), else six-position
    (000 eqs. 1-2). ``pose_means`` (K, 3) m/s² are the mean readings of the still poses
    (:func:`margtrack.calibration.static.segment_means`). Raises ``ValueError`` listing why
    each model failed when none can be fitted ("record each axis up and down").
    """
    fits: dict[str, AccelFit] = {}
    failures: dict[str, str] = {}
    for name, fit in (("known directions", fit_known_directions), ("norm", fit_norm)):
        try:
            fits[name] = fit(pose_means, gravity_m_s2=gravity_m_s2)
        except ValueError as exc:
            failures[name] = str(exc)
    six = None
    try:
        six = six_position(pose_means, gravity_m_s2)
    except ValueError as exc:
        failures["six-position"] = str(exc)
    candidates = {**{k: f.triad() for k, f in fits.items()},
                  **({"six-position": six.triad()} if six is not None else {})}
    for name in ACCEL_MODELS:
        if name in candidates:
            return AccelModelChoice(fits, six, failures, name, candidates[name])
    reasons = "; ".join(f"{k}: {v}" for k, v in failures.items())
    raise ValueError(
        f"no accelerometer model could be fitted ({reasons}): record each axis up and down"
    )
