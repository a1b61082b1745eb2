"""Cross-validation by trial or by group: the error of a tuned method on trials its tuning did
not see.

A figure whose parameters were chosen on the same trials it is measured on is in-sample:
it includes what the choice fitted to those trials. Here each trial is scored with the
grid point that is best (lowest mean total RMSE) on the *other* trials, the way a user's
recording is scored with parameters chosen without it:

1. every grid point runs once on every trial (:func:`margtrack.bench.tune.evaluate_grid`,
   distributable with a ``mapper``): the score matrix, points x trials x (total, heading,
   inclination) RMSE in degrees;
2. the trials are split into folds: leave-one-trial-out (each trial its own fold, the
   default), ``K`` folds by trial (trial ``i`` of the folder's order in fold ``i mod K``:
   deterministic, and it spreads BROAD's ordered groups over the folds), or
   leave-one-group-out (``kinds``: every trial of one kind, such as every attached-magnet
   trial, held out together, so the choice has seen no trial of that kind: the figure
   predicts a kind of recording the tuning never met; BROAD's kinds:
   :func:`margtrack.bench.broad.trial_kinds`);
3. for each fold the point with the lowest mean total RMSE on the training trials (all
   trials outside the fold) is chosen; ties go to the first point in grid order; a point
   with a NaN figure on a training trial is never chosen;
4. each held-out trial is scored with its fold's choice; the cross-validated figure is the
   mean over trials of those scores (per group likewise).

Reported next to it: the in-sample best (the point best on all trials, scored on them),
the defaults' in-sample mean, and which point each fold chose (stability). No run is
repeated: the folds only select from the matrix, so cross-validation costs one grid
evaluation.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.bench.runner import KEYS, Scores
from margtrack.bench.tune import GridScores, Mapper, evaluate_grid
from margtrack.estimator import Estimator
from margtrack.recording import Recording

__all__ = [
    "CVResult",
    "Fold",
    "choose_point",
    "cross_validate",
    "cross_validate_grid",
    "fold_of_kinds",
    "fold_of_trials",
    "score_matrix",
]


def fold_of_trials(n_trials: int, folds: int | None = None) -> NDArray[np.int64]:
    """The fold index (n_trials,) of each trial: its own (``folds`` None) or ``i mod folds``.

    Raises ``ValueError`` for fewer than 2 trials, or ``folds`` outside 2..n_trials.
    """
    if n_trials < 2:
        raise ValueError(
            f"cross-validation needs at least 2 trials (each is scored with parameters chosen "
            f"on the others); got {n_trials}: give a folder with more recordings"
        )
    if folds is None:
        return np.arange(n_trials)
    if isinstance(folds, bool) or not isinstance(folds, (int, np.integer)):
        raise ValueError(f"--folds must be a whole number, got {folds!r}")
    if not 2 <= folds <= n_trials:
        raise ValueError(
            f"--folds {folds} is not possible with {n_trials} trials: give 2 to {n_trials} "
            "folds (or leave --folds out for leave-one-trial-out)"
        )
    return np.arange(n_trials) % int(folds)


def fold_of_kinds(kinds: Sequence[str]) -> NDArray[np.int64]:
    """The fold index (n_trials,) of each trial by its kind: kinds numbered as first seen.

    Raises ``ValueError`` when fewer than 2 kinds are given (nothing would be left to
    choose on).
    """
    order = list(dict.fromkeys(kinds))
    if len(order) < 2:
        raise ValueError(
            "cross-validation by group needs trials of at least 2 kinds (each kind is scored "
            f"with parameters chosen on the others); got {len(order)}: {', '.join(order)}"
        )
    return np.array([order.index(k) for k in kinds], dtype=np.int64)


def choose_point(total_deg: NDArray[np.float64], train: NDArray[np.bool_]) -> int:
    """Index of the point (row of ``total_deg``, points x trials) best on the ``train`` trials.

    Best is the lowest mean total RMSE over the training columns; ties go to the lowest
    index (grid order); a point with a NaN on a training trial is never chosen (ValueError
    if every point has one).
    """
    sub = np.asarray(total_deg, dtype=np.float64)[:, np.asarray(train, dtype=bool)]
    if sub.shape[1] == 0:
        raise ValueError("a fold has no training trial")
    means = np.where(np.isnan(sub).any(axis=1), np.inf, sub.mean(axis=1))
    if not np.isfinite(means).any():
        raise ValueError("every grid point failed (NaN error) on a training trial")
    return int(np.argmin(means))  # the first of equal minima


def score_matrix(grid: GridScores) -> NDArray[np.float64]:
    """The figures (points, trials, 3) in degrees, in :data:`KEYS` order, of ``grid``."""
    names = [t.name for t in grid.results[0].trials]
    for r in grid.results:
        if [t.name for t in r.trials] != names:
            raise ValueError(f"grid point {r.params} was not scored on the same trials")
    return np.array([[[getattr(t, k) for k in KEYS] for t in r.trials] for r in grid.results])


@dataclass(frozen=True)
class Fold:
    """One fold: its held-out trials, the point chosen without them and their scores.

    chosen : index of the point in grid order; label : its ``name=value`` label.
    train_total_deg : the chosen point's mean total RMSE on the training trials.
    held_out_total_deg : its mean total RMSE on the held-out trials.
    kind : the held-out trials' kind (leave-one-group-out), else "".
    held_out_figures : the held-out trials' mean (total, heading, inclination), deg.
    """

    held_out: tuple[str, ...]
    chosen: int
    label: str
    train_total_deg: float
    held_out_total_deg: float
    kind: str = ""
    held_out_figures: tuple[float, float, float] = (np.nan, np.nan, np.nan)


@dataclass(frozen=True)
class CVResult:
    """Cross-validated, in-sample best and default figures of one method's grid.

    cross_validated : each trial scored with its fold's choice (``Scores``; its per-trial
    ``params`` are in ``chosen_by_trial``); best_in_sample : the point best on all trials;
    default : the defaults on the same trials (None if not evaluated); folds : one
    :class:`Fold` each; n_folds : their number (the trial count for leave-one-trial-out);
    by_kind : True for leave-one-group-out (each fold one kind of trial, ``Fold.kind``).
    """

    method: str
    grid: GridScores
    folds: tuple[Fold, ...]
    n_folds: int
    leave_one_out: bool
    cross_validated: Scores
    best_in_sample: Scores
    best_index: int
    chosen_by_trial: Mapping[str, str]
    by_kind: bool = False

    @property
    def default(self) -> Scores | None:
        """The defaults' evaluation on the same trials."""
        return self.grid.default

    @property
    def stability(self) -> float:
        """Fraction of folds that chose the in-sample best point."""
        return sum(f.chosen == self.best_index for f in self.folds) / len(self.folds)

    @property
    def n_distinct_choices(self) -> int:
        """How many different points the folds chose."""
        return len({f.chosen for f in self.folds})

    def split_name(self) -> str:
        """``leave-one-trial-out``, ``K folds by trial`` or ``leave-one-group-out (K groups)``."""
        if self.by_kind:
            return f"leave-one-group-out ({self.n_folds} groups)"
        return "leave-one-trial-out" if self.leave_one_out else f"{self.n_folds} folds by trial"

    def to_json(self) -> dict[str, Any]:
        """Figures (deg) and choices as plain JSON types."""

        def figures(s: Scores) -> dict[str, Any]:
            return {"mean": s.mean(), "groups": {g: s.mean(g) for g in s.groups()}}

        default = self.default
        return {
            "method": self.method,
            "split": self.split_name(),
            "n_folds": self.n_folds,
            "n_points": len(self.grid.labels),
            "in_sample_default": (
                None if default is None else {"params": dict(default.params), **figures(default)}
            ),
            "in_sample_best": {
                "label": self.grid.labels[self.best_index],
                "params": dict(self.best_in_sample.params),
                **figures(self.best_in_sample),
            },
            "cross_validated": {
                **figures(self.cross_validated),
                "trials": {
                    t.name: {**t.figures(), "chosen": self.chosen_by_trial[t.name]}
                    for t in self.cross_validated.trials
                },
            },
            "folds": [
                {
                    **({"group": f.kind} if self.by_kind else {}),
                    **(
                        {"held_out_figures": dict(zip(KEYS, f.held_out_figures, strict=True))}
                        if self.by_kind else {}
                    ),
                    "held_out": list(f.held_out),
                    "chosen": f.label,
                    "params": dict(self.grid.results[f.chosen].params),
                    "train_total_rmse_deg": f.train_total_deg,
                    "held_out_total_rmse_deg": f.held_out_total_deg,
                }
                for f in self.folds
            ],
            "stability": self.stability,
        }


def _folds(
    names: Sequence[str], folds: int | None, kinds: Mapping[str, str] | None
) -> NDArray[np.int64]:
    """The fold of each trial named in ``names``: by ``kinds`` when given, else by trial."""
    if kinds is None:
        return fold_of_trials(len(names), folds)
    if folds is not None:
        raise ValueError("--folds splits by trial; leave it out with --cv group")
    missing = [n for n in names if n not in kinds]
    if missing:
        raise ValueError(f"no kind (group) for trial(s) {', '.join(missing)}")
    return fold_of_kinds([kinds[n] for n in names])


def cross_validate_grid(
    grid: GridScores, folds: int | None = None, kinds: Mapping[str, str] | None = None
) -> CVResult:
    """Cross-validate an evaluated grid: a choice per fold, each trial scored with it.

    ``folds`` None is leave-one-trial-out; an int K splits the trials (in their order) into
    K folds, trial i in fold i mod K. ``kinds`` (trial name -> kind) holds out each kind in
    turn instead (leave-one-group-out; not with ``folds``). See the module docstring.
    """
    if not grid.results:
        raise ValueError("the grid has no evaluated point")
    figures = score_matrix(grid)
    trials = grid.results[0].trials
    fold = _folds([t.name for t in trials], folds, kinds)
    n_folds = int(fold.max()) + 1
    total = figures[:, :, 0]
    picked = np.empty(len(trials), dtype=np.int64)
    out = []
    for k in range(n_folds):
        test = fold == k
        c = choose_point(total, ~test)
        picked[test] = c
        out.append(
            Fold(
                tuple(t.name for t, held in zip(trials, test, strict=True) if held),
                c,
                grid.labels[c],
                float(total[c, ~test].mean()),
                float(total[c, test].mean()),
                "" if kinds is None else kinds[trials[int(np.argmax(test))].name],
                tuple(float(x) for x in figures[c, test].mean(axis=0)),  # type: ignore[arg-type]
            )
        )
    rows = tuple(grid.results[int(picked[j])].trials[j] for j in range(len(trials)))
    cv = Scores(
        f"{grid.method} (cross-validated)",
        {},
        rows,
        grid.results[0].group_order,
    )
    best = choose_point(total, np.ones(len(trials), dtype=bool))
    return CVResult(
        grid.method,
        grid,
        tuple(out),
        n_folds,
        folds is None,
        cv,
        grid.results[best],
        best,
        {t.name: grid.labels[int(picked[j])] for j, t in enumerate(trials)},
        kinds is not None,
    )


def cross_validate(
    method: str | type[Estimator],
    grid: Mapping[str, Sequence[Any]],
    recordings: Sequence[tuple[Recording, tuple[str, ...]]],
    *,
    folds: int | None = None,
    kinds: Mapping[str, str] | None = None,
    fixed: Mapping[str, Any] | None = None,
    group_order: Sequence[str] = (),
    progress: Callable[[str], None] | None = None,
    mapper: Mapper | None = None,
) -> CVResult:
    """Evaluate ``grid`` (and the defaults) on every recording once, then cross-validate.

    The folds are checked before anything runs. ``folds`` and ``kinds`` as in
    :func:`cross_validate_grid`; ``fixed``, ``group_order``, ``progress`` and ``mapper`` as
    in :func:`margtrack.bench.tune.tune`. The same grid by another split costs no run:
    ``cross_validate_grid(result.grid, ...)``.
    """
    _folds([r.name for r, _ in recordings], folds, kinds)  # bad split: fail first
    scored = evaluate_grid(
        method, grid, recordings, fixed=fixed, group_order=group_order, progress=progress,
        mapper=mapper, with_default=True,
    )
    return cross_validate_grid(scored, folds, kinds)
