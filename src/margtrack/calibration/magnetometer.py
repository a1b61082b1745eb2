"""Magnetometer calibration: min/max null and scale (000 eqs. 3-4) and an ellipsoid fit.

Model (:mod:`margtrack.calibration.calibration_file`): ``y = K h + b`` with ``h`` the
field in body axes, ``|h| = F`` everywhere in a clean place; ``b`` is the hard-iron offset,
``K`` the soft-iron (and scale, misalignment) matrix. The readings of a freely rotated
sensor lie on the ellipsoid ``(y - b)ᵀ (K Kᵀ)⁻¹ (y - b) = F²``.

- :func:`min_max`: 000's method. Per axis the null is the mid-range and the scale the
  multiplier to ±F (eqs. 3-4) from 360 deg turns that bring each axis to magnetic north
  and south. ``K`` diagonal; its known limits: cross-axis soft iron is not seen, an axis
  that never points along the field gives too small a range, and noise widens the range
  (the extremes are taken after a short moving average to tame it).
- :func:`align_to_gravity`: the rotation the ellipsoid cannot see, from still poses whose
  vertical the calibrated accelerometer measures: the field's vertical component
  ``-F sin(dip)`` is the same in every pose, which fixes the magnetometer's axes to the
  accelerometer's (the body's), turning ``S`` into a full ``K``.
- :func:`fit_ellipsoid`: algebraic least-squares quadric, then a geometric refinement of
  ``|S⁻¹ (y - b)| = F``, with ``S`` symmetric positive definite. The field alone fixes
  ``K Kᵀ`` but not a rotation of the triad, so ``S = (K Kᵀ)^½`` (the symmetric soft-iron
  matrix). Quality figures: residual spread and sphere coverage; data spread too thinly to
  determine the ellipsoid (too little rotation) raises ``ValueError``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import sqrtm
from scipy.optimize import least_squares

from margtrack.calibration.calibration_file import TriadCalibration

Array = NDArray[np.float64]

__all__ = ["EllipsoidFit", "MinMax", "align_to_gravity", "fit_ellipsoid", "min_max",
           "sphere_coverage"]


# The readings' widest spread must exceed the noise this many times (a still sensor's
# readings spread by the noise alone, in every direction alike).
_MIN_SPREAD_OVER_NOISE = 20.0


def _mag(mag: ArrayLike, minimum: int) -> Array:
    m = np.asarray(mag, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != 3:
        raise ValueError(f"mag must have shape (N, 3), got {m.shape}")
    bad = np.argwhere(~np.isfinite(m))
    if bad.size:
        raise ValueError(f"mag has a non-finite value at sample {int(bad[0, 0])}")
    if m.shape[0] < minimum:
        raise ValueError(f"need at least {minimum} magnetometer samples, got {m.shape[0]}")
    return m


@dataclass(frozen=True)
class MinMax:
    """Min/max result (000 eqs. 3-4), per axis (3,), µT.

    max_ut / min_ut : extreme readings. null_ut : eq. 3, ``(max + min) / 2``.
    scale : eq. 4, the multiplier ``2 F / (max - min)`` making the nulled reading ±F.
    field_ut : F used.
    """

    max_ut: Array
    min_ut: Array
    null_ut: Array
    scale: Array
    field_ut: float

    def triad(self) -> TriadCalibration:
        """As a calibration: ``K = diag(1 / scale)``, ``b = null``."""
        return TriadCalibration("mag", np.diag(1.0 / self.scale), self.null_ut, "uT",
                                "min/max (000 eqs. 3-4)")


def _smooth(m: Array, samples: int) -> Array:
    if samples <= 1:
        return m
    kernel = np.ones(samples) / samples
    return np.stack([np.convolve(m[:, i], kernel, mode="valid") for i in range(3)], axis=1)


def min_max(
    mag: ArrayLike,
    field_ut: float | None = None,
    smooth_samples: int = 5,
    max_ut: ArrayLike | None = None,
    min_ut: ArrayLike | None = None,
) -> MinMax:
    """Null and scale per axis (000 eqs. 3-4) from readings (N, 3) µT covering ±F on each axis.

    The extremes are taken after a ``smooth_samples`` moving average (noise would widen the
    range); ``max_ut``/``min_ut`` (3,) override them when the extremes come from separate
    turns (000 steps 15-16). ``field_ut`` is F; None uses the mean half-range, so the
    corrected field keeps the sensor's average unit.
    """
    if max_ut is None or min_ut is None:
        m = _smooth(_mag(mag, 2), int(smooth_samples))
        hi = m.max(axis=0) if max_ut is None else np.asarray(max_ut, dtype=float)
        lo = m.min(axis=0) if min_ut is None else np.asarray(min_ut, dtype=float)
    else:
        hi, lo = np.asarray(max_ut, dtype=float), np.asarray(min_ut, dtype=float)
    half = 0.5 * (hi - lo)
    if np.any(half <= 0.0):
        i = int(np.argmin(half))
        raise ValueError(f"axis {'xyz'[i]} never changed: turn the sensor so it sees ±F")
    field = float(np.mean(half)) if field_ut is None else float(field_ut)
    if not (np.isfinite(field) and field > 0.0):
        raise ValueError(f"field_ut must be a finite number > 0, got {field_ut!r}")
    null = 0.5 * (hi + lo)  # (000, eq. 3)
    scale = 2.0 * field / (hi - lo)  # (000, eq. 4), "mag units" = F
    return MinMax(hi, lo, null, scale, field)


def _fibonacci_sphere(n: int) -> Array:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def sphere_coverage(directions: ArrayLike, n_bins: int = 100) -> float:
    """Fraction of ``n_bins`` equal-area patches of the unit sphere that ``directions`` visit.

    ``directions`` (N, 3), any length (normalised here). Patches are the Voronoi cells of a
    Fibonacci lattice (about 23 deg across for 100). A full tumble gives ~1; one 360 deg
    turn about one axis ~0.2 (a great circle crosses ~20 cells); the whole 18-step procedure
    ~0.65.
    """
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=1)[:, None]
    centres = _fibonacci_sphere(n_bins)
    nearest = np.argmax(d @ centres.T, axis=1)
    return float(np.unique(nearest).size / n_bins)


@dataclass(frozen=True)
class EllipsoidFit:
    """Hard and soft iron from an ellipsoid fit: ``y = S h + b`` with ``|h| = F``.

    offset_ut : b (3,) hard iron, µT. soft_iron : S (3, 3) symmetric positive definite.
    field_ut : F. residual_rms_ut : RMS of ``|S⁻¹ (y - b)| - F``. residual_spread : that RMS
    over F (relative). coverage : :func:`sphere_coverage` of the corrected directions.
    thinnest_spread : smallest over largest principal spread of the readings (0: a plane).
    n_samples : N.
    """

    offset_ut: Array
    soft_iron: Array
    field_ut: float
    residual_rms_ut: float
    residual_spread: float
    coverage: float
    thinnest_spread: float
    n_samples: int

    def triad(self) -> TriadCalibration:
        """As a calibration: ``K = S``, ``b`` = hard-iron offset."""
        return TriadCalibration("mag", self.soft_iron, self.offset_ut, "uT",
                                "ellipsoid fit (hard + soft iron)")

    def correct(self, mag: ArrayLike) -> Array:
        """``S⁻¹ (y - b)`` for readings (N, 3)."""
        return self.triad().correct(mag)


def _algebraic(m: Array) -> tuple[Array, Array]:
    """Centre and shape ``Q`` (``(y - c)ᵀ Q (y - c) = 1``) of the least-squares quadric."""
    centre0 = m.mean(axis=0)
    scale0 = np.abs(m - centre0).max()
    x, y, z = ((m - centre0) / scale0).T
    design = np.stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z,
                       2 * x, 2 * y, 2 * z, np.ones_like(x)], axis=1)
    _, _, vt = np.linalg.svd(design, full_matrices=False)
    v = vt[-1]
    a = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    centre = -np.linalg.solve(a, v[6:9])
    k = centre @ a @ centre - v[9]
    q = a / k
    if np.any(np.linalg.eigvalsh(q) <= 0.0):
        raise ValueError(
            "the readings do not lie on an ellipsoid (the fitted quadric is not one): rotate "
            "the sensor through more orientations, away from magnets and metal"
        )
    return centre0 + centre * scale0, q / scale0**2


def fit_ellipsoid(
    mag: ArrayLike,
    field_ut: float | None = None,
    min_thinnest_spread: float = 0.2,
    min_coverage: float = 0.15,
) -> EllipsoidFit:
    """Hard-iron offset and symmetric soft-iron matrix from freely rotated readings (N, 3) µT.

    ``field_ut``: F the corrected field should have; None keeps the sensor's average unit
    (``det S = 1``). Raises ``ValueError`` when the data cannot determine the ellipsoid:
    fewer than 50 samples, readings spread less than 20x their noise (a still sensor),
    readings spread in their thinnest principal direction less than
    ``min_thinnest_spread`` times their widest (turns about one axis only), or corrected
    directions covering less than ``min_coverage`` of the sphere.
    """
    m = _mag(mag, 50)
    centred = m - m.mean(axis=0)
    eig = np.linalg.eigvalsh(centred.T @ centred / m.shape[0])
    # white noise from second differences (smooth turning cancels): std(d²y) = √6 σ
    noise = float(np.sqrt(np.mean(np.diff(m, 2, axis=0) ** 2) / 6.0))
    if np.sqrt(max(eig[-1], 0.0)) < _MIN_SPREAD_OVER_NOISE * noise or eig[-1] <= 0.0:
        raise ValueError(
            f"too little rotation to fit an ellipsoid: the readings spread only "
            f"{np.sqrt(max(eig[-1], 0.0)):.3g} µT, {_MIN_SPREAD_OVER_NOISE}x less than "
            f"needed over their noise ({noise:.3g} µT); turn the sensor about all three axes"
        )
    thinnest = float(np.sqrt(max(eig[0], 0.0) / eig[-1]))
    if thinnest < min_thinnest_spread:
        raise ValueError(
            f"too little rotation to fit an ellipsoid: the readings spread {100 * thinnest:.0f} % "
            f"as much in their thinnest direction as in their widest (need "
            f"{100 * min_thinnest_spread:.0f} %); turn the sensor about all three axes"
        )
    centre, q = _algebraic(m)
    # shape: (y - c)ᵀ Q (y - c) = 1 = |S⁻¹ (y - c)|² / F²  =>  S S = Q⁻¹ / F²
    semi = np.real(sqrtm(np.linalg.inv(q)))
    semi = 0.5 * (semi + semi.T)
    field = float(np.linalg.det(semi) ** (1.0 / 3.0)) if field_ut is None else float(field_ut)
    if not (np.isfinite(field) and field > 0.0):
        raise ValueError(f"field_ut must be a finite number > 0, got {field_ut!r}")
    inv0 = np.linalg.inv(semi / field)
    iu = np.triu_indices(3)

    def unpack(p: Array) -> tuple[Array, Array]:
        w = np.zeros((3, 3))
        w[iu] = p[:6]
        return w + np.triu(w, 1).T, p[6:]

    def residual(p: Array) -> Array:
        w, b = unpack(p)
        return np.linalg.norm((m - b) @ w.T, axis=1) - field

    sol = least_squares(residual, np.concatenate([inv0[iu], centre]), method="lm")
    w, offset = unpack(sol.x)
    soft = np.linalg.inv(w)
    soft = 0.5 * (soft + soft.T)
    if field_ut is None:  # keep det S = 1 after the refinement too
        g = np.linalg.det(soft) ** (1.0 / 3.0)
        soft, field = soft / g, field * g
    res = np.linalg.norm((m - offset) @ np.linalg.inv(soft).T, axis=1) - field
    corrected = (m - offset) @ np.linalg.inv(soft).T
    coverage = sphere_coverage(corrected)
    if coverage < min_coverage:
        raise ValueError(
            f"too little rotation: the readings cover {100 * coverage:.0f} % of the sphere of "
            f"directions (need {100 * min_coverage:.0f} %); tumble the sensor through many "
            "orientations"
        )
    rms = float(np.sqrt(np.mean(res**2)))
    return EllipsoidFit(offset, soft, field, rms, rms / field, coverage, thinnest, m.shape[0])


def align_to_gravity(
    triad: TriadCalibration, up_body: ArrayLike, mag: ArrayLike
) -> tuple[TriadCalibration, float, float]:
    """Rotate a magnetometer calibration's axes onto the accelerometer's (module docstring).

    ``up_body`` (K, 3): up in body axes in K still poses (calibrated accelerometer,
    normalised here); ``mag`` (K, 3): raw mean field in the same poses, µT. With
    ``m_k = K⁻¹ (y_k - b)`` the true field is ``R^T m_k`` and ``up_k · R^T m_k = c`` for all
    k; R (3 angles) and c are found by least squares and ``K`` becomes ``K R``. Returns the
    new calibration, R's angle in deg and the RMS residual in µT. Needs K >= 5 poses with
    differing verticals, else ``ValueError``.
    """
    from scipy.spatial.transform import Rotation

    up = np.asarray(up_body, dtype=np.float64)
    y = np.asarray(mag, dtype=np.float64)
    if up.ndim != 2 or up.shape[1] != 3 or up.shape != y.shape or up.shape[0] < 5:
        raise ValueError(f"up_body and mag must be (K, 3) with K >= 5, got {up.shape}, {y.shape}")
    up = up / np.linalg.norm(up, axis=1)[:, None]
    m = triad.correct(y)

    def residual(p: Array) -> Array:
        rot = Rotation.from_rotvec(p[:3]).as_matrix()
        return np.einsum("ki,ki->k", up, m @ rot) - p[3]  # up_k · R^T m_k

    p0 = np.array([0.0, 0.0, 0.0, float(np.mean(np.einsum("ki,ki->k", up, m)))])
    sol = least_squares(residual, p0, method="lm")
    sv = np.linalg.svd(sol.jac, compute_uv=False)
    if sv[-1] < 1e-6 * sv[0]:
        raise ValueError("the poses' verticals do not determine the rotation: use poses with "
                         "different axes up")
    rot = Rotation.from_rotvec(sol.x[:3])
    k = triad.K @ rot.as_matrix()
    aligned = TriadCalibration("mag", k, triad.bias, "uT",
                               triad.method + ", axes aligned to gravity")
    rms = float(np.sqrt(np.mean(sol.fun**2)))
    return aligned, float(np.degrees(rot.magnitude())), rms
