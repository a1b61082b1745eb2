"""Single-frame estimators: the orientation of each sample from its accelerometer and
magnetometer alone (TRIAD, QUEST, FQA, Davenport's q-method, Gauss-Newton and Newton).

Each estimator's module loads on first use (``margtrack.single_frame.Fqa`` imports
``margtrack.single_frame.fqa`` only), so a command running one method loads no other.
"""

from __future__ import annotations

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
    "Fqa",
    "FqaParams",
    "GaussNewton",
    "GaussNewtonParams",
    "Newton",
    "NewtonParams",
    "Quest",
    "QuestParams",
    "Triad",
    "TriadParams",
]


__getattr__, __dir__ = lazy_names(__name__, _WHERE)
