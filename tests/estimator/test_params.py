"""Declared parameters: one declaration drives validation, specs and defaults."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from margtrack import methods
from margtrack.estimator.params import Params, param, specs


@dataclasses.dataclass(frozen=True)
class _Demo(Params):
    tau_s: float = param(2.0, unit="s", gt=0, help="time constant")
    weight: float = param(0.5, ge=0, le=1, help="a weight")
    count: int = param(3, ge=1, help="iterations")
    axes: tuple[float, ...] | float = param(0.1, unit="s", gt=0, help="per axis")
    dip_deg: float | None = param(None, unit="deg", ge=-90, le=90, help="None: measured")
    mode: str = param("fast", choices=("fast", "slow"), help="how")

    def check(self) -> None:
        super().check()
        if self.mode == "slow" and self.count < 2:
            raise ValueError("mode 'slow' needs count >= 2")


def test_declared_bounds_are_enforced_with_name_unit_and_range():
    with pytest.raises(ValueError, match=r"tau_s must be a finite number, > 0 s; got -1"):
        _Demo(tau_s=-1.0)
    with pytest.raises(ValueError, match=r"parameter tau_s .* got nan"):
        _Demo(tau_s=math.nan)
    with pytest.raises(ValueError, match=r"weight must be a finite number, >= 0 and <= 1"):
        _Demo(weight=1.5)
    with pytest.raises(ValueError, match=r"parameter count must be a whole number"):
        _Demo(count=2.5)
    with pytest.raises(ValueError, match=r"parameter mode must be one of 'fast', 'slow'"):
        _Demo(mode="medium")
    with pytest.raises(ValueError, match=r"parameter axes .* > 0 s; got"):
        _Demo(axes=(0.1, -0.2, 0.3))
    with pytest.raises(ValueError, match="needs count >= 2"):
        _Demo(mode="slow", count=1)


def test_values_are_normalised_and_none_is_allowed_only_where_declared():
    d = _Demo(count=4.0, axes=[0.1, 0.2, 0.3], dip_deg=None)
    assert d.count == 4 and isinstance(d.count, int)
    assert d.axes == (0.1, 0.2, 0.3)
    with pytest.raises(ValueError, match="parameter tau_s must be given"):
        _Demo(tau_s=None)


def test_specs_list_every_field_with_unit_help_and_default():
    by_name = {s.name: s for s in specs(_Demo)}
    assert by_name["tau_s"].unit == "s" and by_name["tau_s"].default == 2.0
    assert by_name["tau_s"].help == "time constant"
    assert by_name["weight"].bounds_text() == ">= 0 and <= 1"
    assert by_name["mode"].bounds_text() == "fast | slow"
    # the shared input policy is declared in the base, in front of the method's own
    names = list(by_name)
    assert names[:2] == ["frame", "gyr_range_deg_s"]
    assert {"max_gap_s", "acc_range_g", "strict", "mag_stuck_s"} <= set(names)


@pytest.mark.parametrize("name", methods.available())
def test_every_registered_parameter_is_declared_with_help(name):
    cls = methods.get(name)
    for spec in specs(cls.params_type):
        assert spec.help, f"{name}: parameter {spec.name} has no help"
    cls.params_type()  # the defaults pass their own declaration


def test_base_policy_parameters_are_validated():
    with pytest.raises(ValueError, match="parameter max_gap_s must be a finite number, > 0 s"):
        Params(max_gap_s=0.0)
    with pytest.raises(ValueError, match="parameter gyr_range_deg_s"):
        Params(gyr_range_deg_s=-2000.0)
    with pytest.raises(ValueError, match="frame must be 'NED' or 'ENU'"):
        Params(frame="NWU")
    assert Params(frame="ned").frame == "NED"


def test_wrong_types_name_the_parameter():
    with pytest.raises(ValueError, match="parameter axes must be a number, got 'a'"):
        _Demo(axes=("a", 1.0))
    with pytest.raises(ValueError, match="parameter count must be a number, got True"):
        _Demo(count=True)
    with pytest.raises(ValueError, match=r"parameter axes .* got -0.2$"):
        _Demo(axes=np.array([0.1, -0.2]))
    with pytest.raises(ValueError, match="parameter strict must be true or false, got 1"):
        Params(strict=1)
