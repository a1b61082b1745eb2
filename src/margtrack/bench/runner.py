"""The one runner: a recording to an estimate to its error figures, for every command.

``evaluate``, ``tune``, ``bench broad``, ``demo`` and ``batch`` all go through here:

- a *method* is anything with ``name``, ``params``, ``reset()`` and ``run(recording) ->
  Estimate``: every margtrack :class:`~margtrack.estimator.Estimator`, and
  :class:`Adapter`, which wraps another library's function (recording -> (N, 4) quats in
  ENU) so it returns the same :class:`~margtrack.estimator.Estimate` type;
- :func:`run_method` runs one method on one recording from a fresh state and times it;
- :class:`ErrorAccumulator` sums the squared errors of an orientation series against the
  truth, a whole recording at once or chunk after chunk (``margtrack run`` and ``batch``
  through :func:`margtrack.run.chunked.run_file`), with the same figures either way;
- :func:`score` turns an orientation series into a :class:`TrialScore` against the truth
  (one :class:`ErrorAccumulator` over the whole recording); :func:`score_estimate` is the
  same for an :class:`~margtrack.estimator.Estimate` (``margtrack.score``, the API's way
  to the figures ``margtrack evaluate`` prints);
- :func:`evaluate` is both, and :func:`evaluate_all` a set of trials into :class:`Scores`,
  the one result model (per-trial figures, group means, speed, JSON).

Errors are the RMSE over the trial's ``movement`` samples (all samples without a mask) in
degrees, then the mean over trials (DESIGN.md, "Real data"); samples whose truth is a hole
(NaN rows of ``quat_true``) are skipped. The keys are :data:`KEYS`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.accuracy import ErrorAccumulator, ErrorSummary
from margtrack.estimator.estimate import Estimate
from margtrack.recording import Recording

__all__ = [
    "KEYS",
    "Adapter",
    "ErrorAccumulator",
    "Method",
    "Scores",
    "TrialScore",
    "evaluate",
    "evaluate_all",
    "run_method",
    "score",
    "score_estimate",
]

#: the error figures of every result, in degrees
KEYS = ("total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg")


@runtime_checkable
class Method(Protocol):
    """What the runner runs: a margtrack Estimator or an :class:`Adapter`."""

    name: str

    def reset(self) -> None:
        """Forget the state: the next run starts afresh."""

    def run(self, recording: Recording) -> Estimate:
        """The orientation series of ``recording``."""


class Adapter:
    """Another library's filter as a method: ``run(recording)`` gives an :class:`Estimate`.

    fn : ``fn(recording) -> (N, 4)`` quaternions ``[w, x, y, z]`` of the body in ``frame``.
    name : the label it is reported under.
    params : the parameters it runs with (reported, not interpreted).
    frame : earth frame of ``fn``'s output ("ENU" for every adapter in
        :mod:`margtrack.bench.external`).
    Calling the adapter like ``fn`` gives the bare quaternions.
    """

    def __init__(
        self,
        fn: Callable[[Recording], ArrayLike],
        name: str,
        params: Mapping[str, Any] | None = None,
        frame: str = "ENU",
    ) -> None:
        self.fn = fn
        self.name = name
        self.params = dict(params or {})
        self.frame = frame

    def reset(self) -> None:
        """Nothing to forget: every call of ``fn`` starts afresh."""

    def run(self, recording: Recording) -> Estimate:
        """``fn(recording)`` as an Estimate (quat (N, 4), the recording's ``t``, ``frame``)."""
        q = np.asarray(self.fn(recording), dtype=np.float64)
        if q.shape != (recording.n_samples, 4):
            raise ValueError(
                f"{self.name} returned an array of shape {q.shape} for {recording.name!r}; "
                f"expected ({recording.n_samples}, 4) quaternions [w, x, y, z]"
            )
        return Estimate(q, recording.t, self.frame, self.name, dict(self.params))  # type: ignore[arg-type]

    def __call__(self, recording: Recording) -> NDArray[np.float64]:
        return np.asarray(self.fn(recording), dtype=np.float64)


@dataclass(frozen=True)
class TrialScore:
    """One trial's RMSE figures (deg, over its movement samples), groups and run time.

    n_scored : how many samples the figures are over (the movement mask's count).
    n_samples : how many samples the method processed; seconds : its run time, s.
    """

    name: str
    total_rmse_deg: float
    heading_rmse_deg: float
    inclination_rmse_deg: float
    n_scored: int
    groups: tuple[str, ...] = ()
    n_samples: int = 0
    seconds: float = 0.0

    @property
    def errors(self) -> ErrorSummary:
        """The figures as :class:`~margtrack.accuracy.ErrorSummary`."""
        return ErrorSummary(
            self.total_rmse_deg, self.heading_rmse_deg, self.inclination_rmse_deg, self.n_scored
        )

    def figures(self) -> dict[str, float]:
        """The :data:`KEYS` figures as a dict."""
        return {k: getattr(self, k) for k in KEYS}


@dataclass(frozen=True)
class Scores:
    """One method (one parameter set) on a set of trials: figures, means and speed.

    method : the name (or label) it is reported under; params : its parameters.
    trials : one :class:`TrialScore` per trial, in run order.
    group_order : the dataset's order of groups (BROAD's trials.json), for tables.
    """

    method: str
    params: Mapping[str, Any]
    trials: tuple[TrialScore, ...]
    group_order: tuple[str, ...] = field(default=())

    def trial(self, name: str) -> TrialScore:
        """The score of the trial called ``name``."""
        for t in self.trials:
            if t.name == name:
                return t
        raise KeyError(f"no trial {name!r}; have {', '.join(t.name for t in self.trials)}")

    def mean(self, group: str | None = None) -> dict[str, float]:
        """Mean over trials (of ``group`` if given) of each RMSE figure, degrees."""
        rows = [t for t in self.trials if group is None or group in t.groups]
        if not rows:
            raise ValueError(f"no trial in group {group!r}")
        return {k: float(np.mean([getattr(t, k) for t in rows])) for k in KEYS}

    def groups(self) -> list[str]:
        """Groups that hold at least one trial, in the dataset's order."""
        present = {g for t in self.trials for g in t.groups}
        ordered = [g for g in self.group_order if g in present]
        return ordered + sorted(present - set(ordered))

    @property
    def n_samples(self) -> int:
        """Samples processed over all trials."""
        return sum(t.n_samples for t in self.trials)

    @property
    def seconds(self) -> float:
        """Run time over all trials, s (estimation only: no reading, no scoring)."""
        return sum(t.seconds for t in self.trials)

    @property
    def samples_per_s(self) -> float:
        """Samples processed per second of estimation time (nan if none was measured)."""
        return self.n_samples / self.seconds if self.seconds > 0 else float("nan")

    def to_json(self) -> dict[str, Any]:
        """The documented JSON layout: method, params, trials{name: figures}, mean, groups."""
        return {
            "method": self.method,
            "params": dict(self.params),
            "trials": {t.name: t.figures() for t in self.trials},
            "mean": self.mean(),
            "groups": {g: self.mean(g) for g in self.groups()},
        }

    def write_json(self, path: str | Path) -> None:
        """Write :meth:`to_json` to ``path``."""
        Path(path).write_text(json.dumps(self.to_json(), indent=2) + "\n")


def run_method(method: Method, recording: Recording) -> tuple[Estimate, float]:
    """Run ``method`` from a fresh state on ``recording``; the Estimate and its run time, s."""
    method.reset()
    start = time.perf_counter()
    estimate = method.run(recording)
    return estimate, time.perf_counter() - start




def score(
    recording: Recording,
    quat: ArrayLike,
    frame: str = "ENU",
    *,
    groups: Sequence[str] = (),
    seconds: float = 0.0,
) -> TrialScore:
    """The error of ``quat`` (N, 4), body to ``frame``, against ``recording``'s truth.

    RMSE (deg) of total, heading and inclination error over the movement mask (all
    samples without one), truth holes skipped (:class:`ErrorAccumulator`); ``seconds`` is
    the run time to report with it.
    """
    if recording.quat_true is None:
        raise ValueError(
            f"recording {recording.name!r} has no ground truth (quat_true); "
            "error figures need a recording with truth"
        )
    errors = ErrorAccumulator()
    errors.add(recording, quat, frame)
    try:
        summary = errors.summary()
    except ValueError as exc:
        raise ValueError(f"recording {recording.name!r}: {exc}") from None
    return TrialScore(
        recording.name,
        summary.total_rmse_deg,
        summary.heading_rmse_deg,
        summary.inclination_rmse_deg,
        summary.n_samples,
        tuple(groups),
        recording.n_samples,
        seconds,
    )


def score_estimate(estimate: Any, recording: Recording) -> ErrorSummary:
    """The error of ``estimate`` against ``recording``'s truth, as ``margtrack evaluate``
    scores it (``margtrack.score``).

    Parameters
    ----------
    estimate : an :class:`~margtrack.estimator.Estimate` of the recording (or anything with
        its ``quat`` (N, 4) [w, x, y, z], body to earth, and ``frame``, such as a file read
        with :func:`margtrack.io.read_estimate`).
    recording : the recording it was made from, with truth ``quat_true``.

    Returns
    -------
    :class:`~margtrack.accuracy.ErrorSummary`: RMSE (deg) of the total, heading and
    inclination error over the recording's ``movement`` samples (every sample without a
    mask; truth holes skipped), and how many samples that is. Scoring every sample instead
    (``summarize(error_series(...))``) weighs the rests at the start and end of a trial,
    where the error is small, and reads lower than the benchmark figure.
    """
    return score(recording, estimate.quat, estimate.frame).errors


def evaluate(method: Method, recording: Recording, groups: Sequence[str] = ()) -> TrialScore:
    """Run ``method`` (fresh state) on ``recording`` and score it against the truth."""
    if recording.quat_true is None:  # before running: a long run for nothing otherwise
        raise ValueError(
            f"recording {recording.name!r} has no ground truth (quat_true); "
            "error figures need a recording with truth"
        )
    estimate, seconds = run_method(method, recording)
    return score(recording, estimate.quat, estimate.frame, groups=groups, seconds=seconds)


def evaluate_all(
    method: Method,
    recordings: Iterable[tuple[Recording, Sequence[str]]],
    *,
    label: str | None = None,
    params: Mapping[str, Any] | None = None,
    group_order: Sequence[str] = (),
    progress: Callable[[str], None] | None = None,
) -> Scores:
    """Evaluate one method on every (recording, groups) pair, a fresh state per trial.

    ``label`` and ``params`` default to the method's name and parameters; ``progress``
    is told each trial's name before it runs.
    """
    if params is None:
        raw = getattr(method, "params", {})
        params = raw.as_dict() if hasattr(raw, "as_dict") else dict(raw)
    rows = []
    for recording, groups in recordings:
        if progress is not None:
            progress(recording.name)
        rows.append(evaluate(method, recording, groups))
    if not rows:
        raise ValueError("no recording to evaluate")
    return Scores(label or method.name, dict(params), tuple(rows), tuple(group_order))
