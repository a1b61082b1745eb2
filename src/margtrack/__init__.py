"""margtrack: orientation tracking with MARG sensors.

The public API, re-exported here:

- :mod:`margtrack.quaternion`, :mod:`margtrack.frames`: the conventions as functions;
- :class:`Recording` and :mod:`margtrack.io`: data in and out (any CSV through a column map,
  phone loggers, a pandas DataFrame: ``io.read``, ``io.from_dataframe``); :func:`resample`
  puts a slower sensor's samples on the gyroscope's timestamps (004's interpolation);
- :mod:`margtrack.sim`: simulated recordings with truth;
- :func:`create` / :func:`available_methods` (:mod:`margtrack.methods`, one folder per
  method; :mod:`margtrack.single_frame`): estimators by name, all following one contract
  (:class:`Estimator`, :class:`Estimate`);
- :func:`score` (:func:`margtrack.bench.runner.score_estimate`): an estimate's error
  against its recording's truth as ``margtrack evaluate`` reports it (RMSE in degrees over
  the movement samples); :func:`error_series`, :func:`summarize`
  (:mod:`margtrack.accuracy`): the errors per sample and their RMSE over any mask.

Submodules that pull in numba or h5py load on first use, so ``import margtrack`` is quick.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from margtrack import frames, quaternion
from margtrack.recording import Recording, resample

if TYPE_CHECKING:  # pragma: no cover
    from margtrack import bench, body, calibration, io, live, methods, sim, single_frame
    from margtrack.accuracy import error_series, summarize
    from margtrack.bench.runner import score_estimate as score
    from margtrack.estimator import Estimate, Estimator
    from margtrack.methods import available as available_methods
    from margtrack.methods import create

__version__ = "0.1.0"

_LAZY_MODULES = {
    "bench",
    "body",
    "calibration",
    "io",
    "live",
    "methods",
    "sim",
    "single_frame",
}
_LAZY_NAMES = {
    "Estimate": ("margtrack.estimator", "Estimate"),
    "Estimator": ("margtrack.estimator", "Estimator"),
    "available_methods": ("margtrack.methods", "available"),
    "create": ("margtrack.methods", "create"),
    "error_series": ("margtrack.accuracy", "error_series"),
    "score": ("margtrack.bench.runner", "score_estimate"),
    "summarize": ("margtrack.accuracy", "summarize"),
}

__all__ = [
    "Estimate",
    "Estimator",
    "Recording",
    "available_methods",
    "bench",
    "body",
    "calibration",
    "create",
    "error_series",
    "frames",
    "io",
    "live",
    "methods",
    "quaternion",
    "resample",
    "score",
    "sim",
    "single_frame",
    "summarize",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY_MODULES:
        return importlib.import_module(f"margtrack.{name}")
    if name in _LAZY_NAMES:
        module, attr = _LAZY_NAMES[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'margtrack' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The public API and the lazy submodules, so ``mt.<TAB>`` in a REPL lists them."""
    return sorted(set(__all__) | _LAZY_MODULES | set(_LAZY_NAMES) | {"__version__"})
