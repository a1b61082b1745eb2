"""The registry of estimation methods, by the names the CLI and the benchmarks use.

A later method joins by adding its name, module and class to ``_WHERE``; nothing else changes.
``"default"`` names the recommended method (the best one measured on BROAD so far).
"""

from __future__ import annotations

import dataclasses
import importlib
import types
import typing
from collections.abc import Iterable, Mapping
from typing import Any

from margtrack.estimators.base import Estimator, Params

__all__ = [
    "DEFAULT_METHOD",
    "available",
    "create",
    "get",
    "parse_params",
    "parse_params_items",
]

#: name -> (module, class): a method's module is imported only when the method is used, so a
#: command running one method does not load the others (``tests/test_methods.py`` checks that
#: each name equals its class's ``name``)
_WHERE: Mapping[str, tuple[str, str]] = types.MappingProxyType({
    "bachmann": ("margtrack.filters.complementary", "Bachmann"),
    "bachmann-accmag": ("margtrack.filters.complementary", "BachmannAccMag"),
    "bias-kf": ("margtrack.filters.bias_kf", "BiasKalman"),
    "davenport": ("margtrack.estimators.davenport", "Davenport"),
    "fqa": ("margtrack.estimators.fqa", "Fqa"),
    "gauss-newton": ("margtrack.estimators.gauss_newton", "GaussNewton"),
    "gradient": ("margtrack.filters.gradient", "Gradient"),
    "gyro": ("margtrack.filters.gyro", "GyroIntegration"),
    "ekf": ("margtrack.filters.ekf", "MarinsEkf"),
    "newton": ("margtrack.estimators.gauss_newton", "Newton"),
    "quest": ("margtrack.estimators.quest", "Quest"),
    "robust": ("margtrack.filters.robust", "Robust"),
    "robust-offline": ("margtrack.filters.robust_offline", "RobustOffline"),
    "triad": ("margtrack.estimators.triad", "Triad"),
})

#: The recommended method; ``"default"`` resolves to it: the best measured on BROAD so far.
#: Mean total RMSE over the 16 trials with default parameters: robust 2.03 deg (VQF 2.76
#: deg in the same run), gyro 28.8 deg, TRIAD 47.8 deg.
DEFAULT_METHOD = "robust"


def available() -> list[str]:
    """Registered method names (``"default"`` not included)."""
    return sorted(_WHERE)


def get(name: str) -> type[Estimator]:
    """The estimator class registered under ``name`` (``"default"`` is the recommended one)."""
    key = DEFAULT_METHOD if name == "default" else name
    try:
        module, attr = _WHERE[key]
    except KeyError:
        raise ValueError(
            f"unknown method {name!r}; available: {', '.join(['default', *available()])}"
        ) from None
    return getattr(importlib.import_module(module), attr)


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
