"""Simulated body-worn sensors for the body-workflow tests (one walking person, lower body)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from margtrack import quaternion as quat
from margtrack.live.simulator import PeopleSimulation
from margtrack.recording import Recording

RATE_HZ = 100.0


def simulation(still_s: float = 2.0, seed: int = 3) -> PeopleSimulation:
    """A walk in place (lower body, 7 sensors, 100 Hz), standing still facing north first."""
    return PeopleSimulation(preset="lower", motion="walk", rate_hz=RATE_HZ, still_s=still_s,
                            seed=seed)


def recordings(sim: PeopleSimulation, n: int = 800) -> dict[str, Recording]:
    """One Recording per sensor, named by segment, on the simulation's common clock."""
    t, gyr, acc, mag = sim.signals(0, n)
    return {name: Recording(t=t, gyr=gyr[s], acc=acc[s], mag=mag[s], name=name)
            for s, name in enumerate(sim.skeleton.names)}


def truth_deg(sim: PeopleSimulation, t_s: np.ndarray) -> dict[str, np.ndarray]:
    """The commanded clinical joint angles (N, 3) deg at ``t_s``, by joint name."""
    angles, _, _ = sim.joint_angles_deg(t_s)
    return {k: v[0] for k, v in angles.items()}


def pelvis_forward_axis(sim: PeopleSimulation) -> np.ndarray:
    """The pelvis sensor's axis (its own frame) that points forward out of the body.

    ``q_sensor = q_segment ⊗ q_offset*``, so a segment vector ``v`` is ``rotate(q_offset, v)``
    in the sensor's frame; forward is ENU ``y`` in the reference pose.
    """
    return quat.rotate(sim.mounting[0, sim.skeleton.names.index("pelvis")], [0.0, 1.0, 0.0])


def without_samples(rec: Recording, start_s: float, end_s: float) -> Recording:
    """``rec`` with the samples in ``[start_s, end_s)`` removed (a gap, as dropped packets)."""
    keep = (rec.t < start_s) | (rec.t >= end_s)
    return replace(rec, t=rec.t[keep], gyr=rec.gyr[keep], acc=rec.acc[keep],
                   mag=None if rec.mag is None else rec.mag[keep])
