"""Recursive filters: gyro propagation corrected by accelerometer and magnetometer.

Each filter's module loads on first use (``margtrack.filters.Robust`` imports
``margtrack.filters.robust`` only), so a command running one filter loads no other.
"""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "Bachmann": "complementary",
    "BachmannAccMag": "complementary",
    "BachmannParams": "complementary",
    "BiasKalman": "bias_kf",
    "BiasKalmanParams": "bias_kf",
    "Gradient": "gradient",
    "GradientParams": "gradient",
    "GyroIntegration": "gyro",
    "GyroParams": "gyro",
    "MarinsEkf": "ekf",
    "MarinsEkfParams": "ekf",
    "Robust": "robust",
    "RobustOffline": "robust_offline",
    "RobustParams": "robust",
    "align_to_gyro": "gradient",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(__all__) | set(globals()))
