"""Single-frame estimators (accelerometer + magnetometer only) and the estimator contract."""

from margtrack.estimators.base import Estimate, Estimator, Params, State, initial_orientation
from margtrack.estimators.davenport import Davenport, DavenportParams
from margtrack.estimators.fqa import Fqa, FqaParams
from margtrack.estimators.gauss_newton import GaussNewton, GaussNewtonParams, Newton, NewtonParams
from margtrack.estimators.quest import Quest, QuestParams
from margtrack.estimators.triad import Triad, TriadParams

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
