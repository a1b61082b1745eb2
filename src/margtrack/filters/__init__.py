"""Recursive filters: gyro propagation corrected by accelerometer and magnetometer."""

from margtrack.filters.gyro import GyroIntegration, GyroParams

__all__ = ["GyroIntegration", "GyroParams"]
