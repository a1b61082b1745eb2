"""Grid search for one parameter set per method that minimises the mean total RMSE over trials.

The honest figure for a filter on BROAD is one parameter set for every trial; this finds
it. Recordings are read once and kept in memory; each grid point runs the method on every
trial with a fresh estimator.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from margtrack.bench.broad import EvaluationResult, evaluate_recordings
from margtrack.estimators.base import Estimator
from margtrack.methods import get, parse_params
from margtrack.recording import Recording

__all__ = ["TuneResult", "parse_grid", "tune"]


@dataclass(frozen=True)
class TuneResult:
    """Every grid point's evaluation, best first by mean total RMSE."""

    method: str
    results: tuple[EvaluationResult, ...]

    @property
    def best(self) -> EvaluationResult:
        """The evaluation with the lowest mean total RMSE."""
        return self.results[0]


def parse_grid(items: Sequence[str]) -> dict[str, list[str]]:
    """``["gain=0.1,0.2", "mag_weight=1"]`` to ``{"gain": ["0.1", "0.2"], ...}``."""
    grid: dict[str, list[str]] = {}
    for item in items:
        name, sep, values = item.partition("=")
        if not sep or not values.strip():
            raise ValueError(f"a grid is given as name=v1,v2,..., got {item!r}")
        grid[name.strip().replace("-", "_")] = [v.strip() for v in values.split(",")]
    return grid


def tune(
    method: str | type[Estimator],
    grid: Mapping[str, Sequence[Any]],
    recordings: Sequence[tuple[Recording, tuple[str, ...]]],
    *,
    fixed: Mapping[str, Any] | None = None,
    group_order: Sequence[str] = (),
    progress: Callable[[str], None] | None = None,
) -> TuneResult:
    """Evaluate every combination of ``grid`` (plus ``fixed``) on ``recordings``; best first.

    ``method`` is a registered name or an :class:`Estimator` subclass.

    ``grid`` maps parameter names to candidate values (strings are coerced like CLI
    parameters); ``progress`` is told each combination before it runs.
    """
    cls = get(method) if isinstance(method, str) else method
    if not grid:
        raise ValueError("the grid is empty: give at least one name=v1,v2,... ")
    names = list(grid)
    results = []
    for values in itertools.product(*(grid[n] for n in names)):
        point = {**(fixed or {}), **dict(zip(names, values, strict=True))}
        params = parse_params(cls.params_type, point)
        if progress is not None:
            progress(", ".join(f"{k}={v}" for k, v in zip(names, values, strict=True)))
        results.append(
            evaluate_recordings(
                lambda params=params: cls(params),
                recordings,
                method=cls.name,
                params=params.as_dict(),
                group_order=group_order,
            )
        )
    results.sort(key=lambda r: r.mean()["total_rmse_deg"])
    return TuneResult(cls.name, tuple(results))
