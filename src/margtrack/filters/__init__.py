"""Recursive filters: gyro propagation corrected by accelerometer and magnetometer."""

from margtrack.filters.bias_kf import BiasKalman, BiasKalmanParams
from margtrack.filters.complementary import Bachmann, BachmannAccMag, BachmannParams
from margtrack.filters.ekf import MarinsEkf, MarinsEkfParams
from margtrack.filters.gradient import Gradient, GradientParams, align_to_gyro
from margtrack.filters.gyro import GyroIntegration, GyroParams
from margtrack.filters.robust import Robust, RobustParams

__all__ = [
    "Bachmann",
    "BachmannAccMag",
    "BachmannParams",
    "BiasKalman",
    "BiasKalmanParams",
    "Gradient",
    "GradientParams",
    "GyroIntegration",
    "GyroParams",
    "MarinsEkf",
    "MarinsEkfParams",
    "Robust",
    "RobustParams",
    "align_to_gyro",
]
