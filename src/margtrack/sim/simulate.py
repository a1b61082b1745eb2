"""Turn a ground-truth :class:`Trajectory` into a MARG :class:`Recording`, deterministically.

Measurement model (one convention, the library's: ``q`` body-to-earth)::

    gyr = gyr_errors(body_rate(trajectory))                                    rad/s, body
    acc = acc_errors(rotate_inverse(q, acc_lin + gravity_reference(frame, g)))  m/s², body
    mag = mag_errors(rotate_inverse(q, mag_reference(frame, dip, F) + Σ d(t)) + Σ b(t))  µT, body

where ``d(t)`` are the earth-frame magnetic disturbances (fixed in the room) and ``b(t)``
the body-frame ones (carried by the sensor: :class:`~margtrack.sim.dipole.AttachedDipole`).
Noise comes from ``numpy.random.default_rng(seed)``, drawn in a fixed order: gyr, acc,
mag (two (N, 3) blocks each, see :meth:`SensorErrors.apply`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from margtrack import quaternion as qt
from margtrack.frames import STANDARD_GRAVITY_M_S2, check_frame, gravity_reference, mag_reference
from margtrack.recording import Recording
from margtrack.sim._validate import check_seed as _check_seed
from margtrack.sim.disturbances import BodyMagDisturbance, MagDisturbance
from margtrack.sim.sensor_model import SensorErrors
from margtrack.sim.trajectories import (
    Trajectory,
    body_rate,
    constant_rotation,
    limb_swing,
    random_motion,
    static,
)

__all__ = [
    "DEFAULT_DIP_DEG",
    "DEFAULT_FIELD_UT",
    "MOTIONS",
    "simulate",
    "simulate_default",
    "simulate_motion",
]

#: Default magnetic dip (inclination), deg, and field strength, µT: round values near the
#: World Magnetic Model at Monterey, California, where 000-002's experiments were run
#: (inclination about 61 deg, total intensity about 48 µT).
DEFAULT_DIP_DEG = 60.0
DEFAULT_FIELD_UT = 50.0


def _describe(disturbance: MagDisturbance | BodyMagDisturbance) -> dict[str, Any]:
    if dataclasses.is_dataclass(disturbance) and not isinstance(disturbance, type):
        return {"type": type(disturbance).__name__, **dataclasses.asdict(disturbance)}
    return {"type": type(disturbance).__name__, "repr": repr(disturbance)}


def simulate(
    trajectory: Trajectory,
    frame: str = "ENU",
    dip_deg: float = DEFAULT_DIP_DEG,
    field_ut: float = DEFAULT_FIELD_UT,
    gyr_errors: SensorErrors | None = None,
    acc_errors: SensorErrors | None = None,
    mag_errors: SensorErrors | None = None,
    mag_disturbances: Sequence[MagDisturbance | BodyMagDisturbance] = (),
    gravity_m_s2: float = STANDARD_GRAVITY_M_S2,
    seed: int = 0,
    with_mag: bool = True,
    name: str = "sim",
) -> Recording:
    """Simulated MARG recording of ``trajectory`` with ground truth (model in the module docstring).

    Parameters
    ----------
    trajectory : the motion; its ``quat`` becomes ``quat_true`` (body-to-earth in ``frame``),
        its ``acc_lin_m_s2`` is taken in ``frame``. A trajectory built for another frame
        (``trajectory.meta["frame"]``, e.g. :func:`limb_swing`) is refused.
    frame : earth frame, "ENU" or "NED".
    dip_deg, field_ut : magnetic inclination (deg, positive down) and strength (µT) of
        the reference field, :func:`margtrack.frames.mag_reference`.
    gyr_errors, acc_errors, mag_errors : error models; ``None`` is a perfect sensor. The
        noise rate is the trajectory's median sample rate.
    mag_disturbances : additive fields: earth-frame ones (``earth_field_ut``,
        :mod:`margtrack.sim.disturbances`) and body-frame ones (``body_field_ut``, a magnet
        carried by the sensor: :mod:`margtrack.sim.dipole`).
    gravity_m_s2 : gravity magnitude, m/s².
    seed : integer >= 0 for ``numpy.random.default_rng``.
    with_mag : False leaves ``mag`` as None (its noise is still drawn last, so gyr and
        acc do not change).
    name : the recording's name.

    Returns
    -------
    Recording with ``t``, ``gyr``, ``acc``, ``mag``, ``quat_true``, ``movement`` (all True),
    ``frame`` and ``meta`` holding the seed, every parameter and the trajectory's meta.
    """
    frame = check_frame(frame)
    built_for = trajectory.meta.get("frame")
    if built_for is not None and check_frame(built_for) != frame:
        raise ValueError(
            f"frame is {frame!r} but the trajectory {trajectory.name!r} was built for "
            f"{built_for!r}; build it with frame={frame!r}"
        )
    seed = _check_seed(seed)
    given = {"gyr_errors": gyr_errors, "acc_errors": acc_errors, "mag_errors": mag_errors}
    errors = {key: SensorErrors.none() if e is None else e for key, e in given.items()}
    q = trajectory.quat
    t = trajectory.t
    rate_hz = trajectory.rate_hz
    mag_ref = mag_reference(frame, dip_deg, field_ut)
    g_ref = gravity_reference(frame, gravity_m_s2)
    disturbances = tuple(mag_disturbances)
    field_earth = np.broadcast_to(mag_ref, (t.shape[0], 3)).copy()
    field_body = np.zeros((t.shape[0], 3))
    for disturbance in disturbances:
        if isinstance(disturbance, BodyMagDisturbance):
            field_body += disturbance.body_field_ut(t)
        else:
            field_earth += disturbance.earth_field_ut(t, mag_ref, frame)

    rng = np.random.default_rng(seed)
    gyr = errors["gyr_errors"].apply(body_rate(trajectory), rate_hz, rng)
    acc_true = qt.rotate_inverse(q, trajectory.acc_lin_m_s2 + g_ref)
    acc = errors["acc_errors"].apply(acc_true, rate_hz, rng)
    mag_true = qt.rotate_inverse(q, field_earth) + field_body
    mag = errors["mag_errors"].apply(mag_true, rate_hz, rng)

    meta: dict[str, Any] = {
        "source": "margtrack.sim.simulate",
        "seed": seed,
        "frame": frame,
        "dip_deg": float(dip_deg),
        "field_ut": float(field_ut),
        "gravity_m_s2": float(gravity_m_s2),
        "with_mag": bool(with_mag),
        **{key: dataclasses.asdict(value) for key, value in errors.items()},
        "mag_disturbances": [_describe(d) for d in disturbances],
        "trajectory": {"name": trajectory.name, **trajectory.meta},
    }
    return Recording(
        t=t.copy(),
        gyr=gyr,
        acc=acc,
        mag=mag if with_mag else None,
        quat_true=q.copy(),
        movement=np.ones(t.shape[0], dtype=bool),
        frame=frame,
        name=name,
        meta=meta,
    )


def simulate_default(
    duration_s: float = 60.0,
    rate_hz: float = 100.0,
    seed: int = 0,
    frame: str = "ENU",
    noise: bool = True,
) -> Recording:
    """A ready-made demo recording: :func:`random_motion` seen by a consumer MEMS MARG sensor.

    The motion is ``random_motion(duration_s, rate_hz, seed, max_rate_deg_s=200,
    bandwidth_hz=2, translation_m=0.02)`` (linear acceleration peaks of 0.5-1.5 m/s²); with
    ``noise`` the sensors have :meth:`SensorErrors.mems_gyr`, ``mems_acc`` and ``mems_mag``
    errors, otherwise none. Dip and field are the defaults of :func:`simulate`. Used by the
    README's quick demo and ``margtrack simulate``; the 100 Hz default is only this demo's.
    """
    return simulate_motion(
        "random", duration_s=duration_s, rate_hz=rate_hz, seed=seed, frame=frame, noise=noise
    )


def _mems_errors(noise: bool) -> dict[str, SensorErrors | None]:
    """The consumer-MEMS error presets for gyr, acc and mag, or perfect sensors."""
    if not noise:
        return {"gyr_errors": None, "acc_errors": None, "mag_errors": None}
    return {
        "gyr_errors": SensorErrors.mems_gyr(),
        "acc_errors": SensorErrors.mems_acc(),
        "mag_errors": SensorErrors.mems_mag(),
    }


#: Motions :func:`simulate_motion` knows, by name.
MOTIONS = ("random", "limb", "static", "tilt")


def simulate_motion(
    motion: str = "random",
    *,
    duration_s: float = 60.0,
    rate_hz: float = 100.0,
    seed: int = 0,
    frame: str = "ENU",
    noise: bool = True,
    with_mag: bool = True,
) -> Recording:
    """A named demo motion seen by a consumer MEMS MARG sensor (or a perfect one).

    ``motion``: "random" (:func:`simulate_default`'s random motion), "limb" (a 1 Hz, 30 deg
    limb swing), "static" (at rest, level), "tilt" (a tilt table turning about the
    earth's x axis at 10 deg/s). Used by ``margtrack simulate`` and ``margtrack demo``.
    """
    if motion not in MOTIONS:
        raise ValueError(f"motion must be one of {', '.join(MOTIONS)}, got {motion!r}")
    if motion == "random":
        trajectory = random_motion(
            duration_s, rate_hz, seed, max_rate_deg_s=200.0, bandwidth_hz=2.0, translation_m=0.02
        )
    elif motion == "limb":
        trajectory = limb_swing(duration_s, rate_hz, frame=frame)
    elif motion == "static":
        trajectory = static(duration_s, rate_hz)
    else:
        trajectory = constant_rotation((1.0, 0.0, 0.0), 10.0, duration_s, rate_hz)
    return simulate(
        trajectory,
        frame=frame,
        **_mems_errors(noise),
        seed=seed,
        with_mag=with_mag,
        name=f"sim-{motion}-{seed}",
    )
