"""000's Appendix B procedure driven live: the guided state machine plus what a person needs
to see while doing it (no sockets, no screen: :mod:`margtrack.live.calibration_panel` and
``margtrack calibrate guided --udp/--serial`` show it).

:class:`LiveProcedure` feeds samples of one sensor to
:class:`~margtrack.calibration.guided.GuidedCalibration` (which decides when a pose or a turn
is done and assembles the calibration) and keeps a :class:`ProcedureStatus` after every
sample:

- the step being waited for and its instruction (``step``, ``instruction``);
- a progress bar for each hold: ``hold_progress`` 0..1, the still time so far over the time
  the step needs (``null_hold_s`` in step 1, ``hold_s`` elsewhere); it drops to 0 when the
  sensor moves;
- which signed body axis points down now (``down``, from the mean specific force over the
  last ``window_s``: the axis reading about ``-g``) and which one should (``expected_down``);
- what is wrong, in words (``problem``): ``"+z should point down (now +y is down)"``,
  ``"hold still"``, ``"set the sensor flat on a face (tilted 23 deg)"``, or ``""``;
- the last message of the state machine (``message``: its instructions, figures and
  warnings such as "the turn measured ... go back to +y down").

Live samples are checked before they reach the state machine: a non-finite value or a time
not after the previous sample's is rejected and counted (``rejected``, ``last_rejection``),
never raised, so one bad packet does not end a calibration.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.calibration.guided import (
    STAGES,
    Event,
    GuidedCalibration,
    GuidedSettings,
    Stage,
)
from margtrack.calibration.procedure_result import GuidedResult
from margtrack.calibration.static import StillnessDetector
from margtrack.io.safe_output import atomic_output, check_output

Array = NDArray[np.float64]

__all__ = ["LiveProcedure", "ProcedureStatus", "save_result"]


@dataclass(frozen=True)
class ProcedureStatus:
    """What to show during the live procedure (module docstring); times in s, angles in deg."""

    t_s: float
    step: int
    stage: int
    n_stages: int
    instruction: str
    hold_needed_s: float
    hold_progress: float
    still: bool
    down: str
    tilt_deg: float
    expected_down: str
    problem: str
    message: str
    finished: bool
    samples: int
    rejected: int

    def line(self, width: int = 20) -> str:
        """One text line: step, progress bar, what is wrong (for terminals and logs)."""
        filled = round(self.hold_progress * width)
        bar = "#" * filled + "-" * (width - filled)
        state = "done" if self.finished else (self.problem or ("still" if self.still
                                                               else "moving"))
        return (f"step {self.step:2d}/18 [{bar}] {100 * self.hold_progress:3.0f}%  "
                f"down {self.down or '?'} (want {self.expected_down})  {state}")


class LiveProcedure:
    """The guided procedure on live samples of one sensor (module docstring).

    Parameters
    ----------
    settings : tolerances (:class:`GuidedSettings`), shared with the offline procedure.
    """

    def __init__(self, settings: GuidedSettings | None = None) -> None:
        self.settings = settings or GuidedSettings()
        self.machine = GuidedCalibration(self.settings)
        self._detector = StillnessDetector(self.settings.stillness)
        self._recent: deque[tuple[float, Array]] = deque()
        self._acc_sum = np.zeros(3)
        self._still_since: float | None = None
        self._t_last = -math.inf
        self._samples = 0
        self.rejected = 0
        self.last_rejection = ""
        self._message = self.machine.instruction
        self._status = self._make_status(0.0, False)

    @property
    def finished(self) -> bool:
        """True once step 18 is done: :meth:`result` is ready."""
        return self.machine.finished

    @property
    def status(self) -> ProcedureStatus:
        """The status after the last sample."""
        return self._status

    @property
    def events(self) -> list[Event]:
        """Every event of the state machine so far."""
        return list(self.machine.events)

    def result(self) -> GuidedResult:
        """The calibration and its figures (``ValueError`` before the procedure is done)."""
        return self.machine.result()

    def _reject(self, reason: str) -> list[Event]:
        self.rejected += 1
        self.last_rejection = reason
        return []

    def add_sample(self, t_s: float, gyr: ArrayLike, acc: ArrayLike, mag: ArrayLike
                   ) -> list[Event]:
        """Feed one sample: t s, gyr (3,) rad/s, acc (3,) m/s², mag (3,) µT (sensor frame).

        Returns the state machine's new events; a bad sample is counted, not raised.
        """
        g, a, m = (np.asarray(v, dtype=np.float64).reshape(3) for v in (gyr, acc, mag))
        t = float(t_s)
        if not (math.isfinite(t) and np.all(np.isfinite(g)) and np.all(np.isfinite(a))
                and np.all(np.isfinite(m))):
            return self._reject(f"sample at t = {t!r} s has a non-finite value; skipped")
        if t <= self._t_last:
            return self._reject(f"time {t!r} s is not after the previous sample's "
                                f"{self._t_last!r} s; skipped")
        if self.finished:
            return []
        self._t_last = t
        self._samples += 1
        still = self._detector.update(t, g, a)
        window = self.settings.stillness.window_s
        self._recent.append((t, a))
        self._acc_sum += a
        while self._recent[0][0] < t - window:
            self._acc_sum -= self._recent.popleft()[1]
        if still and self._still_since is None:
            self._still_since = self._recent[0][0]  # the state machine's hold starts there
        elif not still:
            self._still_since = None
        stage = self._stage_index()
        events = self.machine.add_sample(t, g, a, m)
        if events:
            self._message = events[-1].message
        if self._stage_index() != stage:
            self._still_since = t  # a new step: its hold counts from now
        self._status = self._make_status(t, still)
        return events

    def add_samples(self, t_s: ArrayLike, gyr: ArrayLike, acc: ArrayLike, mag: ArrayLike
                    ) -> list[Event]:
        """Feed N samples (t (N,), gyr/acc/mag (N, 3)); bad ones are counted and skipped."""
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        arrays = [np.asarray(v, dtype=np.float64).reshape(t.size, 3) for v in (gyr, acc, mag)]
        events: list[Event] = []
        for i in range(t.size):
            events += self.add_sample(t[i], arrays[0][i], arrays[1][i], arrays[2][i])
        return events

    # -- status -----------------------------------------------------------------------------
    def _down(self) -> tuple[str, float]:
        if not self._recent:
            return "", 90.0
        mean = self._acc_sum / len(self._recent)
        norm = float(np.linalg.norm(mean))
        if norm < 0.5 * self.settings.gravity_m_s2:
            return "", 90.0  # free fall or a broken accelerometer: no pose
        i = int(np.argmax(np.abs(mean)))
        tilt = float(np.degrees(np.arccos(min(1.0, abs(mean[i]) / norm))))
        return ("-" if mean[i] > 0 else "+") + "xyz"[i], tilt  # specific force points up

    def _make_status(self, t: float, still: bool) -> ProcedureStatus:
        stage_i = self._stage_index()
        finished = self.finished
        stage = STAGES[stage_i]
        need = self.settings.null_hold_s if stage.kind == "hold" else self.settings.hold_s
        progress = 0.0
        if finished:
            progress = 1.0
        down, tilt = self._down()
        if not finished and still and self._still_since is not None and down == stage.end \
                and tilt <= self.settings.max_tilt_deg:
            progress = min(1.0, (t - self._still_since) / need)
        expected = stage.end
        problem = "" if finished else self._problem(stage, still, down, tilt)
        return ProcedureStatus(
            t_s=t, step=self.machine.step, stage=stage_i + (1 if finished else 0),
            n_stages=len(STAGES), instruction=self.machine.instruction, hold_needed_s=need,
            hold_progress=progress, still=still, down=down, tilt_deg=tilt,
            expected_down=expected, problem=problem, message=self._message, finished=finished,
            samples=self._samples, rejected=self.rejected)

    def _stage_index(self) -> int:
        step = self.machine.step
        for i, stage in enumerate(STAGES):
            if stage.step == step:
                return i
        return len(STAGES) - 1

    def _problem(self, stage: Stage, still: bool, down: str, tilt: float) -> str:
        if not down:
            return "no gravity reading: check the accelerometer"
        flat = tilt <= self.settings.max_tilt_deg
        if still and not flat:
            return f"set the sensor flat on a face (tilted {tilt:.0f} deg)"
        if stage.kind in ("hold", "reference"):
            if flat and down != "+z":
                return f"+z should point down (now {down} is down)"
            return "hold still" if flat and not still else ""
        if stage.kind == "spin":  # it passes every pose while turning: judge it at rest
            return f"+z should point down (now {down} is down)" if still and flat and \
                down != "+z" else ""
        # a turn: from its start pose to its end pose, then a hold
        if still and flat and down not in (stage.start, stage.end):
            return (f"{stage.end} should point down after this turn (now {down} is down): go "
                    f"back to {stage.start} down and turn again")
        if not still and flat and down == stage.end:
            return "hold still"
        return ""


def save_result(result: GuidedResult, path: str | Path, source: str = "",
                force: bool = False) -> Path:
    """Write the procedure's calibration JSON atomically; refuses to overwrite without
    ``force`` (:func:`margtrack.io.safe_output.check_output`). Returns the path."""
    out = check_output(path, force=force)
    cal = dataclasses.replace(result.calibration, source=source or "live guided procedure")
    with atomic_output(out) as tmp:
        tmp.write_text(cal.to_json(), encoding="utf-8")
    return out
