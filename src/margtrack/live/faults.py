"""Field faults on demand: a line stream of S sensors with the faults body-worn sensors have.

:class:`FaultyStream` produces the text lines (:mod:`margtrack.live.lines`, with sequence
numbers) of ``n_sensors`` sensors at ``rate_hz`` for ``duration_s``, grouped by the wall
time they are due, each sensor turning about the vertical (ENU) at its own rate
``0.2 + 0.05 i`` rad/s, level, in a field of 40 uT (dip 60 deg), every sensor on one
device clock starting at ``clock0_s``. :class:`Fault` entries change that stream:

- ``"reboot"``: from ``at_s`` on, the sensor's clock and sequence number restart at 0;
- ``"stamp"``: the sensor's sample at ``at_s`` is stamped ``value`` (1e9) instead;
- ``"zero_acc"``: the sensor's samples from ``at_s`` for ``duration_s`` have acc = 0
  (``at_s = 0``: its first line);
- ``"gyro"``: the sensor's rate at ``at_s`` is ``value`` (1e300) rad/s on x;
- ``"silent"``: the sensor sends nothing from ``at_s`` for ``duration_s``;
- ``"drop"``: its lines from ``at_s`` for ``duration_s`` are lost on the way (sequence
  numbers go on: counted as lost);
- ``"duplicate"``: its line at ``at_s`` is sent twice;
- ``"garbage"``: a malformed line (``value`` fields of text) is sent at ``at_s``.

:meth:`FaultyStream.expected` gives, per sensor, how many lines were sent and what the
engine should count; :func:`default_faults` mixes every fault over the first sensors and
leaves the others clean (the soak test and ``benchmarks/live_soak.py``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from margtrack.live.lines import format_line

__all__ = ["FAULT_KINDS", "Fault", "FaultyStream", "default_faults"]

FAULT_KINDS = ("reboot", "stamp", "zero_acc", "gyro", "silent", "drop", "duplicate", "garbage")

_G = 9.81
_FIELD_UT = 40.0
_DIP_RAD = math.radians(60.0)


@dataclass(frozen=True)
class Fault:
    """One fault: ``kind`` (module docstring) of ``sensor`` at ``at_s`` for ``duration_s``."""

    kind: str
    sensor: int
    at_s: float
    duration_s: float = 0.0
    value: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r}; known: {', '.join(FAULT_KINDS)}")
        if not (math.isfinite(self.at_s) and self.at_s >= 0 and self.duration_s >= 0):
            raise ValueError(f"fault times must be finite and >= 0, got {self}")

    def covers(self, t_s: float) -> bool:
        """Whether session time ``t_s`` falls in this fault's interval (or is its instant)."""
        if self.duration_s == 0.0:
            return abs(t_s - self.at_s) < 1e-9
        return self.at_s - 1e-9 <= t_s < self.at_s + self.duration_s - 1e-9


def default_faults(duration_s: float) -> list[Fault]:
    """Every fault the live engine handles, once each on sensors 0..8, spread over
    ``duration_s`` (>= 3 s)."""
    if duration_s < 3.0:
        raise ValueError(f"the fault mix needs at least 3 s, got {duration_s}")
    d = duration_s
    return [
        Fault("reboot", 0, round(0.4 * d, 2)),
        Fault("stamp", 1, round(0.3 * d, 2), value=1e9),
        Fault("zero_acc", 2, 0.0, 0.05),
        Fault("gyro", 3, round(0.5 * d, 2), value=1e300),
        Fault("silent", 4, round(0.3 * d, 2), round(0.3 * d, 2)),
        Fault("drop", 5, round(0.6 * d, 2), 0.05),
        Fault("duplicate", 6, round(0.2 * d, 2)),
        Fault("garbage", 7, round(0.7 * d, 2), value=3),
        Fault("reboot", 8, round(0.8 * d, 2)),
    ]


class FaultyStream:
    """Lines of S simulated sensors with faults (module docstring).

    Parameters
    ----------
    n_sensors : S; rate_hz : sample rate, Hz; duration_s : length, s.
    faults : the faults; sensors they name must exist.
    clock0_s : the device clock at the first sample, s.
    """

    def __init__(self, n_sensors: int = 15, rate_hz: float = 100.0, duration_s: float = 5.0,
                 faults: Sequence[Fault] = (), clock0_s: float = 100.0) -> None:
        if n_sensors < 1 or not (rate_hz > 0) or not (duration_s > 0):
            raise ValueError("n_sensors >= 1, rate_hz > 0 and duration_s > 0 are required")
        for f in faults:
            if not 0 <= f.sensor < n_sensors:
                raise ValueError(f"fault {f} names sensor {f.sensor}; there are {n_sensors}")
        self.n_sensors = n_sensors
        self.rate_hz = float(rate_hz)
        self.n_frames = math.floor(duration_s * rate_hz + 0.5)
        self.faults = tuple(faults)
        self.clock0_s = float(clock0_s)
        self.rate_rad_s = 0.2 + 0.05 * np.arange(n_sensors)

    @property
    def affected(self) -> set[int]:
        """Sensors with a fault."""
        return {f.sensor for f in self.faults}

    def _of(self, sensor: int, kind: str, t: float) -> Fault | None:
        for f in self.faults:
            if f.sensor == sensor and f.kind == kind and f.covers(t):
                return f
        return None

    def truth_yaw_rad(self, sensor: int, t_s: float) -> float:
        """The sensor's true heading at session time ``t_s``, rad (about +z, ENU)."""
        return float(self.rate_rad_s[sensor] * t_s)

    def ticks(self) -> Iterator[tuple[float, list[str]]]:
        """``(t_s, lines)`` per sample time: the lines to send then (session time)."""
        reboot_at = {f.sensor: f.at_s for f in self.faults if f.kind == "reboot"}
        seq = np.zeros(self.n_sensors, dtype=np.int64)
        for k in range(self.n_frames):
            t = k / self.rate_hz
            lines: list[str] = []
            for s in range(self.n_sensors):
                if self._of(s, "silent", t):
                    continue
                device = self.clock0_s + t
                if s in reboot_at and t >= reboot_at[s] - 1e-9:
                    if abs(t - reboot_at[s]) < 1e-9:
                        seq[s] = 0
                    device = t - reboot_at[s]
                stamp = self._of(s, "stamp", t)
                if stamp is not None:
                    device = stamp.value
                yaw = self.truth_yaw_rad(s, t)
                c, sn = math.cos(yaw), math.sin(yaw)
                gyr = [0.0, 0.0, float(self.rate_rad_s[s])]
                gyro = self._of(s, "gyro", t)
                if gyro is not None:
                    gyr[0] = gyro.value
                acc = [0.0, 0.0, _G] if self._of(s, "zero_acc", t) is None else [0.0, 0.0, 0.0]
                north, down = _FIELD_UT * math.cos(_DIP_RAD), _FIELD_UT * math.sin(_DIP_RAD)
                mag = [north * sn, north * c, -down]  # earth (0, north, -down) in the body
                line = format_line(device, s, gyr, acc, mag, seq=int(seq[s]))
                seq[s] += 1
                if self._of(s, "drop", t):
                    continue
                lines.append(line)
                if self._of(s, "duplicate", t):
                    lines.append(line)
                garbage = self._of(s, "garbage", t)
                if garbage is not None:
                    lines.append(",".join(["x"] * max(int(garbage.value), 1)) + "\n")
            yield t, lines

    def expected(self) -> dict[str, np.ndarray]:
        """Per sensor (S,): ``sent`` sample lines (duplicates and garbage not included),
        ``dropped`` on the way, ``duplicates``, ``silent_s``, ``resyncs``, ``bad_stamps``."""
        out = {key: np.zeros(self.n_sensors, dtype=np.int64)
               for key in ("sent", "dropped", "duplicates", "resyncs", "bad_stamps")}
        out["silent_s"] = np.zeros(self.n_sensors)
        for f in self.faults:
            if f.kind == "reboot":
                out["resyncs"][f.sensor] += 1
            elif f.kind == "stamp":
                out["bad_stamps"][f.sensor] += 1
            elif f.kind == "silent":
                out["silent_s"][f.sensor] += f.duration_s
        for k in range(self.n_frames):
            t = k / self.rate_hz
            for s in range(self.n_sensors):
                if self._of(s, "silent", t):
                    continue
                if self._of(s, "drop", t):
                    out["dropped"][s] += 1
                    continue
                out["sent"][s] += 1
                if self._of(s, "duplicate", t):
                    out["duplicates"][s] += 1
        return out
