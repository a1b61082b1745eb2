"""Angular velocity from the all-accelerometer IMU (003 eqs. 1-6) and its noise (eqs. 32-37).

- :func:`differential_acceleration`: ``A_D = [a13x, a23y, a12z]`` from the six channels
  (eq. 4); :func:`gravity_estimate`: the two sensors per axis averaged (eq. 42).
- :func:`solve_angular_velocity`: per sample, the ``Ω`` that solves eq. 5 with the
  backward-difference angular acceleration ``Ω̇ = (Ω - Ω_prev)/T`` (eq. 3), by Gauss-Newton
  or Levenberg-Marquardt (eq. 6). The solution drifts: noise in ``A_D`` enters ``Ω̇``
  and is integrated, which the bias state of :class:`margtrack.methods.bias_kf.BiasKalman`
  absorbs.
- :func:`unscented_transform` (eqs. 34-37) and :func:`all_accelerometer_noise`: the
  rate-noise and bias-walk covariances of the solver's output, for the filter's parameters.

Array layout and channel order: :mod:`margtrack.sim.all_accelerometer`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.sim.all_accelerometer import AccelerometerArray
from margtrack.single_frame import all_accelerometer_kernel as kernel

Array = NDArray[np.float64]

__all__ = [
    "AllAccelerometerNoise",
    "SolverResult",
    "all_accelerometer_noise",
    "angular_velocity",
    "differential_acceleration",
    "gravity_estimate",
    "solve_angular_velocity",
    "unscented_transform",
]


def _readings(readings: ArrayLike) -> Array:
    r = np.ascontiguousarray(readings, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != 6:
        raise ValueError(
            f"readings must have shape (N, 6) (channels 1x, 1z, 2y, 2z, 3x, 3y), got {r.shape}"
        )
    bad = np.argwhere(~np.isfinite(r))
    if bad.size:
        raise ValueError(f"readings has a non-finite value at sample {int(bad[0, 0])}")
    return r


def differential_acceleration(readings_m_s2: ArrayLike) -> Array:
    """``A_D = [3x - 1x, 3y - 2y, 2z - 1z]`` (N, 3), m/s² (003 eqs. 1 and 4)."""
    r = _readings(readings_m_s2)
    return np.ascontiguousarray(np.stack([r[:, 4] - r[:, 0], r[:, 5] - r[:, 2],
                                          r[:, 3] - r[:, 1]], axis=1))


def gravity_estimate(readings_m_s2: ArrayLike) -> Array:
    """Body specific force (N, 3), m/s²: the two sensors per axis averaged (003 eq. 42).

    x from {1, 3}, y from {2, 3}, z from {1, 2}; averaging halves the white-noise
    variance. Each axis is the specific force at its two sensors' midpoint: the rotational
    terms there are part of the body-acceleration noise of eq. 43.
    """
    r = _readings(readings_m_s2)
    return 0.5 * np.stack([r[:, 0] + r[:, 4], r[:, 2] + r[:, 5], r[:, 1] + r[:, 3]], axis=1)


@dataclass(frozen=True)
class SolverResult:
    """omega_rad_s (N, 3) body rates; iterations (N,); converged (N,) bool; residual_m_s2
    (N,) the final ``|A_D - g(Ω)|``."""

    omega_rad_s: Array
    iterations: NDArray[np.int64]
    converged: NDArray[np.bool_]
    residual_m_s2: Array


def _dt(n: int, t: ArrayLike | None, rate_hz: float | None) -> Array:
    if (t is None) == (rate_hz is None):
        raise ValueError("give exactly one of t (timestamps in s) or rate_hz; no rate is assumed")
    if t is None:
        if not (rate_hz is not None and math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz}")
        dt = np.full(n, 1.0 / rate_hz)
    else:
        ts = np.asarray(t, dtype=np.float64)
        if ts.shape != (n,) or not np.all(np.isfinite(ts)):
            raise ValueError(f"t must be a finite ({n},) array, got shape {ts.shape}")
        steps = np.diff(ts)
        if np.any(steps <= 0):
            i = int(np.flatnonzero(steps <= 0)[0]) + 1
            raise ValueError(f"timestamps must increase strictly: t[{i - 1}] >= t[{i}]")
        dt = np.empty(n)
        dt[1:] = steps
    dt[0] = 0.0
    return dt


def solve_angular_velocity(
    diff_acc_m_s2: ArrayLike, array: AccelerometerArray, *, t: ArrayLike | None = None,
    rate_hz: float | None = None, omega0_rad_s: ArrayLike = (0.0, 0.0, 0.0),
    damping: float = 0.0, max_iter: int = 20, tol: float = 1e-12,
) -> SolverResult:
    """Body angular velocity (N, 3) rad/s from ``A_D`` (N, 3) m/s² (003 eqs. 3, 5, 6).

    Sample 0 is ``omega0_rad_s`` (the initial condition ``Ω(0)`` of eq. 3, rest by
    default); sample ``i`` solves ``A_D,i = [(Ω×Ω× + Ω̇×) P]`` with ``Ω̇ = (Ω - Ω_{i-1})/T_i``,
    starting at ``Ω_{i-1}``. ``damping`` 0 is Gauss-Newton; > 0 Levenberg-Marquardt
    with that initial ``λ``. Iteration stops at ``|δ| <= tol (1 + |Ω|)`` or ``max_iter``.

    Error dynamics (linearised, ``M`` = :meth:`AccelerometerArray.tangential_matrix`,
    ``C`` the Jacobian of the centripetal terms): ``δΩ_k = (I + T M⁻¹ C_k)⁻¹ (δΩ_{k-1} +
    T M⁻¹ ξ_k)``. Accelerometer noise ``ξ`` is integrated into a random walk (the bias of
    003 IV-B), and ``C ~ |Ω| |P|`` makes the recursion unstable at a rate of order
    ``|Ω| |P| / (smallest baseline)``; open loop the rates diverge within seconds once the
    walk has grown. :func:`margtrack.methods.bias_kf.track_all_accelerometer` feeds the
    filter's bias estimate back into ``Ω_prev`` to keep them bounded.
    """
    a_d = np.ascontiguousarray(diff_acc_m_s2, dtype=np.float64)
    if a_d.ndim != 2 or a_d.shape[1] != 3 or a_d.shape[0] == 0:
        raise ValueError(f"diff_acc_m_s2 must have shape (N, 3) with N >= 1, got {a_d.shape}")
    bad = np.argwhere(~np.isfinite(a_d))
    if bad.size:
        raise ValueError(f"diff_acc_m_s2 has a non-finite value at sample {int(bad[0, 0])}")
    if not isinstance(array, AccelerometerArray):
        raise ValueError(f"array must be an AccelerometerArray, got {type(array).__name__}")
    omega = np.array(omega0_rad_s, dtype=np.float64)
    if omega.shape != (3,) or not np.all(np.isfinite(omega)):
        raise ValueError(f"omega0_rad_s must be 3 finite numbers, got {omega0_rad_s!r}")
    if not (math.isfinite(damping) and damping >= 0.0):
        raise ValueError(f"damping must be a finite number >= 0 (0: Gauss-Newton), got {damping}")
    if int(max_iter) != max_iter or max_iter < 1:
        raise ValueError(f"max_iter must be an integer >= 1, got {max_iter!r}")
    if not (math.isfinite(tol) and tol > 0.0):
        raise ValueError(f"tol must be a finite number > 0, got {tol}")
    n = a_d.shape[0]
    dt = _dt(n, t, rate_hz)
    out = np.empty((n, 3))
    iters = np.empty(n, dtype=np.int64)
    conv = np.empty(n, dtype=np.bool_)
    res = np.empty(n)
    kernel.solve_rates(a_d, array.baselines(), dt, omega, float(damping), int(max_iter),
                       float(tol), out, iters, conv, res)
    return SolverResult(out, iters, conv, res)


def angular_velocity(
    readings_m_s2: ArrayLike, array: AccelerometerArray, **options: object
) -> SolverResult:
    """:func:`solve_angular_velocity` of :func:`differential_acceleration` of the readings."""
    return solve_angular_velocity(differential_acceleration(readings_m_s2), array, **options)


def unscented_transform(
    func: Callable[[Array], Array], mean: ArrayLike, cov: ArrayLike, kappa: float = 0.0
) -> tuple[Array, Array]:
    """Mean and covariance of ``func(x)`` for ``x`` with ``mean`` (n,) and ``cov`` (n, n).

    2n + 1 sigma points (003 eq. 34): ``S_0 = x̄`` with weight ``κ/(n+κ)`` and
    ``S_{i, i+n} = x̄ ± (√((n+κ) Σ))_i`` (columns of the Cholesky factor) with weights
    ``1/(2(n+κ))``; then eqs. 35-37. The extracted eq. 34 reads ``S_0 = c_0 = κ/(n+κ)``:
    two statements merged; for the zero-mean noise of 003 ``S_0 = 0``. ``n + κ`` must be
    > 0 (a square root of a negative multiple of ``Σ`` does not exist). ``κ = 3 - n``
    matches the fourth moment of a Gaussian (Julier et al. 2000).
    """
    x = np.asarray(mean, dtype=np.float64).ravel()
    sigma = np.asarray(cov, dtype=np.float64)
    n = x.shape[0]
    if sigma.shape != (n, n):
        raise ValueError(f"cov must have shape ({n}, {n}), got {sigma.shape}")
    if not (math.isfinite(kappa) and n + kappa > 0):
        raise ValueError(f"kappa must be a finite number with n + kappa > 0 (n = {n}), "
                         f"got {kappa}")
    try:
        root = np.linalg.cholesky((n + kappa) * sigma)
    except np.linalg.LinAlgError:
        raise ValueError("cov must be symmetric positive definite") from None
    points = [x] + [x + root[:, i] for i in range(n)] + [x - root[:, i] for i in range(n)]
    weights = np.array([kappa / (n + kappa)] + [0.5 / (n + kappa)] * (2 * n))
    images = np.array([np.atleast_1d(np.asarray(func(p), dtype=np.float64)) for p in points])
    y_mean = weights @ images  # eq. 35
    dev = images - y_mean
    return y_mean, (weights[:, None] * dev).T @ dev  # eq. 36


@dataclass(frozen=True)
class AllAccelerometerNoise:
    """Noise of the solver's rates, per sample and as the filter's densities.

    rate_cov_rad2_s2 : Ξ_Ω (3, 3), covariance of the white part of Ω per sample.
    bias_step_cov_rad2_s2 : Ξ_B (3, 3), covariance of the bias increment per sample.
    gyr_noise_rad_s_sqrt_hz : (3,) ``sqrt(diag Ξ_Ω · T)``, white-noise density per axis.
    gyr_bias_walk_rad_s_sqrt_s : (3,) ``sqrt(diag Ξ_B / T)``, bias random-walk density.
    """

    rate_cov_rad2_s2: Array
    bias_step_cov_rad2_s2: Array
    gyr_noise_rad_s_sqrt_hz: tuple[float, float, float]
    gyr_bias_walk_rad_s_sqrt_s: tuple[float, float, float]


def all_accelerometer_noise(
    array: AccelerometerArray, acc_noise_m_s2_sqrt_hz: float, rate_hz: float,
    omega_rad_s: ArrayLike = (0.0, 0.0, 0.0), kappa: float = 0.0,
) -> AllAccelerometerNoise:
    """Rate and bias noise of :func:`solve_angular_velocity` by the unscented transform.

    ``Ξ_AD = 2 σ_A² I`` with ``σ_A = density·√rate``: each entry of ``A_D`` is the
    difference of two independent channels (the extracted eq. 32 prints ``4 σ_A²``, which
    does not follow from the difference of two; ``2 σ_A²`` is derived and tested).
    At a steady rotation ``ω`` (``A_D0 = Ω×Ω× P``, no angular acceleration):

    1. ``Ξ_Ω``: sigma points of ``Ξ_AD`` through one solver step with ``Ω_prev`` exact,
       ``Ω = F(A_D0 + ξ_AD; Ω_prev = ω)`` (eqs. 34-37, "disregarding" the integrated part);
    2. ``Ξ_B``: sigma points of ``Ξ_Ω`` on ``Ω_prev`` through the same step with ``A_D``
       exact: how the previous rate's noise carries over through ``Ω̇`` (eq. 3), the
       integrated noise the filter models as a bias random walk (003 IV-C-3).
    """
    rate_hz = float(rate_hz)
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz}")
    if not (math.isfinite(acc_noise_m_s2_sqrt_hz) and acc_noise_m_s2_sqrt_hz > 0):
        raise ValueError(f"acc_noise_m_s2_sqrt_hz must be a finite number > 0, "
                         f"got {acc_noise_m_s2_sqrt_hz}")
    w0 = np.array(omega_rad_s, dtype=np.float64)
    if w0.shape != (3,) or not np.all(np.isfinite(w0)):
        raise ValueError(f"omega_rad_s must be 3 finite numbers, got {omega_rad_s!r}")
    period = 1.0 / rate_hz
    base = array.baselines()
    a_d0 = np.array([np.cross(w0, np.cross(w0, base[k]))[k] for k in range(3)])

    def step(a_d: Array, prev: Array) -> Array:
        state = prev.copy()
        out = np.empty((2, 3))
        kernel.solve_rates(np.stack([a_d, a_d]), base, np.array([0.0, period]), state, 0.0,
                           50, 1e-14, out, np.empty(2, dtype=np.int64),
                           np.empty(2, dtype=np.bool_), np.empty(2))
        return out[1]

    var_ad = 2.0 * (acc_noise_m_s2_sqrt_hz**2 * rate_hz)  # eq. 32, derived
    _, xi_omega = unscented_transform(lambda e: step(a_d0 + e, w0), np.zeros(3),
                                      var_ad * np.eye(3), kappa)
    _, xi_bias = unscented_transform(lambda e: step(a_d0, w0 + e), np.zeros(3), xi_omega, kappa)
    noise = np.sqrt(np.diag(xi_omega) * period)
    walk = np.sqrt(np.diag(xi_bias) / period)
    return AllAccelerometerNoise(
        xi_omega, xi_bias, tuple(float(v) for v in noise), tuple(float(v) for v in walk)
    )
