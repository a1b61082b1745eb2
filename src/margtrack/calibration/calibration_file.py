"""The calibration file: a linear model per sensor triad, reference vectors and noise, as JSON.

One model for the gyroscope, the accelerometer and the magnetometer::

    y = K x + b             sensor model: x true (body axes), y measured, in the triad's unit
    x̂ = K⁻¹ (y - b)         the correction :meth:`Calibration.apply` makes

``K`` (3, 3) holds the sensitive axes as rows, scaled by their sensitivity; ``b`` (3,) is
000's "null point". It is the model of :class:`margtrack.sim.SensorErrors`, with
``K = (I + diag(scale)) @ M`` and ``b = bias``, so simulated truth compares directly.
000's scale factors (eqs. 2, 4, 5) are the multipliers ``1 / K_ii`` of a diagonal ``K``;
a magnetometer's soft-iron matrix and an accelerometer's 12-parameter fit fill all of
``K``. Units are SI inside (rad/s, m/s², µT); a file may state deg/s, g, nT, mG or G,
and is converted on reading. The JSON carries ``format`` and ``version``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.calibration.allan import NoiseDensities
from margtrack.calibration.reference import ReferenceVectors
from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.recording import Recording

Array = NDArray[np.float64]

__all__ = [
    "FORMAT",
    "VERSION",
    "Calibration",
    "TriadCalibration",
    "load_calibration",
    "save_calibration",
]

FORMAT = "margtrack-calibration"
VERSION = 1

#: Units each triad may be stated in, with the factor to its SI unit (the first one).
UNITS: dict[str, dict[str, float]] = {
    "gyr": {"rad/s": 1.0, "deg/s": math.pi / 180.0},
    "acc": {"m/s2": 1.0, "m/s^2": 1.0, "m/s²": 1.0, "g": STANDARD_GRAVITY_M_S2},
    "mag": {"uT": 1.0, "µT": 1.0, "nT": 1e-3, "mG": 0.1, "G": 100.0},
}
# Offsets beyond these (SI) are not errors a sensor has but a unit mix-up.
_MAX_BIAS = {"gyr": 0.5, "acc": 3.0, "mag": 2000.0}
_SENSITIVITY_RANGE = (0.5, 2.0)  # |row| of K
_MAX_CONDITION = 10.0


def _matrix(value: ArrayLike, name: str) -> tuple[tuple[float, float, float], ...]:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be a finite 3x3 matrix, got {value!r}")
    return tuple(tuple(float(v) for v in row) for row in a)  # type: ignore[return-value]


@dataclass(frozen=True)
class TriadCalibration:
    """Linear model ``y = K x + b`` of one triad (module docstring), in SI units.

    Attributes
    ----------
    sensor : "gyr", "acc" or "mag".
    matrix : K, 3x3 rows of floats, dimensionless; each row's norm (the axis sensitivity)
        in [0.5, 2] and condition number below 10.
    bias : b, 3 floats in ``unit``: |b| < 0.5 rad/s, 3 m/s² or 2000 µT per axis.
    unit : the unit ``bias`` is given in; converted at construction to rad/s, m/s2 or uT
        (stored so), others raise ``ValueError`` listing the allowed ones.
    method : how it was found (e.g. "six-position (000 eqs. 1-2)").
    """

    sensor: str
    matrix: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0),
                                                      (0.0, 0.0, 1.0))
    bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    unit: str = ""
    method: str = ""

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if self.sensor not in UNITS:
            raise ValueError(f"sensor must be one of {sorted(UNITS)}, got {self.sensor!r}")
        units = UNITS[self.sensor]
        si = next(iter(units))
        unit = self.unit or si
        if unit not in units:
            raise ValueError(
                f"{self.sensor} unit must be one of {', '.join(units)}, got {self.unit!r}"
            )
        bias = np.asarray(self.bias, dtype=np.float64)
        if bias.shape != (3,) or not np.all(np.isfinite(bias)):
            raise ValueError(f"{self.sensor} bias must be 3 finite numbers, got {self.bias!r}")
        bias = bias * units[unit]
        if np.any(np.abs(bias) > _MAX_BIAS[self.sensor]):
            raise ValueError(
                f"{self.sensor} bias {bias.tolist()} {si} exceeds {_MAX_BIAS[self.sensor]} {si} "
                f"on some axis: no sensor is that far off; check the unit (given: {unit})"
            )
        k = np.asarray(_matrix(self.matrix, f"{self.sensor} matrix"))
        rows = np.linalg.norm(k, axis=1)
        if np.any(rows < _SENSITIVITY_RANGE[0]) or np.any(rows > _SENSITIVITY_RANGE[1]):
            raise ValueError(
                f"{self.sensor} matrix rows must have norms (sensitivities) in "
                f"{list(_SENSITIVITY_RANGE)}, got {rows.round(4).tolist()}"
            )
        if np.linalg.cond(k) > _MAX_CONDITION:
            raise ValueError(
                f"{self.sensor} matrix is nearly singular (condition number "
                f"{np.linalg.cond(k):.3g} > {_MAX_CONDITION}): its axes are not independent"
            )
        set_(self, "matrix", _matrix(k, "matrix"))
        set_(self, "bias", tuple(float(v) for v in bias))
        set_(self, "unit", si)

    @classmethod
    def identity(cls, sensor: str) -> TriadCalibration:
        """No correction: ``K = I``, ``b = 0``."""
        return cls(sensor, method="identity (uncalibrated)")

    @property
    def K(self) -> Array:
        """K as a (3, 3) array."""
        return np.array(self.matrix)

    @property
    def b(self) -> Array:
        """b as a (3,) array, SI unit."""
        return np.array(self.bias)

    def correct(self, values: ArrayLike) -> Array:
        """``x̂ = K⁻¹ (y - b)`` for ``values`` (N, 3) or (3,) in the SI unit."""
        y = np.asarray(values, dtype=np.float64)
        if y.shape[-1:] != (3,):
            raise ValueError(f"values must have shape (..., 3), got {y.shape}")
        return np.linalg.solve(self.K, (y - self.b).reshape(-1, 3).T).T.reshape(y.shape)

    def decompose(self) -> tuple[Array, Array, float]:
        """``K = diag(1 + scale) · M · R``: scale (3,), misalignment (3,) deg, rotation deg.

        ``M`` is :class:`margtrack.sim.SensorErrors`'s lower-triangular axis matrix with
        angles ``(α_x, α_y, α_z)``, ``R`` a rotation of the whole triad (its angle
        returned): an LQ decomposition ``K = L R`` (``L`` lower triangular, positive
        diagonal), rows of ``L`` normalised to ``M``. For a lower-triangular ``K`` the
        rotation is 0 and ``scale``, the angles are exactly the simulator's.
        """
        q, r = np.linalg.qr(self.K.T)  # K^T = Q R  =>  K = R^T Q^T = L R
        signs = np.sign(np.diag(r))
        signs[signs == 0.0] = 1.0
        lower = (r * signs[:, None]).T
        rot = (q * signs[None, :]).T
        norms = np.linalg.norm(lower, axis=1)
        m = lower / norms[:, None]
        alpha_z = np.arctan2(-m[1, 0], m[1, 1])
        alpha_y = np.arcsin(np.clip(m[2, 0], -1.0, 1.0))
        alpha_x = np.arctan2(-m[2, 1], m[2, 2])
        angle = float(np.degrees(np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0))))
        return norms - 1.0, np.degrees([alpha_x, alpha_y, alpha_z]), angle

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {"unit": self.unit, "matrix": [list(r) for r in self.matrix],
                "bias": list(self.bias), "method": self.method}

    @classmethod
    def from_dict(cls, sensor: str, d: dict[str, Any]) -> TriadCalibration:
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError``."""
        unknown = set(d) - {"unit", "matrix", "bias", "method"}
        if unknown or "unit" not in d:
            raise ValueError(
                f"{sensor}: expected keys unit, matrix, bias, method (unit required); "
                f"got {sorted(d)}"
            )
        return cls(sensor, d.get("matrix", cls.matrix), d.get("bias", cls.bias), d["unit"],
                   d.get("method", ""))


@dataclass(frozen=True)
class Calibration:
    """A MARG sensor's calibration: ``x̂ = K⁻¹ (y - b)`` per triad (module docstring).

    Attributes
    ----------
    gyr, acc : :class:`TriadCalibration` of the gyroscope (rad/s) and accelerometer (m/s²).
    mag : of the magnetometer (µT), or None (the magnetometer is left as measured).
    reference : gravity and field measured in the reference pose (000 step 18), or None.
    noise : noise densities from an Allan analysis (003 III-B), or None.
    version : file format version (1).
    source : where it came from (command, recording).
    notes : free remarks (what was checked, quality figures).
    """

    gyr: TriadCalibration = field(default_factory=lambda: TriadCalibration.identity("gyr"))
    acc: TriadCalibration = field(default_factory=lambda: TriadCalibration.identity("acc"))
    mag: TriadCalibration | None = None
    reference: ReferenceVectors | None = None
    noise: NoiseDensities | None = None
    version: int = VERSION
    source: str = ""
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name, triad in (("gyr", self.gyr), ("acc", self.acc), ("mag", self.mag)):
            if triad is None and name == "mag":
                continue
            if not isinstance(triad, TriadCalibration) or triad.sensor != name:
                raise ValueError(f"{name} must be a TriadCalibration for sensor {name!r}")
        if self.version != VERSION:
            raise ValueError(
                f"calibration version {self.version} is not supported; this margtrack reads "
                f"version {VERSION}"
            )
        object.__setattr__(self, "notes", tuple(str(n) for n in self.notes))

    def apply(self, recording: Recording) -> Recording:
        """A new Recording with gyr, acc (and mag, if calibrated) corrected; the input is untouched.

        The output's ``meta["calibration"]`` records the source; a recording that already
        has one is refused (correcting twice would be wrong) with ``ValueError``.
        """
        if "calibration" in recording.meta:
            raise ValueError(
                f"recording {recording.name!r} is already calibrated "
                f"({recording.meta['calibration']}); apply a calibration to raw data only"
            )
        meta = {**recording.meta, "calibration": {"version": self.version, "source": self.source}}
        mag = recording.mag
        if self.mag is not None and mag is not None:
            mag = self.mag.correct(mag)
        return dataclasses.replace(
            recording,
            gyr=self.gyr.correct(recording.gyr),
            acc=self.acc.correct(recording.acc),
            mag=mag,
            meta=meta,
        )

    def parameter_values(self, params_type: type) -> dict[str, float]:
        """The parameters of a method this calibration sets, by their declarations.

        Every parameter declared with ``calibrated_by="reference.field_ut"`` (or
        ``"noise.<field>"``) takes that quantity when the file has it: the reference field
        (000 App. B step 18: norm and dip) reaches every method, the Allan noise densities
        (003 III-B) the noise parameters of the methods that declare them. A quantity in
        rad is converted to deg for a parameter whose unit is in deg.
        """
        from margtrack.estimator.params import specs

        out: dict[str, float] = {}
        for spec in specs(params_type):
            if not spec.calibrated_by:
                continue
            part, _, name = spec.calibrated_by.partition(".")
            source = {"reference": self.reference, "noise": self.noise}.get(part)
            if source is None:
                continue
            value = float(getattr(source, name))
            if "rad" in name and spec.unit.startswith("deg"):
                value = math.degrees(value)
            out[spec.name] = value
        return out

    def to_dict(self) -> dict[str, Any]:
        """The JSON layout: format, version, model, gyr, acc, mag, reference, noise, ..."""
        return {
            "format": FORMAT,
            "version": self.version,
            "model": "y = K x + b (K = matrix, b = bias); corrected x = K^-1 (y - b)",
            "gyr": self.gyr.to_dict(),
            "acc": self.acc.to_dict(),
            "mag": None if self.mag is None else self.mag.to_dict(),
            "reference": None if self.reference is None else self.reference.to_dict(),
            "noise": None if self.noise is None else self.noise.to_dict(),
            "source": self.source,
            "notes": list(self.notes),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Calibration:
        """Inverse of :meth:`to_dict`, checking format, version, keys and units."""
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ValueError(f"not a margtrack calibration: 'format' must be {FORMAT!r}")
        version = d.get("version")
        if not isinstance(version, int) or version > VERSION:
            raise ValueError(
                f"calibration version {version!r} is newer than this margtrack reads "
                f"({VERSION}); upgrade margtrack"
            )
        allowed = {"format", "version", "model", "gyr", "acc", "mag", "reference", "noise",
                   "source", "notes"}
        unknown = set(d) - allowed
        if unknown:
            raise ValueError(
                f"unknown calibration keys {sorted(unknown)}; allowed {sorted(allowed)}"
            )
        return cls(
            gyr=TriadCalibration.from_dict("gyr", d["gyr"]),
            acc=TriadCalibration.from_dict("acc", d["acc"]),
            mag=None if d.get("mag") is None else TriadCalibration.from_dict("mag", d["mag"]),
            reference=None if d.get("reference") is None
            else ReferenceVectors.from_dict(d["reference"]),
            noise=None if d.get("noise") is None else NoiseDensities.from_dict(d["noise"]),
            version=version,
            source=str(d.get("source", "")),
            notes=tuple(d.get("notes", ())),
        )

    def to_json(self) -> str:
        """:meth:`to_dict` as indented JSON text (floats round-trip exactly)."""
        return json.dumps(self.to_dict(), indent=2, ensure_ascii=False) + "\n"


def save_calibration(calibration: Calibration, path: str | Path) -> Path:
    """Write ``calibration`` to ``path`` as JSON and return the path."""
    out = Path(path)
    out.write_text(calibration.to_json(), encoding="utf-8")
    return out


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration JSON written by :func:`save_calibration` (or by hand, same layout)."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no calibration file at {p}")
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p} is not valid JSON: {exc}") from None
    return Calibration.from_dict(d)
