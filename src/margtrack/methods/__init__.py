"""The recursive methods, one folder each, and the registry of every method by name.

Each folder holds one method whole: its parameters and estimator class (``__init__.py``)
and its compiled step (``kernel.py``, on the skeleton in :mod:`margtrack.estimator`).
``margtrack.methods.create("robust")`` and the other registry functions are those of
:mod:`margtrack.registry`; a class (``margtrack.methods.Robust``) loads its folder on first
use, so a command running one method loads no other.
"""

from __future__ import annotations

from margtrack.lazy import lazy_names
from margtrack.registry import (
    DEFAULT_METHOD,
    RECORDS,
    available,
    create,
    get,
    parse_params,
    parse_params_items,
    record,
)

_WHERE = {
    "Bachmann": "bachmann",
    "BachmannAccMag": "bachmann",
    "BachmannParams": "bachmann",
    "BiasKalman": "bias_kf",
    "BiasKalmanParams": "bias_kf",
    "Gradient": "gradient",
    "GradientParams": "gradient",
    "GyroIntegration": "gyro",
    "GyroParams": "gyro",
    "MarinsEkf": "ekf",
    "MarinsEkfParams": "ekf",
    "Robust": "robust",
    "Smoother": "smoother",
    "RobustParams": "robust",
}

__all__ = [
    "DEFAULT_METHOD",
    "RECORDS",
    "available",
    "create",
    "get",
    "parse_params",
    "parse_params_items",
    "record",
    *sorted(_WHERE),
]

__getattr__, __dir__ = lazy_names(
    __name__, _WHERE,
    eager=["DEFAULT_METHOD", "RECORDS", "available", "create", "get", "parse_params",
           "parse_params_items", "record"],
)
