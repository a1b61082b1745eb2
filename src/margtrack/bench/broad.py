"""Run an estimator over recordings with ground truth (BROAD or any file) and tabulate errors.

One parameter set for every trial; a fresh estimator per trial, initialised from the
trial's own first accelerometer/magnetometer sample (never from the truth). Errors are the
RMSE over each trial's ``movement`` samples (all samples if it has no mask), then the
mean over trials, per group and overall, in degrees.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from margtrack.bench.metrics import ErrorSummary, error_series, summarize
from margtrack.estimators.base import Estimator
from margtrack.recording import Recording

__all__ = [
    "EvaluationResult",
    "TrialResult",
    "evaluate_folder",
    "evaluate_recording",
    "evaluate_recordings",
    "format_table",
    "group_order",
]

_KEYS = ("total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg")


@dataclass(frozen=True)
class TrialResult:
    """Errors of one trial, its groups, and how long the estimator took."""

    name: str
    errors: ErrorSummary
    groups: tuple[str, ...] = ()
    n_samples: int = 0
    seconds: float = 0.0


@dataclass(frozen=True)
class EvaluationResult:
    """Per-trial errors of one method with one parameter set, and their means."""

    method: str
    params: Mapping[str, Any]
    trials: tuple[TrialResult, ...]
    group_order: tuple[str, ...] = field(default=())

    def mean(self, group: str | None = None) -> dict[str, float]:
        """Mean over trials (of ``group`` if given) of each RMSE figure, degrees."""
        rows = [t for t in self.trials if group is None or group in t.groups]
        if not rows:
            raise ValueError(f"no trial in group {group!r}")
        return {k: float(np.mean([getattr(t.errors, k) for t in rows])) for k in _KEYS}

    def groups(self) -> list[str]:
        """Groups that hold at least one trial, in the dataset's order."""
        present = {g for t in self.trials for g in t.groups}
        ordered = [g for g in self.group_order if g in present]
        return ordered + sorted(present - set(ordered))

    def samples_per_s(self) -> float:
        """Total samples processed per second of estimator time."""
        seconds = sum(t.seconds for t in self.trials)
        return sum(t.n_samples for t in self.trials) / seconds if seconds > 0 else float("nan")

    def to_json(self) -> dict[str, Any]:
        """The documented JSON layout: method, params, trials{name: figures}, mean, groups."""
        return {
            "method": self.method,
            "params": dict(self.params),
            "trials": {t.name: {k: getattr(t.errors, k) for k in _KEYS} for t in self.trials},
            "mean": self.mean(),
            "groups": {g: self.mean(g) for g in self.groups()},
        }

    def write_json(self, path: str | Path) -> None:
        """Write :meth:`to_json` to ``path``."""
        Path(path).write_text(json.dumps(self.to_json(), indent=2) + "\n")


def evaluate_recording(estimator: Estimator, recording: Recording) -> tuple[ErrorSummary, float]:
    """Run ``estimator`` (fresh state) on ``recording`` and score it against its truth.

    Returns the error summary over the movement mask and the run time in s.
    """
    if recording.quat_true is None:
        raise ValueError(f"recording {recording.name!r} has no ground truth (quat_true)")
    estimator.reset()
    start = time.perf_counter()
    estimate = estimator.run(recording)
    seconds = time.perf_counter() - start
    series = error_series(estimate.quat, recording.quat_true, estimate.frame, recording.frame)
    return summarize(series, recording.movement), seconds


def evaluate_recordings(
    make_estimator: Callable[[], Estimator],
    recordings: Iterable[tuple[Recording, tuple[str, ...]]],
    *,
    method: str,
    params: Mapping[str, Any],
    group_order: Sequence[str] = (),
    progress: Callable[[str], None] | None = None,
) -> EvaluationResult:
    """Evaluate one method over (recording, groups) pairs; ``progress`` is told each trial name."""
    rows = []
    for recording, groups in recordings:
        if progress is not None:
            progress(recording.name)
        errors, seconds = evaluate_recording(make_estimator(), recording)
        rows.append(TrialResult(recording.name, errors, groups, recording.n_samples, seconds))
    if not rows:
        raise ValueError("no recording to evaluate")
    return EvaluationResult(method, dict(params), tuple(rows), tuple(group_order))


def evaluate_folder(
    folder: str | Path,
    make_estimator: Callable[[], Estimator],
    *,
    method: str,
    params: Mapping[str, Any],
    show_progress: bool = True,
) -> EvaluationResult:
    """Evaluate one method on every BROAD trial in ``folder`` with a progress bar."""
    from rich.progress import Progress

    from margtrack.io.broad import broad_trials, read_broad

    trials = broad_trials(folder)
    order = group_order(Path(folder))

    def recordings(update: Callable[[], None]):
        for trial in trials:
            yield read_broad(trial.path), tuple(trial.groups)
            update()

    if not show_progress:
        return evaluate_recordings(
            make_estimator,
            recordings(lambda: None),
            method=method,
            params=params,
            group_order=order,
        )
    with Progress(transient=True) as bar:
        task = bar.add_task(f"{method} on {len(trials)} trials", total=len(trials))
        return evaluate_recordings(
            make_estimator,
            recordings(lambda: bar.advance(task)),
            method=method,
            params=params,
            group_order=order,
            progress=lambda name: bar.update(task, description=f"{method}: {name}"),
        )


def group_order(folder: Path) -> tuple[str, ...]:
    """The group names of a BROAD folder's trials.json in its order (empty without one)."""
    index = folder / "trials.json"
    if not index.is_file():
        return ()
    return tuple(g["name"] for g in json.loads(index.read_text()).get("groups", []))


def format_table(result: EvaluationResult, *, per_group: bool = True) -> Any:
    """A rich Table: one row per trial, then per-group and overall means (degrees)."""
    from rich.table import Table

    table = Table(title=f"{result.method}: RMSE over movement samples (deg)")
    table.add_column("trial / group")
    for label in ("total", "heading", "inclination"):
        table.add_column(label, justify="right")
    for t in result.trials:
        table.add_row(t.name, *(f"{getattr(t.errors, k):.2f}" for k in _KEYS))
    if per_group and len(result.trials) > 1:
        table.add_section()
        for g in result.groups():
            if g == "all_trials":
                continue
            n = sum(g in t.groups for t in result.trials)
            m = result.mean(g)
            table.add_row(f"[italic]{g}[/] ({n})", *(f"{m[k]:.2f}" for k in _KEYS))
    table.add_section()
    m = result.mean()
    table.add_row(f"[bold]mean ({len(result.trials)})[/]", *(f"[bold]{m[k]:.2f}[/]" for k in _KEYS))
    return table
