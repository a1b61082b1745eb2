"""Reproductions of the source papers' experiments, run by ``margtrack experiment NAME``.

Each experiment is a function ``(out_dir: Path, quick: bool) -> ExperimentResult`` that
simulates what the paper did, writes a PNG plot into ``out_dir`` and returns the printed
figures. Modules listed in ``_MODULES`` expose ``EXPERIMENTS: dict[str, Experiment]``.
``quick`` shortens the run for tests (same code path, fewer samples or cases).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["ExperimentResult", "available", "run"]


@dataclass(frozen=True)
class ExperimentResult:
    """What an experiment measured: named figures (units in the names), notes, plot paths."""

    name: str
    figures: Mapping[str, Any]
    plots: tuple[Path, ...] = ()
    notes: tuple[str, ...] = field(default=())


Experiment = Callable[[Path, bool], ExperimentResult]

# experiment modules, one per issue/paper; each defines EXPERIMENTS
_MODULES: tuple[str, ...] = (
    "complementary",
    "gradient",
    "kalman_ang",
    "kalman_marins",
    "single_frame",
    "tilt_table",
)


def _registry() -> dict[str, Experiment]:
    found: dict[str, Experiment] = {}
    for module in _MODULES:
        found.update(importlib.import_module(f"margtrack.bench.experiments.{module}").EXPERIMENTS)
    return found


def available() -> list[str]:
    """Names of the experiments that can be run."""
    return sorted(_registry())


def run(name: str, out_dir: str | Path, *, quick: bool = False) -> ExperimentResult:
    """Run experiment ``name``, writing its plot(s) into ``out_dir`` (created if missing)."""
    experiments = _registry()
    if name not in experiments:
        names = ", ".join(sorted(experiments)) or "none yet"
        raise ValueError(f"unknown experiment {name!r}; available: {names}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return experiments[name](out, quick)
