"""Single-frame estimators (accelerometer + magnetometer only) and the estimator contract.

Each estimator's module loads on first use (``margtrack.estimators.Fqa`` imports
``margtrack.estimators.fqa`` only), so a command running one method loads no other.
"""

from __future__ import annotations

from margtrack.estimators.base import Estimate, Estimator, Params, State, initial_orientation
from margtrack.lazy import lazy_names

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


__getattr__, __dir__ = lazy_names(
    __name__, _WHERE, eager=["Estimate", "Estimator", "Params", "State", "initial_orientation"]
)
