"""Recursive filters: gyro propagation corrected by accelerometer and magnetometer."""

from margtrack.filters.gyro import GyroIntegration, GyroParams
from margtrack.filters.robust import Robust, RobustParams

__all__ = ["GyroIntegration", "GyroParams", "Robust", "RobustParams"]
