"""Grid search for one parameter set per method that minimises the mean total RMSE over trials.

The honest figure for a filter on BROAD is one parameter set for every trial; this finds
it. Recordings are read once and kept in memory; each grid point runs the method on every
trial from a fresh state through the one runner (:mod:`margtrack.bench.runner`).

The grid points are independent jobs: ``mapper`` spreads them over processes or machines
(``margtrack tune --workers N`` / ``--scheduler ADDRESS`` pass a Dask-backed one from
:mod:`margtrack.batch.cluster`); without one they run here, one after the other.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from margtrack.bench.runner import Scores, evaluate_all
from margtrack.estimator import Estimator, Params
from margtrack.methods import get, parse_params
from margtrack.recording import Recording

__all__ = [
    "GridScores",
    "Mapper",
    "TuneResult",
    "evaluate_grid",
    "evaluate_point",
    "grid_points",
    "parse_grid",
    "tune",
]

#: ``mapper(job, items, shared)`` runs ``job(shared, item)`` for every item, anywhere, and
#: yields ``(index of the item, result)`` as each finishes; an error in a job is raised.
Mapper = Callable[[Callable[[Any, Any], Any], Sequence[Any], Any], Iterable[tuple[int, Any]]]


@dataclass(frozen=True)
class TuneResult:
    """Every grid point's evaluation, best first by mean total RMSE."""

    method: str
    results: tuple[Scores, ...]

    @property
    def best(self) -> Scores:
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


def evaluate_point(
    cls: type[Estimator],
    group_order: tuple[str, ...],
    recordings: Sequence[tuple[Recording, tuple[str, ...]]],
    params: Params,
) -> Scores:
    """One grid point: method ``cls`` with ``params`` on every recording (a picklable job)."""
    return evaluate_all(
        cls(params), recordings, label=cls.name, params=params.as_dict(), group_order=group_order
    )


def _here(
    job: Callable[[Any, Any], Any], items: Sequence[Any], shared: Any
) -> Iterator[tuple[int, Any]]:
    """The mapper without workers: every job in this process, in order."""
    for i, item in enumerate(items):
        yield i, job(shared, item)


@dataclass(frozen=True)
class GridScores:
    """Every grid point's evaluation on every trial, in the grid's order (the score matrix).

    labels : one ``name=value, ...`` label per point; results : its :class:`Scores`.
    default : the method's defaults (plus ``fixed``) on the same trials, when asked for;
    default_index : its index in ``results`` when the defaults are a grid point, else None.
    """

    method: str
    labels: tuple[str, ...]
    results: tuple[Scores, ...]
    default: Scores | None = None
    default_index: int | None = None


def grid_points(
    cls: type[Estimator], grid: Mapping[str, Sequence[Any]], fixed: Mapping[str, Any] | None = None
) -> tuple[list[str], list[Params]]:
    """Labels and validated parameter sets of every combination of ``grid`` (plus ``fixed``).

    Raises ``ValueError`` for an empty grid, a parameter with no candidates, an unknown
    parameter or a bad value (naming it), before anything runs.
    """
    if not grid:
        raise ValueError("the grid is empty: give at least one name=v1,v2,... ")
    for name, values in grid.items():
        if len(values) == 0:
            raise ValueError(f"grid parameter {name!r} has no candidate values")
    names = list(grid)
    labels, points = [], []
    for values in itertools.product(*(grid[n] for n in names)):
        point = {**(fixed or {}), **dict(zip(names, values, strict=True))}
        points.append(parse_params(cls.params_type, point))
        labels.append(", ".join(f"{k}={v}" for k, v in zip(names, values, strict=True)))
    return labels, points


def evaluate_grid(
    method: str | type[Estimator],
    grid: Mapping[str, Sequence[Any]],
    recordings: Sequence[tuple[Recording, tuple[str, ...]]],
    *,
    fixed: Mapping[str, Any] | None = None,
    group_order: Sequence[str] = (),
    progress: Callable[[str], None] | None = None,
    mapper: Mapper | None = None,
    with_default: bool = False,
) -> GridScores:
    """Evaluate every combination of ``grid`` (plus ``fixed``) on every recording, in grid order.

    ``with_default`` also evaluates the defaults (plus ``fixed``), as one more job of the
    same run when they are not a grid point. ``progress`` and ``mapper`` as in :func:`tune`.
    """
    cls = get(method) if isinstance(method, str) else method
    labels, points = grid_points(cls, grid, fixed)
    default_index = None
    if with_default:
        default_params = parse_params(cls.params_type, dict(fixed or {}))
        default_index = next((i for i, p in enumerate(points) if p == default_params), None)
        if default_index is None:
            points.append(default_params)
            labels.append("defaults")
    job = functools.partial(evaluate_point, cls, tuple(group_order))
    results: list[Scores | None] = [None] * len(points)
    for i, scores in (mapper or _here)(job, points, list(recordings)):
        results[i] = scores
        if progress is not None:
            progress(labels[i])
    done = [r for r in results if r is not None]
    if len(done) != len(points):
        raise RuntimeError(f"the mapper returned {len(done)} of {len(points)} grid points")
    default = None
    if with_default:
        default = done[default_index] if default_index is not None else done.pop()
        if default_index is None:
            labels.pop()
    return GridScores(cls.name, tuple(labels), tuple(done), default, default_index)


def tune(
    method: str | type[Estimator],
    grid: Mapping[str, Sequence[Any]],
    recordings: Sequence[tuple[Recording, tuple[str, ...]]],
    *,
    fixed: Mapping[str, Any] | None = None,
    group_order: Sequence[str] = (),
    progress: Callable[[str], None] | None = None,
    mapper: Mapper | None = None,
) -> TuneResult:
    """Evaluate every combination of ``grid`` (plus ``fixed``) on ``recordings``; best first.

    ``method`` is a registered name or an :class:`Estimator` subclass.

    ``grid`` maps parameter names to candidate values (strings are coerced like CLI
    parameters); every point is validated before any runs. ``progress`` is told each
    combination as it finishes; ``mapper`` (:data:`Mapper`) runs the points elsewhere,
    with ``recordings`` shipped once as the shared argument. The result does not depend
    on where the points ran: ties keep the grid's order. Cross-validation of the same
    grid: :func:`margtrack.bench.cv.cross_validate`.
    """
    scored = evaluate_grid(
        method, grid, recordings, fixed=fixed, group_order=group_order, progress=progress,
        mapper=mapper,
    )
    done = sorted(scored.results, key=lambda r: r.mean()["total_rmse_deg"])
    return TuneResult(scored.method, tuple(done))
