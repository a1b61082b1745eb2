"""Single-frame estimators (accelerometer + magnetometer only) and the estimator contract."""

from margtrack.estimators.base import Estimate, Estimator, Params, State, initial_orientation
from margtrack.estimators.triad import Triad, TriadParams

__all__ = [
    "Estimate",
    "Estimator",
    "Params",
    "State",
    "Triad",
    "TriadParams",
    "initial_orientation",
]
