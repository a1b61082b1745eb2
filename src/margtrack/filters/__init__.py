"""Recursive filters: gyro propagation corrected by accelerometer and magnetometer."""

from margtrack.filters.complementary import Bachmann, BachmannAccMag, BachmannParams
from margtrack.filters.gyro import GyroIntegration, GyroParams
from margtrack.filters.robust import Robust, RobustParams

__all__ = [
    "Bachmann",
    "BachmannAccMag",
    "BachmannParams",
    "GyroIntegration",
    "GyroParams",
    "Robust",
    "RobustParams",
]
