"""The estimator contract every method builds on.

- :mod:`~margtrack.estimator.params`: parameters declared once (unit, bounds, default, help);
- :mod:`~margtrack.estimator.flags`: the health-flag schema, the same for every method;
- :mod:`~margtrack.estimator.screening`: the input policy run before every kernel;
- :mod:`~margtrack.estimator.units`: unit checks on every path;
- :mod:`~margtrack.estimator.contract`: :class:`Estimator`, :class:`State`, :class:`Estimate`.
"""

from margtrack.estimator.contract import Estimate, Estimator, State, initial_orientation
from margtrack.estimator.flags import Flag
from margtrack.estimator.params import Params, ParamSpec, param, specs

__all__ = [
    "Estimate",
    "Estimator",
    "Flag",
    "ParamSpec",
    "Params",
    "State",
    "initial_orientation",
    "param",
    "specs",
]
