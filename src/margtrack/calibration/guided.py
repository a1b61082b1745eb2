"""The guided calibration procedure (000, Appendix B steps 1-18) as a state machine fed by samples.

A person follows the instructions; the machine decides from the data alone when a pose or a
turn is done: *still* (:class:`~margtrack.calibration.static.StillnessDetector`), *which
axis sees gravity* (the still mean of the accelerometer, within ``max_tilt_deg`` of a signed
axis: "+y down" reads ``-g`` on y, since specific force points up) and *how far it turned*
(the gyro integrated from the last still pose, null removed). A turn counts when it starts
in the expected pose, ends in the expected pose and integrates to the known angle within
``angle_tolerance_deg``; anything else gets a message saying how to recover.

Samples come one at a time (:meth:`GuidedCalibration.add_sample`, for a live source) or as
arrays or a Recording (the same per-sample path). At step 18 it assembles the calibration
(:mod:`margtrack.calibration.procedure_result`). The poses (body axis pointing down) and
turns are those of :mod:`margtrack.calibration.simulate_procedure`'s table.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.calibration.procedure_result import GuidedResult, PoseRecord, assemble
from margtrack.calibration.static import StillnessDetector, StillnessSettings
from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.recording import Recording

Array = NDArray[np.float64]

__all__ = ["STAGES", "Event", "GuidedCalibration", "GuidedSettings", "Stage", "run_guided"]


@dataclass(frozen=True)
class GuidedSettings:
    """Tolerances of the guided procedure.

    stillness : the still test (:class:`StillnessSettings`).
    null_hold_s : still time needed in step 1 (gyro null), s (default 3).
    hold_s : still time needed in every other pose, s (default 1).
    max_tilt_deg : a pose counts if gravity is within this of a signed axis (default 10).
    angle_tolerance_deg : allowed gap between a turn's integral and its known angle (30).
    north_tolerance_deg : allowed heading of +x from magnetic north in step 18 (10).
    gravity_m_s2 : local gravity for eqs. 1-2 and the 12-parameter fit.
    mag_smooth_samples : moving average before min/max (000 eqs. 3-4), samples (5).
    use_ellipsoid : also fit an ellipsoid to all magnetometer samples and prefer it to
        min/max when the procedure's turns determine it (default True).
    """

    stillness: StillnessSettings = field(default_factory=StillnessSettings)
    null_hold_s: float = 3.0
    hold_s: float = 1.0
    max_tilt_deg: float = 10.0
    angle_tolerance_deg: float = 30.0
    north_tolerance_deg: float = 10.0
    gravity_m_s2: float = STANDARD_GRAVITY_M_S2
    mag_smooth_samples: int = 5
    use_ellipsoid: bool = True

    def __post_init__(self) -> None:
        for name in ("null_hold_s", "hold_s", "max_tilt_deg", "angle_tolerance_deg",
                     "north_tolerance_deg", "gravity_m_s2"):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if int(self.mag_smooth_samples) < 1:
            raise ValueError(f"mag_smooth_samples must be >= 1, got {self.mag_smooth_samples}")


@dataclass(frozen=True)
class Stage:
    """One action of the procedure: kind "hold", "turn", "spin" or "reference"; the paper's
    step; the body axis (0-2) and known angle (deg) of a turn; poses as "+z" (axis down)."""

    kind: str
    step: int
    axis: int
    angle_deg: float
    start: str
    end: str
    text: str


STAGES: tuple[Stage, ...] = (
    Stage("hold", 1, -1, 0.0, "+z", "+z", "place the sensor on a level non-magnetic surface, "
          "+z down, and keep it still (gyro null)"),
    Stage("turn", 2, 0, 90.0, "+z", "+y", "turn +90 deg about +x (onto the face with +y down), "
          "then hold still"),
    Stage("turn", 4, 0, -180.0, "+y", "-y", "turn 180 deg about -x (+y ends up), then hold still"),
    Stage("turn", 6, 2, 90.0, "-y", "-x", "turn +90 deg about +z (+x ends up), then hold still"),
    Stage("turn", 8, 2, -180.0, "-x", "+x", "turn 180 deg about -z (+x ends down), then hold "
          "still"),
    Stage("turn", 10, 1, -90.0, "+x", "-z", "turn 90 deg about -y (+z ends up), then hold still"),
    Stage("turn", 12, 1, 180.0, "-z", "+z", "turn +180 deg about +y (+z ends down), then hold "
          "still"),
    Stage("spin", 15, 1, 360.0, "+z", "+z", "+z down, point +x to magnetic north and hold still; "
          "then turn a full 360 deg about +y and hold still"),
    Stage("spin", 16, 0, 360.0, "+z", "+z", "+z down, point +y to magnetic north and hold still; "
          "then turn a full 360 deg about +x and hold still"),
    Stage("reference", 18, -1, 0.0, "+z", "+z", "reference position: +z down, +x to magnetic "
          "north, +y east; hold still"),
)


@dataclass(frozen=True)
class Event:
    """Something to tell the person: at ``t_s``, for paper ``step``; kind "instruction"
    (what to do now), "done" (a step's figures), "warning" (what went wrong and how to
    recover) or "finished"."""

    t_s: float
    step: int
    kind: str
    message: str


class _Period:
    """Sums over one still period (samples of its first quiet window included)."""

    def __init__(self, rows: list[tuple[float, Array, Array, Array, Array]]) -> None:
        self.t0 = rows[0][0]
        self.t1 = rows[-1][0]
        self.n = 0
        self.gyr = np.zeros(3)
        self.gyr_sq = np.zeros(3)
        self.acc = np.zeros(3)
        self.mag = np.zeros(3)
        self.theta_enter = rows[-1][4].copy()
        self.theta_anchor = rows[0][4].copy()
        for row in rows:
            self.add(row)

    def add(self, row: tuple[float, Array, Array, Array, Array]) -> None:
        self.t1 = row[0]
        self.n += 1
        self.gyr += row[1]
        self.gyr_sq += row[1] * row[1]
        self.acc += row[2]
        self.mag += row[3]

    def record(self, pose: str) -> PoseRecord:
        mean = self.gyr / self.n
        var = np.maximum(self.gyr_sq / self.n - mean * mean, 0.0) * self.n / max(self.n - 1, 1)
        return PoseRecord(pose, self.t0, self.t1, self.n, mean, np.sqrt(var), self.acc / self.n,
                          self.mag / self.n)


def _pose(acc_mean: Array, max_tilt_deg: float) -> tuple[str, float]:
    """("+y", tilt_deg): the signed body axis pointing down and its angle from gravity."""
    norm = float(np.linalg.norm(acc_mean))
    i = int(np.argmax(np.abs(acc_mean)))
    tilt = float(np.degrees(np.arccos(min(1.0, abs(acc_mean[i]) / norm)))) if norm else 90.0
    # specific force points up: the axis pointing down reads -g
    return ("-" if acc_mean[i] > 0 else "+") + "xyz"[i], tilt


class GuidedCalibration:
    """000's Appendix B procedure, driven by samples (module docstring).

    Use ``instruction`` to show what to do, feed samples with :meth:`add_sample` /
    :meth:`add_samples` / :meth:`add_recording` (each returns the new :class:`Event` s), and
    take :meth:`result` once ``finished``. The magnetometer is required.
    """

    def __init__(self, settings: GuidedSettings | None = None) -> None:
        self.settings = settings or GuidedSettings()
        self._detector = StillnessDetector(self.settings.stillness)
        self._window: deque[tuple[float, Array, Array, Array, Array]] = deque()
        self._stage = 0
        self._theta = np.zeros(3)
        self._null = np.zeros(3)
        self._t_prev: float | None = None
        self._period: _Period | None = None
        self._decided = False
        self._base: _Period | None = None  # the accepted still pose a turn starts from
        self._anchor: Array | None = None
        self._smooth: deque[Array] = deque()
        self._mag_hi = np.full(3, -np.inf)
        self._mag_lo = np.full(3, np.inf)
        self._poses: dict[int, _Period] = {}
        self._rotations: list[tuple[int, int, float, Array]] = []  # step, axis, known, turned deg
        self._extremes: dict[int, tuple[Array, Array]] = {}
        self._mag_all: list[Array] = []
        self._result: GuidedResult | None = None
        self.events: list[Event] = [Event(0.0, 1, "instruction", self.instruction)]

    @property
    def step(self) -> int:
        """The paper's step the procedure is waiting for (19 when finished)."""
        return STAGES[self._stage].step if self._stage < len(STAGES) else 19

    @property
    def finished(self) -> bool:
        """True once step 18 is done and :meth:`result` is available."""
        return self._result is not None

    @property
    def instruction(self) -> str:
        """What the person should do now."""
        if self._stage >= len(STAGES):
            return "done: the calibration is ready"
        stage = STAGES[self._stage]
        return f"step {stage.step}: {stage.text}"

    def result(self) -> GuidedResult:
        """The assembled calibration and its figures; ``ValueError`` before step 18 is done."""
        if self._result is None:
            warnings = [e.message for e in self.events if e.kind == "warning"][-3:]
            raise ValueError(
                f"the procedure is not finished; still waiting for {self.instruction}"
                + (f" (last warnings: {'; '.join(warnings)})" if warnings else "")
            )
        return self._result

    def add_recording(self, recording: Recording) -> list[Event]:
        """Feed a whole Recording (it must have a magnetometer)."""
        if recording.mag is None:
            raise ValueError("the guided procedure needs a magnetometer (steps 15-18)")
        return self.add_samples(recording.t, recording.gyr, recording.acc, recording.mag)

    def add_samples(self, t: ArrayLike, gyr: ArrayLike, acc: ArrayLike,
                    mag: ArrayLike) -> list[Event]:
        """Feed samples ``t`` (N,) s, ``gyr`` (N, 3) rad/s, ``acc`` (N, 3) m/s², ``mag`` (N, 3)."""
        t_arr = np.asarray(t, dtype=np.float64).reshape(-1)
        arrays = [np.asarray(x, dtype=np.float64) for x in (gyr, acc, mag)]
        for name, a in zip(("gyr", "acc", "mag"), arrays, strict=True):
            if a.shape != (t_arr.shape[0], 3) or not np.all(np.isfinite(a)):
                raise ValueError(f"{name} must be a finite ({t_arr.shape[0]}, 3) array, "
                                 f"got {a.shape}")
        new: list[Event] = []
        for i in range(t_arr.shape[0]):
            new += self._add(float(t_arr[i]), arrays[0][i], arrays[1][i], arrays[2][i])
        return new

    def add_sample(self, t: float, gyr: ArrayLike, acc: ArrayLike, mag: ArrayLike) -> list[Event]:
        """Feed one sample (t s, gyr (3,) rad/s, acc (3,) m/s², mag (3,) µT)."""
        return self.add_samples([t], np.reshape(gyr, (1, 3)), np.reshape(acc, (1, 3)),
                                np.reshape(mag, (1, 3)))

    # --- one sample -----------------------------------------------------------------------

    def _add(self, t: float, gyr: Array, acc: Array, mag: Array) -> list[Event]:
        if self.finished:
            return []
        still = self._detector.update(t, gyr, acc)
        if self._t_prev is not None:
            self._theta = self._theta + (gyr - self._null) * (t - self._t_prev)
        self._t_prev = t
        self._mag_all.append(mag)
        self._smooth.append(mag)
        if len(self._smooth) > self.settings.mag_smooth_samples:
            self._smooth.popleft()
        if len(self._smooth) == self.settings.mag_smooth_samples:
            m = np.mean(self._smooth, axis=0)
            self._mag_hi = np.maximum(self._mag_hi, m)
            self._mag_lo = np.minimum(self._mag_lo, m)
        row = (t, gyr, acc, mag, self._theta.copy())
        self._window.append(row)
        while self._window[0][0] < t - self.settings.stillness.window_s:
            self._window.popleft()
        events: list[Event] = []
        if still:
            if self._period is None:
                self._period = _Period(list(self._window))
                self._decided = False
            else:
                self._period.add(row)
            self._period.theta_anchor = self._window[0][4].copy()
            stage = STAGES[self._stage]
            need = self.settings.null_hold_s if stage.kind == "hold" else self.settings.hold_s
            if not self._decided and self._period.t1 - self._period.t0 >= need:
                self._decided = True
                events = self._decide(t, self._period)
        elif self._period is not None:
            if self._period is self._base:
                # the turn starts here: count it from the last quiet window's start
                self._anchor = self._period.theta_anchor
                self._mag_hi = np.full(3, -np.inf)
                self._mag_lo = np.full(3, np.inf)
            self._period = None
        self.events += events
        return events

    def _say(self, t: float, kind: str, message: str) -> Event:
        return Event(t, STAGES[min(self._stage, len(STAGES) - 1)].step, kind, message)

    def _advance(self, t: float, period: _Period) -> list[Event]:
        self._base = period
        self._stage += 1
        if self._stage < len(STAGES):
            return [self._say(t, "instruction", self.instruction)]
        return []

    def _decide(self, t: float, period: _Period) -> list[Event]:
        stage = STAGES[self._stage]
        pose, tilt = _pose(period.acc / period.n, self.settings.max_tilt_deg)
        flat = tilt <= self.settings.max_tilt_deg
        if not flat:
            return [self._say(t, "warning", f"still, but tilted {tilt:.0f} deg from every axis: "
                              "set the sensor flat on a face")]
        if stage.kind == "hold":
            if pose != stage.end:
                return [self._say(t, "warning", f"{pose} is down but step 1 needs +z down")]
            self._poses[1] = period
            self._null = period.gyr / period.n
            done = self._say(t, "done", "step 1: +z down; gyro null "
                             f"{np.degrees(self._null).round(3).tolist()} deg/s (kept averaging "
                             "while still)")
            return [done, *self._advance(t, period)]
        if stage.kind == "reference":
            return self._reference(t, period, pose)
        turned = np.degrees(period.theta_enter - self._anchor) if self._anchor is not None \
            else np.zeros(3)
        if stage.kind == "turn":
            return self._turn(t, period, pose, stage, turned)
        return self._spin(t, period, pose, stage, turned)

    def _restart(self, t: float, period: _Period, pose: str, stage: Stage) -> list[Event]:
        if pose == stage.start:
            self._base = period
            return [self._say(t, "instruction", f"back at {pose} down: {self.instruction}")]
        self._base = None
        return [self._say(t, "warning", f"{pose} is down; go back to {stage.start} down "
                          f"(step {stage.step}'s start) and {stage.text}")]

    def _turn(self, t: float, period: _Period, pose: str, stage: Stage,
              turned: Array) -> list[Event]:
        tol = self.settings.angle_tolerance_deg
        if pose != stage.end or self._base is None:
            if pose == stage.start and np.max(np.abs(turned)) < tol:
                self._base = period  # never left the start pose: re-anchor
                return []
            return self._restart(t, period, pose, stage)
        others = np.delete(turned, stage.axis)
        measured = float(turned[stage.axis])
        if abs(measured - stage.angle_deg) > tol or np.max(np.abs(others)) > tol:
            self._base = None
            return [self._say(t, "warning", f"the turn measured {np.round(turned, 1).tolist()} "
                              f"deg about (x, y, z), not {stage.angle_deg:+g} about "
                              f"{'xyz'[stage.axis]}; go back to {stage.start} down and "
                              f"{stage.text}")]
        self._poses[stage.step + 1] = period
        self._rotations.append((stage.step, stage.axis, stage.angle_deg, turned.copy()))
        done = self._say(t, "done", f"step {stage.step + 1}: {pose} down; "
                         f"{'xyz'[stage.axis]} gyro integrated {measured:.2f} deg for "
                         f"{stage.angle_deg:+g}: scale factor {stage.angle_deg / measured:.5f} "
                         "(000 eq. 5)")
        events = [done]
        if stage.step == 12:
            events.append(self._say(t, "done", "step 14: accelerometer null and scale from the "
                                    "six poses (000 eqs. 1-2) and the 12-parameter fit"))
        return events + self._advance(t, period)

    def _spin(self, t: float, period: _Period, pose: str, stage: Stage,
              turned: Array) -> list[Event]:
        tol = self.settings.angle_tolerance_deg
        if pose != "+z":
            self._base = None
            return [self._say(t, "warning", f"{pose} is down; put the sensor level with +z down")]
        spin = float(turned[stage.axis])
        others = np.delete(turned, stage.axis)
        if self._base is not None and abs(abs(spin) - 360.0) <= tol \
                and np.max(np.abs(others)) <= tol:
            self._extremes[stage.step] = (self._mag_hi.copy(), self._mag_lo.copy())
            known = 360.0 if spin > 0 else -360.0
            self._rotations.append((stage.step, stage.axis, known, turned.copy()))
            axes = "x and z" if stage.step == 15 else "y and z"
            events = [self._say(t, "done", f"step {stage.step}: turned {spin:.1f} deg about "
                                f"{'xyz'[stage.axis]}; magnetometer {axes} max/min recorded")]
            if stage.step == 16:
                events.append(self._say(t, "done", "step 17: magnetometer null and scale "
                                        "(000 eqs. 3-4)"))
            return events + self._advance(t, period)
        self._base = period  # a heading adjustment (or nothing): start the spin from here
        if np.max(np.abs(turned)) > tol:
            return [self._say(t, "instruction", f"turned {np.round(turned, 1).tolist()} deg; "
                              f"now {self.instruction}")]
        return []

    def _reference(self, t: float, period: _Period, pose: str) -> list[Event]:
        if pose != "+z":
            return [self._say(t, "warning", f"{pose} is down; step 18 needs +z down")]
        self._poses[18] = period
        result = assemble(
            {k: p.record(_pose(p.acc / p.n, 90.0)[0]) for k, p in self._poses.items()},
            self._rotations, self._extremes, np.array(self._mag_all), self.settings.gravity_m_s2,
            self.settings.mag_smooth_samples, self.settings.use_ellipsoid,
        )
        heading = result.reference.heading_offset_deg
        if abs(heading) > self.settings.north_tolerance_deg:
            del self._poses[18]
            return [self._say(t, "warning", f"+x points {heading:+.1f} deg from magnetic north "
                              f"(east positive): turn {-heading:+.0f} deg about the vertical "
                              "and hold still")]
        self._result = result
        self._stage += 1
        ref = result.reference
        return [Event(t, 18, "done", f"step 18: gravity {ref.gravity_m_s2:.4f} m/s², field "
                      f"{ref.field_ut:.2f} µT, dip {ref.dip_deg:.2f} deg"),
                Event(t, 18, "finished", "calibration complete")]


def run_guided(recording: Recording, settings: GuidedSettings | None = None) -> GuidedResult:
    """Run the procedure over a whole Recording; ``ValueError`` with the pending instruction
    and the last warnings if it does not reach the end."""
    machine = GuidedCalibration(settings)
    machine.add_recording(recording)
    try:
        return machine.result()
    except ValueError as exc:
        raise ValueError(f"the recording ends before the procedure does: {exc}") from None
