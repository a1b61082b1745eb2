"""The estimator contract every method builds on.

- :mod:`~margtrack.estimator.params`: parameters declared once (unit, bounds, default, help);
- :mod:`~margtrack.estimator.flags`: the health-flag schema, the same for every method;
- :mod:`~margtrack.estimator.screening`: the input policy run before every kernel;
- :mod:`~margtrack.estimator.units`: unit checks on every path;
- :mod:`~margtrack.estimator.estimate`: :class:`State` and :class:`Estimate`;
- :mod:`~margtrack.estimator.initial`: the orientation a sensor starts from;
- :mod:`~margtrack.estimator.inputs`: a run's recordings or arrays, checked and shaped;
- :mod:`~margtrack.estimator.contract`: :class:`Estimator`, ``update``/``run`` and restarts.
"""

from margtrack.estimator.contract import Estimator
from margtrack.estimator.estimate import Estimate, State
from margtrack.estimator.flags import Flag
from margtrack.estimator.initial import initial_orientation
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
