"""Recursive filters: gyro propagation corrected by accelerometer and magnetometer.

Each filter's module loads on first use (``margtrack.filters.Robust`` imports
``margtrack.filters.robust`` only), so a command running one filter loads no other.
"""

from __future__ import annotations

from margtrack.lazy import lazy_names

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


__getattr__, __dir__ = lazy_names(__name__, _WHERE)
