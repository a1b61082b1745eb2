"""A simulated recording of a person following 000's 18-step calibration (Appendix B).

The motions, in NED (body axes named as in the paper; turns about body axes):

====  ==========================================================  ==================
step  action                                                      pose after (down)
====  ==========================================================  ==================
1     hold still on a level surface, +z down (gyro null)           +z
2     turn +90 deg about +x                                        +y
4     turn 180 deg about -x (-180 about +x)                        -y (+y up)
6     turn +90 deg about +z                                        -x (+x up)
8     turn 180 deg about -z                                        +x
10    turn 90 deg about -y                                         -z (+z up)
12    turn +180 deg about +y                                       +z
15    face +x to magnetic north (a turn about the vertical), then  +z
      turn 360 deg about +y (which points east)
16    face +y to magnetic north, turn 360 deg about +x             +z
18    face +x to magnetic north, hold still (reference position)   +z
====  ==========================================================  ==================

Every pose is held ``hold_s`` seconds (the first ``first_hold_s``), every turn is at
``rate_deg_s``. The person starts facing ``start_heading_deg`` east of magnetic north.
Magnetic north is the x axis of NED (:func:`margtrack.frames.mag_reference`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from margtrack import quaternion as qt
from margtrack.recording import Recording
from margtrack.sim import DEFAULT_DIP_DEG, DEFAULT_FIELD_UT, Hold, Rotate, SensorErrors, simulate
from margtrack.sim.trajectories import Trajectory, rotation_sequence

__all__ = ["PROFILES", "error_profile", "procedure_steps", "procedure_trajectory",
           "simulate_procedure"]

#: Names of the sensor error profiles :func:`error_profile` knows.
PROFILES = ("none", "mems", "raw")


def error_profile(name: str) -> tuple[SensorErrors, SensorErrors, SensorErrors]:
    """(gyr, acc, mag) errors: "none" perfect; "mems" :meth:`SensorErrors.mems_gyr` etc.
    (a factory-trimmed part); "raw" the same noise with the offsets of an untrimmed part
    on a circuit board: gyro null (1.5, -1, 2) deg/s, scale 1.5-3 %, misalignment ~1 deg;
    accelerometer null 0.25-0.4 m/s², scale ~2 %; hard iron (25, -15, 40) µT, soft iron
    5-10 %, misalignment 2-3 deg."""
    if name not in PROFILES:
        raise ValueError(f"profile must be one of {', '.join(PROFILES)}, got {name!r}")
    if name == "none":
        return SensorErrors.none(), SensorErrors.none(), SensorErrors.none()
    gyr, acc, mag = SensorErrors.mems_gyr(), SensorErrors.mems_acc(), SensorErrors.mems_mag()
    if name == "mems":
        return gyr, acc, mag
    return (
        dataclasses.replace(gyr, bias=tuple(np.radians([1.5, -1.0, 2.0])),
                            scale=(0.02, -0.015, 0.03), misalignment_deg=(1.0, -0.8, 0.6)),
        dataclasses.replace(acc, bias=(0.3, -0.25, 0.4), scale=(0.02, -0.015, 0.025),
                            misalignment_deg=(1.0, -0.8, 0.7)),
        dataclasses.replace(mag, bias=(25.0, -15.0, 40.0), scale=(0.08, -0.05, 0.1),
                            misalignment_deg=(3.0, -2.0, 2.0)),
    )

_BODY = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]),
         "z": np.array([0.0, 0.0, 1.0])}
_DOWN = np.array([0.0, 0.0, 1.0])  # NED

#: (paper step, body axis, angle deg) of the inertial turns, Appendix B steps 2-13.
INERTIAL_TURNS = ((2, "x", 90.0), (4, "x", -180.0), (6, "z", 90.0), (8, "z", -180.0),
                  (10, "y", -90.0), (12, "y", 180.0))


def _heading_deg(q: np.ndarray, body_axis: str) -> float:
    v = qt.rotate(q, _BODY[body_axis])
    return float(np.degrees(np.arctan2(v[1], v[0])))


def procedure_steps(
    start_heading_deg: float = 20.0, rate_deg_s: float = 90.0, hold_s: float = 3.0,
    first_hold_s: float = 5.0,
) -> tuple[list[Rotate | Hold], list[tuple[int, str]]]:
    """The Rotate/Hold steps (earth-frame axes, NED) and a (paper step, label) per step."""
    q = qt.from_axis_angle(_DOWN, np.radians(start_heading_deg))
    steps: list[Rotate | Hold] = [Hold(first_hold_s)]
    labels: list[tuple[int, str]] = [(1, "hold +z down")]

    def turn(axis_earth: np.ndarray, angle_deg: float, step: int, label: str,
             hold_step: int) -> None:
        nonlocal q
        if abs(angle_deg) < 1e-9:
            return
        steps.append(Rotate(tuple(axis_earth), angle_deg, rate_deg_s))
        labels.append((step, label))
        q = qt.multiply(qt.from_axis_angle(axis_earth, np.radians(angle_deg)), q)
        steps.append(Hold(hold_s))
        labels.append((hold_step, "hold"))

    for step, axis, angle in INERTIAL_TURNS:
        turn(qt.rotate(q, _BODY[axis]), angle, step, f"turn {angle:+g} deg about +{axis}",
             step + 1)
    turn(_DOWN, -_heading_deg(q, "x"), 15, "face +x north", 15)
    turn(qt.rotate(q, _BODY["y"]), 360.0, 15, "turn 360 deg about +y", 15)
    turn(_DOWN, -_heading_deg(q, "y"), 16, "face +y north", 16)
    turn(qt.rotate(q, _BODY["x"]), 360.0, 16, "turn 360 deg about +x", 16)
    turn(_DOWN, -_heading_deg(q, "x"), 18, "face +x north (reference position)", 18)
    return steps, labels


def procedure_trajectory(rate_hz: float, start_heading_deg: float = 20.0,
                         rate_deg_s: float = 90.0, hold_s: float = 3.0,
                         first_hold_s: float = 5.0) -> Trajectory:
    """The procedure's ground-truth motion in NED at ``rate_hz`` (see :func:`procedure_steps`)."""
    steps, _ = procedure_steps(start_heading_deg, rate_deg_s, hold_s, first_hold_s)
    q0 = qt.from_axis_angle(_DOWN, np.radians(start_heading_deg))
    return rotation_sequence(steps, rate_hz, q0=q0)


def simulate_procedure(
    gyr_errors: SensorErrors | None = None,
    acc_errors: SensorErrors | None = None,
    mag_errors: SensorErrors | None = None,
    rate_hz: float = 100.0,
    seed: int = 0,
    dip_deg: float = DEFAULT_DIP_DEG,
    field_ut: float = DEFAULT_FIELD_UT,
    start_heading_deg: float = 20.0,
    rate_deg_s: float = 90.0,
    hold_s: float = 3.0,
    first_hold_s: float = 5.0,
) -> Recording:
    """A Recording (NED truth) of the 18-step procedure seen by a sensor with the given errors.

    ``meta["procedure"]`` lists ``[paper step, label, t_start_s, t_end_s]`` per motion.
    """
    steps, labels = procedure_steps(start_heading_deg, rate_deg_s, hold_s, first_hold_s)
    trajectory = procedure_trajectory(rate_hz, start_heading_deg, rate_deg_s, hold_s,
                                      first_hold_s)
    rec = simulate(trajectory, frame="NED", dip_deg=dip_deg, field_ut=field_ut,
                   gyr_errors=gyr_errors, acc_errors=acc_errors, mag_errors=mag_errors,
                   seed=seed, name="sim-calibration-procedure")
    bounds = np.concatenate([[0.0], np.cumsum([s.duration_s for s in steps])])
    timeline = [[step, label, float(bounds[k]), float(bounds[k + 1])]
                for k, (step, label) in enumerate(labels)]
    return dataclasses.replace(rec, meta={**rec.meta, "procedure": timeline})
