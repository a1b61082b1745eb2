"""Allan variance (overlapping) of still gyro and accelerometer recordings, and its noise terms.

003 section III-B identifies the sensors' random errors from the Allan variance: angle
(velocity) random walk, bias instability and rate (acceleration) random walk. For a signal
``y`` sampled at ``f_s`` with ``θ_k = Σ_{i<k} y_i / f_s`` (``θ_0 = 0``, mean removed first
for precision, as allantools does) and cluster time ``τ = m / f_s``, the overlapping Allan
variance is (IEEE Std 952-1997, annex C)::

    σ²(τ) = Σ_{k=0}^{N-2m} (θ_{k+2m} - 2 θ_{k+m} + θ_k)² / (2 τ² (N + 1 - 2m)).

Each noise process has a power law in τ, and they add (IEEE Std 952, table C.2)::

    σ²(τ) = 3 Q² / τ² + N² / τ + (2 ln 2 / π) B² + K² τ / 3 + R² τ² / 2

Q quantization (unit·s), N white-noise density = angle/velocity random walk (unit/√Hz,
slope -1/2 in σ), B bias instability (unit, slope 0, σ_min ≈ 0.664 B), K rate/acceleration
random walk (unit/√s = unit·s⁻¹/√Hz, slope +1/2), R rate ramp (unit/s, slope +1). The
coefficients are fitted at once by non-negative least squares on the relative error of σ²,
weighted by the number of independent clusters. The Kalman filters (003 eqs. 29-31) take N
and K, per sample as ``N·√f_s`` and ``K/√f_s``; :class:`NoiseDensities` carries both forms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls

Array = NDArray[np.float64]

__all__ = [
    "AllanDeviation",
    "NoiseDensities",
    "NoiseTerms",
    "allan_deviation",
    "identify_noise",
    "noise_densities",
    "plot_allan",
]

_POWERS = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])  # of τ in σ², for Q, N, B, K, R
_B_FACTOR = 2.0 * math.log(2.0) / math.pi  # σ² = _B_FACTOR · B² on the flat part
_MIN_CLUSTERS = 9  # taus with fewer non-overlapping clusters are too noisy to use


@dataclass(frozen=True)
class AllanDeviation:
    """Overlapping Allan deviation of C channels (module docstring).

    tau_s : (M,) cluster times, s. adev : (M, C) Allan deviation σ(τ), unit of the signal.
    n_samples : N. rate_hz : sample rate, Hz.
    """

    tau_s: Array
    adev: Array
    n_samples: int
    rate_hz: float

    def clusters(self) -> Array:
        """(M,) number of non-overlapping clusters ``N / m`` at each τ."""
        return self.n_samples / (self.tau_s * self.rate_hz)


def allan_deviation(
    signal: ArrayLike, rate_hz: float, taus_s: ArrayLike | None = None, points_per_decade: int = 10
) -> AllanDeviation:
    """Overlapping Allan deviation (module docstring) of ``signal`` (N,) or (N, C) at ``rate_hz``.

    ``taus_s`` are rounded to whole numbers of samples ``m`` in ``[1, (N - 1) / 2]``;
    by default ``points_per_decade`` log-spaced values of ``m`` over that range.
    """
    y = np.asarray(signal, dtype=np.float64)
    if y.ndim == 1:
        y = y[:, None]
    if y.ndim != 2 or y.shape[0] < 5 or not np.all(np.isfinite(y)):
        raise ValueError(f"signal must be a finite (N,) or (N, C) array with N >= 5, got {y.shape}")
    if not (np.isfinite(rate_hz) and rate_hz > 0.0):
        raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz!r}")
    n = y.shape[0]
    m_max = (n - 1) // 2
    if taus_s is None:
        if points_per_decade < 1:
            raise ValueError(f"points_per_decade must be >= 1, got {points_per_decade}")
        count = max(2, math.ceil(math.log10(m_max) * points_per_decade) + 1)
        m = np.unique(np.round(np.logspace(0.0, math.log10(m_max), count)).astype(np.int64))
    else:
        m = np.unique(np.round(np.asarray(taus_s, dtype=np.float64) * rate_hz).astype(np.int64))
        if m.size == 0 or m[0] < 1 or m[-1] > m_max:
            raise ValueError(
                f"taus_s must lie in [{1 / rate_hz:g}, {m_max / rate_hz:g}] s for N = {n} "
                f"samples at {rate_hz:g} Hz"
            )
    theta = np.zeros((n + 1, y.shape[1]))
    np.cumsum(y - y.mean(axis=0), axis=0, out=theta[1:])
    theta /= rate_hz
    adev = np.empty((m.size, y.shape[1]))
    for i, mi in enumerate(m):
        d = theta[2 * mi:] - 2.0 * theta[mi:-mi] + theta[:-2 * mi]
        tau = mi / rate_hz
        adev[i] = np.sqrt(np.sum(d * d, axis=0) / (2.0 * tau * tau * (n + 1 - 2 * mi)))
    return AllanDeviation(m / rate_hz, adev, n, float(rate_hz))


@dataclass(frozen=True)
class NoiseTerms:
    """Coefficients of the Allan variance model per channel, (C,) each (module docstring).

    quantization : Q, unit·s. white : N, unit/√Hz (angle or velocity random walk).
    bias_instability : B, unit. random_walk : K, unit/√s (rate or acceleration random walk).
    ramp : R, unit/s. flat_bias_instability : σ_min / 0.664, the classic reading of B off the
    curve's minimum: an upper bound on B (it equals B only where the curve is flat).
    """

    quantization: Array
    white: Array
    bias_instability: Array
    random_walk: Array
    ramp: Array
    flat_bias_instability: Array

    def model_adev(self, tau_s: ArrayLike) -> Array:
        """σ(τ) (M, C) of the fitted model at ``tau_s`` (M,)."""
        tau = np.asarray(tau_s, dtype=np.float64)[:, None]
        var = (
            3.0 * self.quantization**2 / tau**2
            + self.white**2 / tau
            + _B_FACTOR * self.bias_instability**2
            + self.random_walk**2 * tau / 3.0
            + self.ramp**2 * tau**2 / 2.0
        )
        return np.sqrt(var)


def identify_noise(adev: AllanDeviation) -> NoiseTerms:
    """Fit Q, N, B, K, R (:class:`NoiseTerms`) to an Allan deviation, per channel.

    Non-negative least squares on ``(model(τ) - σ²(τ)) / σ²(τ)`` weighted by the square
    root of the cluster count, over the τ with at least 9 clusters (fewer give estimates
    too scattered to weigh). Raises ``ValueError`` if fewer than 5 such τ remain.
    """
    keep = adev.clusters() >= _MIN_CLUSTERS
    if np.count_nonzero(keep) < _POWERS.size:
        raise ValueError(
            f"only {np.count_nonzero(keep)} cluster times have {_MIN_CLUSTERS}+ clusters; "
            "record longer (an Allan analysis needs minutes to hours of still data)"
        )
    tau = adev.tau_s[keep]
    weight = np.sqrt(adev.clusters()[keep])
    basis = tau[:, None] ** _POWERS[None, :]
    coef = np.empty((adev.adev.shape[1], _POWERS.size))
    for c in range(adev.adev.shape[1]):
        var = adev.adev[keep, c] ** 2
        if np.any(var <= 0.0):
            raise ValueError(f"channel {c} is constant: its Allan variance is zero")
        a = basis * (weight / var)[:, None]
        # scale columns for conditioning (τ spans decades), then undo
        norms = np.linalg.norm(a, axis=0)
        x, _ = nnls(a / norms, weight)
        coef[c] = x / norms
    flat = np.min(adev.adev, axis=0) / math.sqrt(_B_FACTOR)
    return NoiseTerms(
        quantization=np.sqrt(coef[:, 0] / 3.0),
        white=np.sqrt(coef[:, 1]),
        bias_instability=np.sqrt(coef[:, 2] / _B_FACTOR),
        random_walk=np.sqrt(3.0 * coef[:, 3]),
        ramp=np.sqrt(2.0 * coef[:, 4]),
        flat_bias_instability=flat,
    )


def _common(values: Array) -> float:
    """One value for all axes: the root mean square (003 assumes identical axes)."""
    return float(np.sqrt(np.mean(np.square(values))))


@dataclass(frozen=True)
class NoiseDensities:
    """Sensor noise for the Kalman filters (003 III-B, eqs. 29-32), one value for all axes.

    gyr_noise_density_rad_s_sqrt_hz : gyro white noise (angle random walk), rad/s/√Hz.
    gyr_bias_walk_rad_s2_sqrt_hz : gyro rate random walk, rad/s²/√Hz (= rad/s/√s).
    gyr_bias_instability_rad_s : gyro bias instability, rad/s.
    acc_noise_density_m_s2_sqrt_hz : accelerometer white noise (velocity random walk),
        m/s²/√Hz. acc_bias_walk_m_s3_sqrt_hz : acceleration random walk, m/s³/√Hz.
    acc_bias_instability_m_s2 : accelerometer bias instability, m/s².

    Per-axis values are combined as the root mean square. All >= 0 and finite.
    """

    gyr_noise_density_rad_s_sqrt_hz: float
    gyr_bias_walk_rad_s2_sqrt_hz: float
    gyr_bias_instability_rad_s: float
    acc_noise_density_m_s2_sqrt_hz: float
    acc_bias_walk_m_s3_sqrt_hz: float
    acc_bias_instability_m_s2: float

    def __post_init__(self) -> None:
        for name, value in self.to_dict().items():
            v = float(value)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
            object.__setattr__(self, name, v)
        if self.gyr_noise_density_rad_s_sqrt_hz > 0.1:
            raise ValueError(
                f"gyr_noise_density_rad_s_sqrt_hz = {self.gyr_noise_density_rad_s_sqrt_hz} is "
                "implausible for rad/s/√Hz (MEMS: ~1e-4); was it given in deg/s/√Hz?"
            )

    def to_dict(self) -> dict[str, float]:
        """JSON-ready dict; the keys carry the units."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NoiseDensities:
        """Inverse of :meth:`to_dict`; unknown or missing keys raise ``ValueError``."""
        keys = set(cls.__dataclass_fields__)
        if set(d) != keys:
            raise ValueError(f"noise needs exactly the keys {sorted(keys)}, got {sorted(d)}")
        return cls(**d)

    def kalman_params(self) -> dict[str, float]:
        """The densities under the parameter names of the bias-augmented Kalman filter
        (003; ``methods/bias_kf``): rad/s/√Hz, rad/s/√s (= rad/s²/√Hz), m/s²/√Hz."""
        return {
            "gyr_noise_rad_s_sqrt_hz": self.gyr_noise_density_rad_s_sqrt_hz,
            "gyr_bias_walk_rad_s_sqrt_s": self.gyr_bias_walk_rad_s2_sqrt_hz,
            "acc_noise_m_s2_sqrt_hz": self.acc_noise_density_m_s2_sqrt_hz,
        }

    def per_sample(self, rate_hz: float) -> dict[str, float]:
        """Discrete standard deviations at ``rate_hz``: white ``N·√f_s``, walk step ``K/√f_s``."""
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz!r}")
        root = math.sqrt(rate_hz)
        return {
            "gyr_noise_rad_s": self.gyr_noise_density_rad_s_sqrt_hz * root,
            "gyr_bias_step_rad_s": self.gyr_bias_walk_rad_s2_sqrt_hz / root,
            "acc_noise_m_s2": self.acc_noise_density_m_s2_sqrt_hz * root,
            "acc_bias_step_m_s2": self.acc_bias_walk_m_s3_sqrt_hz / root,
        }


def noise_densities(gyr: NoiseTerms, acc: NoiseTerms) -> NoiseDensities:
    """:class:`NoiseDensities` from the gyro's and the accelerometer's fitted terms."""
    return NoiseDensities(
        gyr_noise_density_rad_s_sqrt_hz=_common(gyr.white),
        gyr_bias_walk_rad_s2_sqrt_hz=_common(gyr.random_walk),
        gyr_bias_instability_rad_s=_common(gyr.bias_instability),
        acc_noise_density_m_s2_sqrt_hz=_common(acc.white),
        acc_bias_walk_m_s3_sqrt_hz=_common(acc.random_walk),
        acc_bias_instability_m_s2=_common(acc.bias_instability),
    )


def plot_allan(
    panels: list[tuple[str, AllanDeviation, NoiseTerms, str]], path: str | Path
) -> Path:
    """Log-log plot of σ(τ) per axis with the fitted model and its slope lines, as PNG.

    ``panels``: (title, deviation, terms, unit label) per sensor. On each panel the -1/2
    line through N (read at τ = 1 s), the flat line at 0.664 B and the +1/2 line through K
    (read at τ = 3 s) are drawn for the first axis with their values; τ with fewer than 9
    clusters (not used by the fit) are faint.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(6.5 * len(panels), 4.8), squeeze=False)
    for ax, (title, dev, terms, unit) in zip(axes[0], panels, strict=True):
        tau = dev.tau_s
        reliable = dev.clusters() >= _MIN_CLUSTERS
        model = terms.model_adev(tau)
        for c, name in enumerate("xyz"[: dev.adev.shape[1]]):
            line = ax.loglog(tau[reliable], dev.adev[reliable, c], ".-", lw=1, ms=3,
                             label=f"{name}")[0]
            ax.loglog(tau[~reliable], dev.adev[~reliable, c], ".", ms=3, alpha=0.3,
                      color=line.get_color())
            ax.loglog(tau, model[:, c], "--", color=line.get_color(), lw=0.8)
        n, b, k = terms.white[0], terms.bias_instability[0], terms.random_walk[0]
        lo, hi = math.log10(tau[0]), math.log10(tau[-1])
        lines = [  # (values, label, where along the τ axis as a fraction of its decades)
            (n / np.sqrt(tau), f"slope -1/2: N = {n:.3g} {unit}/√Hz", 0.1),
            (np.full_like(tau, b * math.sqrt(_B_FACTOR)), f"slope 0: B = {b:.3g} {unit}", 0.4),
            (k * np.sqrt(tau / 3.0), f"slope +1/2: K = {k:.3g} {unit}/√s", 0.6),
        ]
        for values, label, where in lines:
            if not np.any(values > 0):
                continue
            ax.loglog(tau, values, ":", color="k", lw=1.0, alpha=0.7)
            x = 10.0 ** (lo + where * (hi - lo))
            ax.annotate(label + " (x)", (x, float(np.interp(x, tau, values))), fontsize=7,
                        xytext=(4, -10), textcoords="offset points")
        ax.set_ylim(0.3 * dev.adev.min(), 3.0 * dev.adev.max())
        ax.set_xlabel("cluster time τ (s)")
        ax.set_ylabel(f"Allan deviation σ(τ) ({unit})")
        ax.set_title(f"{title}: overlapping Allan deviation, fit dashed")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
