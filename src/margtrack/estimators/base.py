"""Moved to :mod:`margtrack.estimator` (the contract every method builds on); kept as an alias."""

from margtrack.estimator.contract import Estimator
from margtrack.estimator.estimate import Estimate, State
from margtrack.estimator.initial import initial_orientation
from margtrack.estimator.params import Params

__all__ = ["Estimate", "Estimator", "Params", "State", "initial_orientation"]
