"""Synthetic MARG data with ground truth, deterministic under a seed.

- :mod:`~margtrack.sim.trajectories`: motions (orientation, position, linear acceleration)
  and the true gyro signal :func:`body_rate`;
- :mod:`~margtrack.sim.sensor_model`: :class:`SensorErrors`, one triad's error model;
- :mod:`~margtrack.sim.disturbances`: earth-frame magnetic disturbances;
- :mod:`~margtrack.sim.dipole`: a magnet carried by the sensor (body-frame field);
- :mod:`~margtrack.sim.simulate`: :func:`simulate` and :func:`simulate_default`, which
  return a :class:`margtrack.recording.Recording`.

Example: 000's roll excursions seen by a noisy sensor in NED::

    from margtrack import sim
    roll = (1, 0, 0)
    steps = [sim.Rotate(roll, 45, 10), sim.Hold(15), sim.Rotate(roll, -45, 10), sim.Hold(15)]
    rec = sim.simulate(sim.rotation_sequence(steps, rate_hz=100), frame="NED",
                       gyr_errors=sim.SensorErrors.mems_gyr(), seed=1)
"""

from margtrack.sim.dipole import AttachedDipole, attached_dipole, dipole_field_ut
from margtrack.sim.disturbances import (
    BodyMagDisturbance,
    MagDisturbance,
    MagnetPass,
    RotatingField,
    VerticalTilt,
    magnet_pass,
    rotating_field,
    vertical_tilt,
)
from margtrack.sim.sensor_model import SensorErrors
from margtrack.sim.simulate import (
    DEFAULT_DIP_DEG,
    DEFAULT_FIELD_UT,
    MOTIONS,
    simulate,
    simulate_default,
    simulate_motion,
)
from margtrack.sim.trajectories import (
    Hold,
    Rotate,
    Trajectory,
    body_rate,
    constant_rotation,
    limb_swing,
    random_motion,
    rotation_sequence,
    static,
)

__all__ = [
    "DEFAULT_DIP_DEG",
    "DEFAULT_FIELD_UT",
    "MOTIONS",
    "AttachedDipole",
    "BodyMagDisturbance",
    "Hold",
    "MagDisturbance",
    "MagnetPass",
    "Rotate",
    "RotatingField",
    "SensorErrors",
    "Trajectory",
    "VerticalTilt",
    "attached_dipole",
    "body_rate",
    "constant_rotation",
    "dipole_field_ut",
    "limb_swing",
    "magnet_pass",
    "random_motion",
    "rotating_field",
    "rotation_sequence",
    "simulate",
    "simulate_default",
    "simulate_motion",
    "static",
    "vertical_tilt",
]
