"""Parameters declared once per field: default, unit, bounds, one line of help.

A method's parameters are a frozen dataclass whose fields are made with :func:`param`.
That one declaration drives everything else: validation at construction (a bad value
raises ``ValueError`` naming the parameter, its unit and the allowed range), the
``margtrack methods`` table, ``-p name=value`` parsing, calibration-file overrides and the
live page's controls (label, unit, help)::

    @dataclass(frozen=True)
    class RobustParams(Params):
        tau_acc_s: float = param(3.0, unit="s", gt=0, help="inclination correction time constant")

The base :class:`Params` declares what every method shares: the output ``frame`` and the
input policy (sensor ranges, the longest interval integrated over, strict mode).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass
from typing import Any

import numpy as np

from margtrack import frames
from margtrack.frames import Frame

__all__ = ["ParamSpec", "Params", "param", "specs"]


@dataclass(frozen=True)
class ParamSpec:
    """What one parameter is: its unit, bounds and help, as declared by :func:`param`.

    gt/ge/lt/le : exclusive/inclusive bounds (None: unbounded); they apply to every
        element of a tuple value. choices : the allowed values of a string parameter.
    none_ok : whether ``None`` is allowed (it means "measure it" or "off"; see help).
    calibrated_by : the calibration-file quantity that sets this parameter when a
        calibration is given (``"reference.field_ut"``, ``"noise.gyr_bias_walk_rad_s2_sqrt_hz"``);
        a quantity in rad (its name says so) is converted to degrees when ``unit`` is in deg.
    """

    name: str
    default: Any
    type: Any
    unit: str = ""
    help: str = ""
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[Any, ...] | None = None
    none_ok: bool = False
    calibrated_by: str | None = None

    @property
    def label(self) -> str:
        """A label for people: the name in words and the unit, ``"tau acc s [s]"``."""
        words = self.name.replace("_", " ")
        return f"{words} [{self.unit}]" if self.unit else words

    def bounds_text(self) -> str:
        """The allowed range as text: ``"> 0"``, ``"0 ... 1"``, ``"ENU | NED"``."""
        if self.choices is not None:
            return " | ".join(str(c) for c in self.choices)
        parts = []
        if self.gt is not None:
            parts.append(f"> {_num(self.gt)}")
        if self.ge is not None:
            parts.append(f">= {_num(self.ge)}")
        if self.lt is not None:
            parts.append(f"< {_num(self.lt)}")
        if self.le is not None:
            parts.append(f"<= {_num(self.le)}")
        return " and ".join(parts) if parts else "any"

    def check(self, value: Any) -> Any:
        """The validated value (ints given for floats become floats); raises ValueError."""
        if value is None:
            if self.none_ok:
                return None
            raise ValueError(f"parameter {self.name} must be given (None is not allowed)")
        if self.choices is not None:
            if value not in self.choices:
                raise ValueError(
                    f"parameter {self.name} must be one of {', '.join(map(repr, self.choices))}, "
                    f"got {value!r}"
                )
            return value
        if self.type is bool:
            if not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"parameter {self.name} must be true or false, got {value!r}")
            return bool(value)
        if isinstance(value, (bool, np.bool_)):
            raise ValueError(f"parameter {self.name} must be a number, got {value!r}")
        if isinstance(value, (tuple, list, np.ndarray)):
            return tuple(self._number(v) for v in np.ravel(np.asarray(value, dtype=object)))
        return self._number(value)

    def _number(self, value: Any) -> float | int:
        if isinstance(value, (bool, np.bool_)):
            raise ValueError(f"parameter {self.name} must be a number, got {value!r}")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"parameter {self.name} must be a number, got {value!r}") from None
        value = value.item() if isinstance(value, np.generic) else value
        unit = f" {self.unit}" if self.unit else ""
        ok = math.isfinite(number)
        ok = ok and (self.gt is None or number > self.gt) and (self.ge is None or number >= self.ge)
        ok = ok and (self.lt is None or number < self.lt) and (self.le is None or number <= self.le)
        if not ok:
            raise ValueError(
                f"parameter {self.name} must be a finite number, {self.bounds_text()}{unit}; "
                f"got {value!r}"
            )
        if isinstance(value, (int, np.integer)) and self.type is int:
            return int(value)
        if self.type is int:
            if number != int(number):
                raise ValueError(f"parameter {self.name} must be a whole number, got {value!r}")
            return int(number)
        return number


def _num(x: float) -> str:
    return f"{x:g}"


def param(
    default: Any,
    *,
    unit: str = "",
    help: str = "",
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: tuple[Any, ...] | None = None,
    calibrated_by: str | None = None,
    none_ok: bool | None = None,
) -> Any:
    """A dataclass field declaring one parameter: default, unit, bounds and help.

    ``None`` as default means the parameter may be None (for example "measure the dip
    from the first sample"); ``none_ok=True`` allows None with another default (None then
    means "off", say so in help). Bounds apply to numbers and to each element of tuples.
    ``calibrated_by`` names the calibration-file quantity that sets it (see ParamSpec).
    """
    meta = {
        "param": {
            "unit": unit,
            "help": help,
            "gt": gt,
            "ge": ge,
            "lt": lt,
            "le": le,
            "choices": choices,
            "none_ok": default is None if none_ok is None else none_ok,
            "calibrated_by": calibrated_by,
        }
    }
    return dataclasses.field(default=default, metadata=meta)


def specs(params_type: type[Params] | Params) -> list[ParamSpec]:
    """The declared parameters of a Params class (or instance), in declaration order.

    Fields declared without :func:`param` get a spec with their default and type only.
    """
    cls = params_type if isinstance(params_type, type) else type(params_type)
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        declared = dict(f.metadata.get("param", {}))
        default = f.default if f.default is not dataclasses.MISSING else None
        hint = _base_type(hints.get(f.name, Any))
        if hint is Any and default is not None:
            hint = type(default)
        if not declared:
            declared = {"none_ok": default is None}
        out.append(ParamSpec(name=f.name, default=default, type=hint, **declared))
    return out


def _declares_rule(spec: ParamSpec) -> bool:
    """Whether a spec says anything to check (undeclared fields are left alone)."""
    bounds = (spec.gt, spec.ge, spec.lt, spec.le, spec.choices)
    return spec.type is bool or any(b is not None for b in bounds)


def _base_type(hint: Any) -> Any:
    """float for ``float | None``, tuple for ``tuple[float, ...] | float``, as declared."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        return args[0] if len(args) == 1 else hint
    if hint is Frame or origin is typing.Literal:
        return str
    return hint


@dataclass(frozen=True)
class Params:
    """Parameters every method shares: the output frame and the input policy.

    Subclasses add their own fields with :func:`param`; every declared field is validated
    at construction. A cross-field rule goes in :meth:`check`, which subclasses extend.
    """

    frame: Frame = param(
        "ENU", choices=("ENU", "NED"), help="earth frame of the output orientation"
    )
    gyr_range_deg_s: float = param(
        2000.0,
        unit="deg/s",
        gt=0,
        help="gyroscope range: a rate at or beyond it is flagged and not integrated",
    )
    acc_range_g: float = param(
        16.0,
        unit="g",
        gt=0,
        help="accelerometer range: a sample at or beyond it is flagged and not used",
    )
    max_gap_s: float = param(
        0.25,
        unit="s",
        gt=0,
        help="longest interval integrated over; a longer gap restarts the filter",
    )
    mag_stuck_s: float = param(
        0.5,
        unit="s",
        gt=0,
        help="a field axis unchanged this long while turning is stuck or clipped: ignored",
    )
    mag_norm_tol: float = param(
        0.25,
        gt=0,
        help="relative deviation of the field norm from its reference that counts as disturbed",
    )
    mag_dip_tol_deg: float = param(
        20.0,
        unit="deg",
        gt=0,
        help="deviation of the dip from its reference that counts as disturbed",
    )
    mag_norm_ref: float | None = param(
        None,
        gt=0,
        calibrated_by="reference.field_ut",
        help="reference field norm, any unit (None: learned from the data; calibration sets it)",
    )
    mag_dip_ref_deg: float | None = param(
        None,
        unit="deg",
        calibrated_by="reference.dip_deg",
        ge=-90,
        le=90,
        help="reference dip, positive down (None: learned from the data; calibration sets it)",
    )
    strict: bool = param(
        False, help="raise on the first flagged sample instead of flagging and skipping it"
    )

    def __post_init__(self) -> None:
        object.__setattr__(self, "frame", frames.check_frame(self.frame))
        for spec in specs(self):
            if spec.name != "frame" and _declares_rule(spec):
                object.__setattr__(self, spec.name, spec.check(getattr(self, spec.name)))
        self.check()

    def check(self) -> None:
        """Cross-field rules of the method (subclasses extend); raise ``ValueError``."""

    def as_dict(self) -> dict[str, Any]:
        """Parameters as a plain dict (arrays as lists), for reports and JSON."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            out[f.name] = value.tolist() if isinstance(value, np.ndarray) else value
        return out
