"""Tilt-table experiments of 002 and 001, simulated: rotations by hand or by a table, then still.

- ``lowpass-tracking`` (002 Figs. 4-6): the sensor module on a tilt table is rolled -90 deg
  at 60 deg/s and back, twice. Raw accelerometer data carry the table's accelerations
  (the module sits 0.11 m off the roll axis: tangential and centripetal acceleration, a
  jolt when each move starts and stops) and, while the table moves, its motor's vibration
  (13, 17 and 21 Hz, 2 m/s² per axis). 002: "Neither [QUEST nor FQA] was able to correctly
  estimate orientation during rotational motion" (Fig. 4); with the accelerometer
  low-passed, "either algorithm can be used to track the orientation" (Fig. 6). Every
  case runs FQA and QUEST on the same samples: raw, the accelerometer alone low-passed at
  5 Hz, both signals low-passed at 5 Hz and at 2 Hz (the module's prefilter, a 2nd-order
  Butterworth, :mod:`margtrack.single_frame.prefilter`). Filtering both keeps the two
  vectors in step; filtering one delays it against the other during the turn.
- ``ekf-hand-rotations`` (001 5.3, Figs. 9-10): "first rotated 90 degrees about the x axis,
  followed by a 90 degree rotation about the y axis, and finally rotated 90 degrees about
  the z axis", by hand on a tabletop (about 1 s each, still in between), with MEMS sensor
  errors; the estimated rates must be near zero except during each turn, and the
  quaternion must reach each still orientation, which 001 marks on its Fig. 10.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.bench.experiments import ExperimentResult
from margtrack.bench.experiments.single_frame import _figure
from margtrack.methods.ekf import MarinsEkf
from margtrack.recording import Recording
from margtrack.sim.trajectories import Hold, Rotate, rotation_sequence
from margtrack.single_frame.fqa import Fqa
from margtrack.single_frame.quest import Quest

__all__ = ["EXPERIMENTS", "hand_rotations", "lowpass_tracking", "tilt_table_recording"]

RATE_HZ = 100.0
#: where the module sits on the table, body frame, m (off the x roll axis)
LEVER_ARM_M = (0.0, 0.05, 0.10)
VIBRATION_HZ = (13.0, 17.0, 21.0)
VIBRATION_M_S2 = 2.0
#: (label, acc cut-off Hz, mag cut-off Hz); None = no prefilter
CASES: tuple[tuple[str, float | None, float | None], ...] = (
    ("raw", None, None),
    ("acc 5 Hz", 5.0, None),
    ("acc+mag 5 Hz", 5.0, 5.0),
    ("acc+mag 2 Hz", 2.0, 2.0),
)


def tilt_table_recording(cycles: int = 2, seed: int = 1) -> tuple[Recording, np.ndarray]:
    """002's tilt-table run (NED) and the (N,) mask of samples while the table moves.

    The module's earth-frame acceleration is the second difference of its position
    ``R(t) r`` (lever arm r, ``LEVER_ARM_M``), plus the motor's vibration while moving;
    MEMS accelerometer and magnetometer errors (no gyroscope is used).
    """
    move = [Rotate((1.0, 0.0, 0.0), -90.0, 60.0), Hold(2.0),
            Rotate((1.0, 0.0, 0.0), 90.0, 60.0), Hold(2.0)]
    traj = rotation_sequence([Hold(2.0), *move * cycles], RATE_HZ)
    dt = 1.0 / RATE_HZ
    pos = quat.rotate(traj.quat, np.asarray(LEVER_ARM_M))
    acc_lin = np.gradient(np.gradient(pos, dt, axis=0), dt, axis=0)
    turning = quat.angle_between(traj.quat[1:], traj.quat[:-1]) > 1e-12
    moving = np.r_[turning, False] | np.r_[False, turning]
    phase = 2.0 * np.pi * np.outer(traj.t, VIBRATION_HZ) + np.arange(3)
    acc_lin = acc_lin + VIBRATION_M_S2 * np.sin(phase) * moving[:, None]
    traj = dataclasses.replace(traj, pos_m=pos, acc_lin_m_s2=acc_lin)
    rec = sim.simulate(traj, frame="NED", acc_errors=sim.SensorErrors.mems_acc(),
                       mag_errors=sim.SensorErrors.mems_mag(), seed=seed, name="tilt table")
    return rec, moving


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def lowpass_tracking(out_dir: Path, quick: bool) -> ExperimentResult:
    """002 Figs. 4 and 6: FQA and QUEST on a tilt table, raw and low-pass filtered."""
    rec, moving = tilt_table_recording(cycles=1 if quick else 2)
    figures: dict[str, Any] = {"moving_samples": int(moving.sum())}
    rolls: dict[str, np.ndarray] = {}
    for cls in (Fqa, Quest):
        for label, acc_hz, mag_hz in CASES:
            est = cls(frame="NED", acc_lowpass_hz=acc_hz, mag_lowpass_hz=mag_hz).run(rec)
            err = np.degrees(quat.angle_between(est.quat, rec.quat_true))
            key = f"{cls.name} {label}"
            figures[f"{key} moving_rms_deg"] = _rms(err[moving])
            figures[f"{key} moving_max_deg"] = float(err[moving].max())
            figures[f"{key} still_rms_deg"] = _rms(err[~moving])
            rolls[key] = np.degrees(quat.to_euler(est.quat)[:, 0])
    truth_roll = np.degrees(quat.to_euler(rec.quat_true)[:, 0])

    def draw(axes):
        for col, name in enumerate(("quest", "fqa")):
            for row, label in enumerate(("raw", "acc+mag 5 Hz")):
                ax = axes[row, col]
                ax.plot(rec.t, truth_roll, "k", lw=0.8, label="truth")
                ax.plot(rec.t, rolls[f"{name} {label}"], lw=0.8, label=name)
                fig = "4" if label == "raw" else "6"
                ax.set(title=f"002 Fig. {fig}: {name}, {label}", xlabel="t (s)",
                       ylabel="roll (deg)")
                ax.legend(fontsize=7)

    plot = _figure(out_dir, "lowpass-tracking", 2, 2, draw)
    best = min((f"{c[0]}" for c in CASES[1:]),
               key=lambda c: figures[f"fqa {c} moving_rms_deg"])
    notes = (
        f"During the turns, raw data: FQA {figures['fqa raw moving_rms_deg']:.1f} deg RMS "
        f"(max {figures['fqa raw moving_max_deg']:.0f}), QUEST "
        f"{figures['quest raw moving_rms_deg']:.1f} deg; best prefilter ({best}): FQA "
        f"{figures[f'fqa {best} moving_rms_deg']:.1f} deg, QUEST "
        f"{figures[f'quest {best} moving_rms_deg']:.1f} deg. As 002 Fig. 6: tracking "
        "during the motion once the accelerometer is low-passed; filtering the field at "
        "the same cut-off keeps the two vectors in step.",
    )
    return ExperimentResult("lowpass-tracking", figures, (plot,), notes)


def hand_rotations(out_dir: Path, quick: bool) -> ExperimentResult:
    """001 Figs. 9-10: 90 deg about x, then y, then z, by hand; rates and quaternion."""
    hold = 1.0 if quick else 3.0
    # about the sensor's own x, y, z in turn: each body axis where it points in the earth
    steps: list[Rotate | Hold] = [Hold(hold)]
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for body_axis in np.eye(3):
        axis = quat.rotate(q, body_axis)
        steps += [Rotate(tuple(axis), 90.0, 90.0), Hold(hold)]
        q = quat.multiply(quat.from_axis_angle(axis, np.pi / 2), q)
    traj = rotation_sequence(steps, RATE_HZ)
    rec = sim.simulate(traj, frame="NED", gyr_errors=sim.SensorErrors.mems_gyr(),
                       acc_errors=sim.SensorErrors.mems_acc(),
                       mag_errors=sim.SensorErrors.mems_mag(), seed=5, name="hand rotations")
    est = MarinsEkf(frame="NED").run(rec)
    rate = est.outputs["gyr_est_rad_s"]
    true_rate = sim.body_rate(traj)
    err = np.degrees(quat.angle_between(est.quat, rec.quat_true))
    still = np.linalg.norm(true_rate, axis=1) == 0.0
    figures: dict[str, Any] = {}
    # the end of each hold: the still orientation 001 marks on its Fig. 10
    ends = np.flatnonzero(np.diff(still.astype(int)) == -1)
    ends = np.r_[ends, rec.n_samples - 1]
    for k, i in enumerate(ends):
        figures[f"hold {k} error_deg"] = float(err[i])
        figures[f"hold {k} quat"] = [round(float(v), 3) for v in est.quat[i]]
        figures[f"hold {k} true_quat"] = [round(float(v), 3) for v in rec.quat_true[i]]
    settled = still & (rec.t > 0.5)
    figures["still max_rate_deg_s"] = float(np.degrees(np.abs(rate[settled]).max()))
    turning_rate = np.degrees(np.abs(rate[~still]).max(axis=0))
    figures["turning peak_rate_deg_s"] = [round(float(v), 1) for v in turning_rate]

    def draw(axes):
        for k, label in enumerate(("p", "q", "r")):
            axes[0, 0].plot(rec.t, np.degrees(rate[:, k]), lw=0.8, label=label)
        axes[0, 0].set(title="001 Fig. 9: estimated rates", xlabel="t (s)", ylabel="deg/s")
        axes[0, 0].legend(fontsize=7)
        for k, label in enumerate("wxyz"):
            line = axes[0, 1].plot(rec.t, est.quat[:, k], lw=0.8, label=label)[0]
            axes[0, 1].plot(rec.t, rec.quat_true[:, k], "--", lw=0.6, color=line.get_color())
        axes[0, 1].set(title="001 Fig. 10: quaternion (dashed: truth)", xlabel="t (s)")
        axes[0, 1].legend(fontsize=7)

    plot = _figure(out_dir, "ekf-hand-rotations", 1, 2, draw)
    worst = max(figures[f"hold {k} error_deg"] for k in range(len(ends)))
    notes = (f"Each still orientation reached within {worst:.2f} deg; rates at rest below "
             f"{figures['still max_rate_deg_s']:.2f} deg/s (001: 'mostly zero except the brief "
             "moment when the sensor was rotated about that axis').",)
    return ExperimentResult("ekf-hand-rotations", figures, (plot,), notes)


EXPERIMENTS = {"lowpass-tracking": lowpass_tracking, "ekf-hand-rotations": hand_rotations}
