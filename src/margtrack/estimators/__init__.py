"""Single-frame estimators (accelerometer + magnetometer only) and the estimator contract.

Each estimator's module loads on first use (``margtrack.estimators.Fqa`` imports
``margtrack.estimators.fqa`` only), so a command running one method loads no other.
"""

from __future__ import annotations

import importlib
from typing import Any

from margtrack.estimators.base import Estimate, Estimator, Params, State, initial_orientation

_WHERE = {
    "Davenport": "davenport",
    "DavenportParams": "davenport",
    "Fqa": "fqa",
    "FqaParams": "fqa",
    "GaussNewton": "gauss_newton",
    "GaussNewtonParams": "gauss_newton",
    "Newton": "gauss_newton",
    "NewtonParams": "gauss_newton",
    "Quest": "quest",
    "QuestParams": "quest",
    "Triad": "triad",
    "TriadParams": "triad",
}

__all__ = [
    "Davenport",
    "DavenportParams",
    "Estimate",
    "Estimator",
    "Fqa",
    "FqaParams",
    "GaussNewton",
    "GaussNewtonParams",
    "Newton",
    "NewtonParams",
    "Params",
    "Quest",
    "QuestParams",
    "State",
    "Triad",
    "TriadParams",
    "initial_orientation",
]


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(__all__) | set(globals()))
