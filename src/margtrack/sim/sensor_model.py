"""Error model of one sensor triad (gyroscope, accelerometer or magnetometer).

The model, applied to a true signal ``x`` (N, 3) sampled at ``rate_hz``::

    y_k = (I + diag(scale)) @ M @ x_k + bias + b_k + n_k,
    b_0 = 0,  b_k = b_{k-1} + bias_random_walk / sqrt(rate_hz) · w_k,
    n_k = noise_density · sqrt(rate_hz) · v_k,          v_k, w_k ~ N(0, I3) iid,
    y_k = clip(y_k, -saturation, saturation), then y_k = quantization · round(y_k / quantization).

``M`` (:meth:`SensorErrors.misalignment_matrix`) holds the sensitive axes as rows, a
non-orthogonal triad with three angles ``(α_x, α_y, α_z) = misalignment_deg``: the x axis
is the reference, the y axis is turned by ``α_z`` about z, the z axis by ``α_y`` about y
and then by ``α_x`` about x::

    M = [[1,          0,                  0                ],
         [-sin α_z,   cos α_z,            0                ],
         [sin α_y,    -sin α_x cos α_y,   cos α_x cos α_y  ]]

(first order: ``I + [[0, 0, 0], [-α_z, 0, 0], [α_y, -α_x, 0]]``, the triangular
non-orthogonality model of triad calibration). After clipping, quantization can move a
value by up to half an LSB, so ``|y| <= saturation + quantization / 2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

__all__ = ["SensorErrors"]

_MAX_MISALIGNMENT_DEG = 10.0


def _triple(value: ArrayLike, name: str) -> tuple[float, float, float]:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers (x, y, z), got {value!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


def _non_negative(value: float, name: str) -> None:
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True)
class SensorErrors:
    """Deterministic and random errors of one sensor triad; the model is in the module docstring.

    Units follow the sensor: rad/s (gyr), m/s² (acc) or µT (mag), written ``unit`` below.

    Attributes
    ----------
    noise_density : white-noise density, unit/√Hz, >= 0; the discrete standard deviation
        is ``noise_density * sqrt(rate_hz)``.
    bias : (3,) constant offset, unit.
    bias_random_walk : density of the bias random walk, unit/s/√Hz (= unit/√s), >= 0;
        the bias moves by ``bias_random_walk / sqrt(rate_hz)`` (std) per sample, so by
        ``bias_random_walk * sqrt(T)`` after T seconds.
    scale : (3,) scale-factor errors as fractions in (-1, 1): 0.01 reads 1 % high.
    misalignment_deg : (3,) non-orthogonality angles ``(α_x, α_y, α_z)`` in [-10, 10] deg.
    quantization : LSB, unit, >= 0 (0: none).
    saturation : largest ``|value|``, unit, > 0 (``inf``: none).

    Bad values raise ``ValueError`` naming the attribute and its allowed range.
    """

    noise_density: float = 0.0
    bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_random_walk: float = 0.0
    scale: tuple[float, float, float] = (0.0, 0.0, 0.0)
    misalignment_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quantization: float = 0.0
    saturation: float = math.inf

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in ("noise_density", "bias_random_walk", "quantization"):
            value = float(getattr(self, name))
            _non_negative(value, name)
            set_(self, name, value)
        for name in ("bias", "scale", "misalignment_deg"):
            set_(self, name, _triple(getattr(self, name), name))
        if not all(-1.0 < s < 1.0 for s in self.scale):
            raise ValueError(f"scale must have each entry in (-1, 1) (fractions), got {self.scale}")
        if not all(abs(a) <= _MAX_MISALIGNMENT_DEG for a in self.misalignment_deg):
            raise ValueError(
                f"misalignment_deg must have each entry in [-{_MAX_MISALIGNMENT_DEG}, "
                f"{_MAX_MISALIGNMENT_DEG}] deg, got {self.misalignment_deg}"
            )
        saturation = float(self.saturation)
        if not saturation > 0.0:
            raise ValueError(f"saturation must be > 0 (inf for none), got {self.saturation!r}")
        set_(self, "saturation", saturation)

    def misalignment_matrix(self) -> Array:
        """Non-orthogonal axis matrix ``M`` (3, 3), rows = sensitive axes (module docstring)."""
        ax, ay, az = np.radians(self.misalignment_deg)
        return np.array(
            [
                [1.0, 0.0, 0.0],
                [-np.sin(az), np.cos(az), 0.0],
                [np.sin(ay), -np.sin(ax) * np.cos(ay), np.cos(ax) * np.cos(ay)],
            ]
        )

    def matrix(self) -> Array:
        """Full linear error ``(I + diag(scale)) @ M`` (3, 3) acting on the true signal."""
        return (1.0 + np.asarray(self.scale))[:, None] * self.misalignment_matrix()

    def apply(self, true: ArrayLike, rate_hz: float, rng: np.random.Generator) -> Array:
        """Measured signal (N, 3) from the true one ``true`` (N, 3), sampled at ``rate_hz``.

        Draws exactly two (N, 3) standard-normal blocks from ``rng``, white noise first and
        then random-walk increments, whatever the parameters, so the stream stays aligned
        when a parameter is switched on or off.
        """
        x = np.asarray(true, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3 or not np.all(np.isfinite(x)):
            raise ValueError(f"true must be a finite (N, 3) array, got shape {x.shape}")
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz!r}")
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        white = rng.standard_normal(x.shape)
        steps = rng.standard_normal(x.shape)
        steps[0] = 0.0
        walk = np.cumsum(steps, axis=0) * (self.bias_random_walk / math.sqrt(rate_hz))
        y = x @ self.matrix().T + np.asarray(self.bias) + walk
        y += white * (self.noise_density * math.sqrt(rate_hz))
        y = np.clip(y, -self.saturation, self.saturation)
        if self.quantization > 0.0:
            y = self.quantization * np.round(y / self.quantization)
        return y

    @classmethod
    def none(cls) -> SensorErrors:
        """A perfect sensor: measured equals true."""
        return cls()

    @classmethod
    def mems_gyr(cls) -> SensorErrors:
        """Typical consumer MEMS gyroscope (datasheet order of magnitude, BMI160 / ICM-20948 /
        LSM6DS class; not one part), rad/s: noise 0.005 deg/s/√Hz, bias (0.3, -0.2, 0.25)
        deg/s, bias random walk 0.001 deg/s/√s, scale (0.3, -0.2, 0.4) %, misalignment
        (0.2, -0.15, 0.1) deg, ±2000 deg/s range at 16 bit (LSB 2000/32768 deg/s).
        """
        return cls(
            noise_density=math.radians(0.005),
            bias=tuple(math.radians(b) for b in (0.3, -0.2, 0.25)),
            bias_random_walk=math.radians(0.001),
            scale=(0.003, -0.002, 0.004),
            misalignment_deg=(0.2, -0.15, 0.1),
            quantization=math.radians(2000.0 / 32768.0),
            saturation=math.radians(2000.0),
        )

    @classmethod
    def mems_acc(cls) -> SensorErrors:
        """Typical consumer MEMS accelerometer (same datasheet class), m/s²: noise 150 µg/√Hz,
        bias (0.10, -0.08, 0.15) m/s² (about 10-15 mg), bias random walk 1e-4 m/s²/√s,
        scale (0.5, -0.4, 0.6) %, misalignment (0.3, -0.2, 0.25) deg, ±16 g at 16 bit.
        """
        g = 9.80665
        return cls(
            noise_density=150e-6 * g,
            bias=(0.10, -0.08, 0.15),
            bias_random_walk=1e-4,
            scale=(0.005, -0.004, 0.006),
            misalignment_deg=(0.3, -0.2, 0.25),
            quantization=16.0 * g / 32768.0,
            saturation=16.0 * g,
        )

    @classmethod
    def mems_mag(cls) -> SensorErrors:
        """Typical consumer MEMS magnetometer (AK09916 / BMM150 class), µT: noise 0.05 µT/√Hz
        (0.5 µT rms at 100 Hz), residual hard-iron bias (1.0, -0.8, 0.5) µT, no bias walk,
        scale (1.0, -0.8, 1.2) %, misalignment (0.5, -0.4, 0.3) deg, LSB 0.15 µT, ±4900 µT.
        """
        return cls(
            noise_density=0.05,
            bias=(1.0, -0.8, 0.5),
            scale=(0.01, -0.008, 0.012),
            misalignment_deg=(0.5, -0.4, 0.3),
            quantization=0.15,
            saturation=4900.0,
        )
