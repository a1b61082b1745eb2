"""The registry of estimation methods, by the names the CLI and the benchmarks use.

One :class:`MethodRecord` per method in :data:`RECORDS`: a new method joins with one record
(``docs/adding_a_method.md``). ``"default"`` names the recommended method (the best one
measured on BROAD so far).
"""

from __future__ import annotations

import dataclasses
import importlib
import types
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from margtrack.estimator import Estimator, Params

__all__ = [
    "DEFAULT_METHOD",
    "RECORDS",
    "GridParam",
    "MethodRecord",
    "available",
    "create",
    "get",
    "parse_params",
    "parse_params_items",
    "record",
]

@dataclass(frozen=True)
class GridParam:
    """Candidate values of one parameter of a tuning grid and why it is in the grid."""

    values: tuple[float | int | str, ...]
    reason: str


@dataclass(frozen=True)
class MethodRecord:
    """One method: its name, where its class is (imported on first use, so a command running
    one method loads no other), whether it runs sample by sample (online: ``update``) or on
    whole recordings (offline), and its tuning grid: the parameters whose defaults were
    chosen on BROAD, 3-5 candidates each around the default (``margtrack tune --cv`` and
    ``margtrack bench broad`` read it)."""

    name: str
    module: str
    cls: str
    online: bool = True
    grid: Mapping[str, GridParam] = dataclasses.field(default_factory=dict)


_NORM_TOL = GridParam((0.15, 0.25, 0.4),
                      "the screening's field-norm gate, most of its gain on BROAD")

#: every method, one record each (``tests/test_methods.py`` checks that each name equals its
#: class's ``name``)
RECORDS: tuple[MethodRecord, ...] = (
    MethodRecord("bachmann", "margtrack.methods.bachmann", "Bachmann", grid={
        "gain": GridParam((0.03, 0.06, 0.12), "drift-correction gain k, tuned on BROAD"),
        "mag_weight": GridParam((0.5, 0.7, 1.0), "magnetic weight rho, tuned on BROAD"),
        "mag_norm_tol": _NORM_TOL,
    }),
    MethodRecord("bachmann-accmag", "margtrack.methods.bachmann", "BachmannAccMag"),
    MethodRecord("bias-kf", "margtrack.methods.bias_kf", "BiasKalman", grid={
        "acc_motion_fraction": GridParam(
            (0.01, 0.02, 0.04), "body acceleration as noise: coordinate search on BROAD"),
        "tilt_gate": GridParam((10.0, 20.0, 40.0), "soft tilt gate: coordinate search on BROAD"),
        "mag_dip_correlation_s": GridParam(
            (0.25, 0.5, 1.0), "field noise from the dip: coordinate search on BROAD"),
    }),
    MethodRecord("davenport", "margtrack.single_frame.davenport", "Davenport"),
    MethodRecord("ekf", "margtrack.methods.ekf", "MarinsEkf", grid={
        "quat_noise_per_sqrt_hz": GridParam(
            (0.0375, 0.075, 0.15), "Gauss-Newton measurement noise, tuned on BROAD"),
        "tau_s": GridParam((0.15, 0.3, 0.6), "rate-model time constant, confirmed on BROAD"),
        "mag_norm_tol": _NORM_TOL,
        "mag_disturbance_s": GridParam(
            (0.3, 1.0, 3.0), "correlation time of field disturbances in the quaternion's noise"),
    }),
    MethodRecord("fqa", "margtrack.single_frame.fqa", "Fqa"),
    MethodRecord("gauss-newton", "margtrack.single_frame.gauss_newton", "GaussNewton"),
    MethodRecord("gradient", "margtrack.methods.gradient", "Gradient", grid={
        "beta": GridParam((0.0125, 0.018, 0.025, 0.035, 0.05),
                          "Madgwick's step: the best single value on BROAD (DEFAULT_BETA)"),
        "mag_norm_tol": _NORM_TOL,
    }),
    MethodRecord("gyro", "margtrack.methods.gyro", "GyroIntegration"),
    MethodRecord("newton", "margtrack.single_frame.gauss_newton", "Newton"),
    MethodRecord("quest", "margtrack.single_frame.quest", "Quest"),
    MethodRecord("robust", "margtrack.methods.robust", "Robust", grid={
        "tau_acc_s": GridParam(
            (2.0, 3.0, 4.5), "inclination time constant, set by hand against BROAD's errors"),
        "tau_mag_s": GridParam(
            (10.0, 20.0, 40.0), "heading time constant, set by hand against BROAD's errors"),
        "mag_new_reference_s": GridParam(
            (10.0, 20.0, 40.0), "when a new steady field is trusted: fitted to the magnet trials"),
    }),
    MethodRecord("smoother", "margtrack.methods.smoother", "Smoother", online=False, grid={
        "motion_walk_deg_s_sqrt_hz": GridParam(
            (0.3, 1.0, 3.0), "the orientation's walk in motion: BROAD is flat over 0.3-3"),
        "acc_lowpass_hz": GridParam(
            (0.0, 0.5, 1.0), "the accelerometer's low-pass before the filter: none or 0.5-1 Hz"),
    }),
    MethodRecord("triad", "margtrack.single_frame.triad", "Triad"),
)

_BY_NAME: Mapping[str, MethodRecord] = types.MappingProxyType({r.name: r for r in RECORDS})

#: methods that were removed: name -> (what replaces it, why), for the error that says so
_REPLACED: Mapping[str, tuple[str, str]] = types.MappingProxyType({
    "robust-offline": (
        "smoother",
        "a Kalman filter forwards and a Rauch-Tung-Striebel pass backwards, with robust's "
        "parameters and detectors; as accurate on BROAD, better on simulated disturbances "
        "and after gaps",
    ),
})

#: The recommended method; ``"default"`` resolves to it: the best measured on BROAD so far.
#: Mean total RMSE over the 16 trials with default parameters: robust 2.03 deg (VQF 2.76
#: deg in the same run), gyro 28.8 deg, TRIAD 47.8 deg.
DEFAULT_METHOD = "robust"


def available() -> list[str]:
    """Registered method names (``"default"`` not included)."""
    return sorted(_BY_NAME)


def record(name: str) -> MethodRecord:
    """The record of the method ``name`` (``"default"`` is the recommended one)."""
    key = DEFAULT_METHOD if name == "default" else name
    try:
        return _BY_NAME[key]
    except KeyError:
        if name in _REPLACED:
            new, why = _REPLACED[name]
            raise ValueError(
                f"method {name!r} was replaced by {new!r} ({why}); use {new!r}"
            ) from None
        raise ValueError(
            f"unknown method {name!r}; available: {', '.join(['default', *available()])}"
        ) from None


def get(name: str) -> type[Estimator]:
    """The estimator class registered under ``name`` (``"default"`` is the recommended one)."""
    found = record(name)
    return getattr(importlib.import_module(found.module), found.cls)


def _coerce(value: Any, annotation: Any, name: str) -> Any:
    if not isinstance(value, str):
        return value
    hint = annotation
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if value.lower() in ("none", "null"):
            return None
        # "1,2,3" for a union that admits a tuple (per-axis values), else the first type
        tuples = [a for a in args if a is tuple or typing.get_origin(a) is tuple]
        hint = tuples[0] if tuples and "," in value else (args[0] if args else str)
    if hint is bool:
        low = value.lower()
        if low in ("1", "true", "yes", "on"):
            return True
        if low in ("0", "false", "no", "off"):
            return False
        raise ValueError(f"parameter {name} must be true or false, got {value!r}")
    if hint in (int, float):
        try:
            return hint(value)
        except ValueError:
            raise ValueError(f"parameter {name} must be a {hint.__name__}, got {value!r}") from None
    if typing.get_origin(hint) is tuple or hint is tuple:
        return tuple(float(v) for v in value.strip("()[] ").split(","))
    return value


def parse_params_items(items: Iterable[str]) -> dict[str, str]:
    """``["gain=0.1", "mag-weight=1"]`` to ``{"gain": "0.1", "mag_weight": "1"}``."""
    pairs = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"parameters are given as name=value, got {item!r}")
        key, _, value = item.partition("=")
        pairs[key.strip().replace("-", "_")] = value.strip()
    return pairs


def parse_params(params_type: type[Params], items: Iterable[str] | Mapping[str, Any]) -> Params:
    """Build ``params_type`` from ``name=value`` strings (CLI) or a mapping, coercing types.

    An unknown name raises ``ValueError`` with the closest valid names ("did you mean
    tau_acc_s?", as a mistyped command gets), or the valid names when none is close;
    values are validated by the dataclass itself.
    """
    import difflib

    pairs = dict(items) if isinstance(items, Mapping) else parse_params_items(items)
    hints = typing.get_type_hints(params_type)
    fields = sorted(f.name for f in dataclasses.fields(params_type))
    for name in sorted(set(pairs) - set(fields)):
        close = difflib.get_close_matches(name, fields, n=1, cutoff=0.6)
        if close:
            raise ValueError(f"unknown parameter {name!r}; did you mean {close[0]}?")
        raise ValueError(f"unknown parameter {name!r}; the parameters are {', '.join(fields)}")
    values = {k: _coerce(v, hints[k], k) for k, v in pairs.items()}
    return params_type(**values)


def create(
    name: str,
    params: Iterable[str] | Mapping[str, Any] = (),
    *,
    rate_hz: float | None = None,
) -> Estimator:
    """A new estimator of method ``name`` with parameters from strings or a mapping."""
    cls = get(name)
    return cls(parse_params(cls.params_type, params), rate_hz=rate_hz)
