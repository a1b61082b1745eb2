"""Run an estimator over recordings with ground truth (BROAD or any file) and tabulate errors.

One parameter set for every trial; a fresh state per trial (:mod:`margtrack.bench.runner`),
initialised from the trial's own first accelerometer/magnetometer sample (never from the
truth). Errors are the RMSE over each trial's ``movement`` samples (all samples if it has
no mask), then the mean over trials, per group and overall, in degrees.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from margtrack.accuracy import ErrorSummary
from margtrack.bench.runner import KEYS, Scores, evaluate, evaluate_all
from margtrack.estimator import Estimator
from margtrack.recording import Recording

__all__ = [
    "evaluate_folder",
    "evaluate_recording",
    "evaluate_recordings",
    "format_table",
    "group_order",
    "trial_kind",
    "trial_kinds",
]

#: the trials.json categories that name a trial's kind: its disturbance if it has one,
#: else its speed and motion (``slow_rotation``); breaks do not make another kind
KIND_CATEGORIES = (("disturbance",), ("speed", "motion"))


def evaluate_recording(estimator: Estimator, recording: Recording) -> tuple[ErrorSummary, float]:
    """Run ``estimator`` (fresh state) on ``recording`` and score it against its truth.

    Returns the error summary over the movement mask and the run time in s
    (:func:`margtrack.bench.runner.evaluate`).
    """
    trial = evaluate(estimator, recording)
    return trial.errors, trial.seconds


def evaluate_recordings(
    make_estimator: Callable[[], Estimator],
    recordings: Iterable[tuple[Recording, tuple[str, ...]]],
    *,
    method: str,
    params: Mapping[str, Any],
    group_order: Sequence[str] = (),
    progress: Callable[[str], None] | None = None,
) -> Scores:
    """Evaluate one method over (recording, groups) pairs; ``progress`` is told each trial name.

    The estimator is made once and reset before each trial
    (:func:`margtrack.bench.runner.evaluate_all`).
    """
    return evaluate_all(
        make_estimator(), recordings, label=method, params=params, group_order=group_order,
        progress=progress,
    )


def evaluate_folder(
    folder: str | Path,
    make_estimator: Callable[[], Estimator],
    *,
    method: str,
    params: Mapping[str, Any],
    show_progress: bool = True,
) -> Scores:
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


def trial_kind(groups: Sequence[str], categories: Mapping[str, str]) -> str:
    """The kind of a trial in ``groups``, from the ``categories`` (group -> category) of
    trials.json: its disturbance group(s) (``attached_magnet``), else its speed and motion
    (``slow_rotation``), else its groups below the top level joined with ``+``, else
    ``ungrouped``. Cross-validation by group holds out one kind at a time.
    """
    for cats in KIND_CATEGORIES:
        parts = [g for c in cats for g in groups if categories.get(g) == c]
        if parts:
            return "_".join(parts)
    rest = [g for g in groups if g != "all_trials"]
    return "+".join(rest) if rest else "ungrouped"


def trial_kinds(folder: str | Path) -> dict[str, str]:
    """Trial name -> kind (:func:`trial_kind`) for every trial of the folder's trials.json.

    Raises ``ValueError`` for a folder without trials.json (no groups to hold out).
    """
    index = Path(folder) / "trials.json"
    if not index.is_file():
        raise ValueError(
            f"cross-validation by group needs the trials' groups: {folder} has no trials.json "
            "(use --cv trial, or a BROAD folder)"
        )
    data = json.loads(index.read_text())
    categories = {g["name"]: g.get("category", "") for g in data.get("groups", [])}
    return {
        name: trial_kind(trial.get("groups", ()), categories)
        for name, trial in data.get("trials", {}).items()
    }


def format_table(result: Scores, *, per_group: bool = True) -> Any:
    """A rich Table: one row per trial, then per-group and overall means (degrees)."""
    from rich.table import Table

    table = Table(title=f"{result.method}: RMSE over movement samples (deg)")
    table.add_column("trial / group")
    for label in ("total", "heading", "inclination"):
        table.add_column(label, justify="right")
    for t in result.trials:
        table.add_row(t.name, *(f"{getattr(t, k):.2f}" for k in KEYS))
    if per_group and len(result.trials) > 1:
        table.add_section()
        for g in result.groups():
            if g == "all_trials":
                continue
            n = sum(g in t.groups for t in result.trials)
            m = result.mean(g)
            table.add_row(f"[italic]{g}[/] ({n})", *(f"{m[k]:.2f}" for k in KEYS))
    table.add_section()
    m = result.mean()
    table.add_row(f"[bold]mean ({len(result.trials)})[/]", *(f"[bold]{m[k]:.2f}[/]" for k in KEYS))
    return table
