"""Simulated people wearing MARG sensors: the body model driven by smooth joint angles.

Motion (per person, angles in degrees, ``φ = 2π f t + φ0``, every angle scaled by a smooth
start ``b(t)`` rising from 0 to 1 over ``ramp_s`` after ``still_s`` seconds of standing still
in the reference pose facing north, so "calibrate now" finds a still second at the start):

- ``"walk"``: walking in place on a slowly turning spot (heading rate ``turn_deg_s``):
  hip flexion ``5 + 25 sin φ``, knee flexion ``32 + 27 sin(φ - 0.9)``, ankle
  dorsiflexion ``-2 + 8 sin(φ + 0.3)``, arms swinging against the legs (shoulder flexion
  ``-20 sin φ``, elbow flexion ``20 + 12 sin φ``), right side half a cycle later, pelvis
  sway, trunk counter-rotation, head nod, vertical and lateral bounce of the pelvis;
- ``"wave"``: standing and waving the right arm (shoulder abduction ``50 + 25 sin``, elbow
  flexion ``70 + 40 sin``), the left arm swinging slowly, weight shifts, head turns.

Joint angles are the clinical angles of :mod:`margtrack.body.joints` (so
:func:`margtrack.body.joint_angles` of the simulated segments returns them); segment
orientations follow by the chain ``q_child = q_parent ⊗ q_rel`` from the pelvis, positions
by eq. 11 of 000. Each sensor sits at the middle of its segment, mounted at a random
(seeded) orientation ``q_offset``: ``q_sensor = q_segment ⊗ q_offset*`` (eq. 7 inverted).

Signals follow :mod:`margtrack.sim.simulate`'s measurement model: gyr by
:func:`margtrack.sim.body_rate`'s convention (the rotation from the previous sample over the
interval), ``acc = q* ⊗ (a_lin + g) ⊗ q``, ``mag = q* ⊗ m_ref ⊗ q`` (dip ``dip_deg``,
``field_ut``), plus white noise at the densities of :class:`margtrack.sim.SensorErrors`'
MEMS presets and constant per-sensor biases. The linear acceleration is the central second
difference of the sensor position with a 1 ms step (truncation error ~1e-4 m/s²).
Signals come in blocks of ``block_s`` seconds; block ``k``'s noise is drawn from
``default_rng([seed, k])``, so any stretch is reproducible under a seed.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from margtrack import body
from margtrack import quaternion as quat
from margtrack.body.joints import JOINTS
from margtrack.body.skeleton import PRESETS
from margtrack.frames import check_frame, gravity_reference, mag_reference
from margtrack.live.protocol import BaseSource, Chunk, Pacer, SourceInfo
from margtrack.sim import DEFAULT_DIP_DEG, DEFAULT_FIELD_UT, SensorErrors

Array = NDArray[np.float64]

__all__ = ["MOTIONS", "PeopleSimulation", "SimulatorSource"]

MOTIONS = ("walk", "wave")
_FD_STEP_S = 1e-3
_LEFT_SIGNS = np.array([1.0, -1.0, -1.0])  # body.joints: left-side sign of (α, β, γ)


def _cardan(frame_c: Array, deg: Array) -> Array:
    """``c ⊗ Rx(α) Ry(β) Rz(γ) ⊗ c*`` for angles (..., 3) deg in anatomical axes."""
    a = np.radians(deg)
    ex, ey, ez = np.eye(3)
    q = quat.multiply(quat.multiply(quat.from_axis_angle(ex, a[..., 0]),
                                    quat.from_axis_angle(ey, a[..., 1])),
                      quat.from_axis_angle(ez, a[..., 2]))
    return quat.multiply(quat.multiply(frame_c, q), quat.conjugate(frame_c))


def _ramp(x: Array) -> tuple[Array, Array]:
    """Smoothstep ``3x² - 2x³`` on [0, 1] and its integral (continued linearly past 1)."""
    xc = np.clip(x, 0.0, 1.0)
    integral = np.where(x < 1.0, xc**3 - xc**4 / 2.0, 0.5 + (x - 1.0))
    return 3 * xc**2 - 2 * xc**3, np.where(x > 0, integral, 0.0)


@dataclass(frozen=True)
class PeopleSimulation:
    """People, motion and sensors of a simulation (module docstring).

    n_people : A >= 1; preset : skeleton preset (``full``: 15 sensors each, ``lower``,
    ``left_arm``...); motion : ``"walk"`` or ``"wave"``; height_m : body height, m;
    rate_hz : sample rate, Hz; still_s, ramp_s : still reference pose, then the ramp into
    motion, s; frame : ``"ENU"``/``"NED"``; dip_deg, field_ut : magnetic field; noise :
    False for perfect sensors; spacing_m : distance between people, m; block_s : length
    of a generated block, s; seed : integer >= 0.
    """

    n_people: int = 1
    preset: str = "full"
    motion: str = "walk"
    height_m: float = 1.75
    rate_hz: float = 100.0
    still_s: float = 2.0
    ramp_s: float = 1.0
    frame: str = "ENU"
    dip_deg: float = DEFAULT_DIP_DEG
    field_ut: float = DEFAULT_FIELD_UT
    noise: bool = True
    spacing_m: float = 1.5
    block_s: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        if int(self.n_people) < 1:
            raise ValueError(f"n_people must be >= 1, got {self.n_people}")
        if self.preset not in PRESETS:
            raise ValueError(f"preset must be one of {', '.join(PRESETS)}, got {self.preset!r}")
        if self.motion not in MOTIONS:
            raise ValueError(f"motion must be one of {', '.join(MOTIONS)}, got {self.motion!r}")
        for name in ("rate_hz", "block_s", "ramp_s", "spacing_m"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {getattr(self, name)}")
        if not (math.isfinite(self.still_s) and self.still_s >= 0):
            raise ValueError(f"still_s must be >= 0, got {self.still_s}")
        if int(self.seed) < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed}")
        object.__setattr__(self, "frame", check_frame(self.frame))

    # -- fixed, seeded properties ----------------------------------------------------------
    @cached_property
    def skeleton(self) -> body.Skeleton:
        """The skeleton of every person."""
        return body.Skeleton.from_height(self.height_m, self.preset, self.frame)

    @property
    def sensor_names(self) -> tuple[str, ...]:
        """``segment`` for one person, ``p<a>/segment`` for several (person-major)."""
        names = self.skeleton.names
        if self.n_people == 1:
            return names
        return tuple(f"p{a}/{n}" for a in range(self.n_people) for n in names)

    @cached_property
    def _fixed(self) -> dict[str, Array]:
        rng = np.random.default_rng([self.seed, 0x51D])
        a, k = self.n_people, len(self.skeleton)
        return {
            "phase": rng.uniform(0, 2 * np.pi, (a, 1)) if a > 1 else np.zeros((1, 1)),
            "cadence_hz": rng.uniform(0.8, 1.0, (a, 1)) if a > 1 else np.full((1, 1), 0.9),
            "turn_deg_s": rng.uniform(-20, 20, (a, 1)) if a > 1 else np.full((1, 1), 12.0),
            "offsets": quat.canonical(quat.normalize(rng.normal(size=(a, k, 4)))),
            "gyr_bias": rng.normal(0.0, math.radians(0.2), (a * k, 1, 3)),
            "acc_bias": rng.normal(0.0, 0.05, (a * k, 1, 3)),
            "mag_bias": rng.normal(0.0, 0.5, (a * k, 1, 3)),
        }

    @property
    def mounting(self) -> Array:
        """(A, K, 4) the true ``q_offset`` of every sensor (what calibration should find)."""
        return self._fixed["offsets"]

    def pelvis_forward_axis(self, person: int = 0) -> Array:
        """(3,) the axis of a person's pelvis sensor (its own frame) that points forward out
        of the body: the heading reference of ``heading="pelvis"``. A segment vector ``v`` is
        ``rotate(q_offset, v)`` in the sensor's frame (``q_sensor = q_segment ⊗ q_offset*``)."""
        pelvis = self.skeleton.names.index("pelvis")
        return quat.rotate(self.mounting[person, pelvis], body.body_axes(self.frame)[1])

    @cached_property
    def root_positions_m(self) -> Array:
        """(A, 3) m, each person's root in the reference pose (the grid of the avatars)."""
        right, forward, _ = body.body_axes(self.frame)
        columns = math.ceil(math.sqrt(self.n_people))
        grid = np.array([(a % columns, a // columns) for a in range(self.n_people)], float)
        return self.skeleton.root_position_m + self.spacing_m * (
            grid[:, :1] * right + grid[:, 1:] * forward)

    # -- motion ----------------------------------------------------------------------------
    def joint_angles_deg(self, t_s: Array) -> tuple[dict[str, Array], Array, Array]:
        """Commanded angles (A, N, 3) deg per relation, heading (A, N) rad, bounce (A, N, 3) m.

        Keys: JOINTS as ``<side>_<kind>`` (clinical components), and ``pelvis``, ``trunk``,
        ``head``, ``<side>_hand`` as raw X-Y-Z Cardan angles in anatomical axes.
        """
        f = self._fixed
        t = np.asarray(t_s, dtype=np.float64)[None, :]
        b, b_int = _ramp((t - self.still_s) / self.ramp_s)
        heading = np.radians(f["turn_deg_s"]) * self.ramp_s * b_int
        z = np.zeros_like(t * f["phase"])
        ang: dict[str, Array] = {}
        right, _, upward = body.body_axes(self.frame)
        if self.motion == "walk":
            phi = 2 * np.pi * f["cadence_hz"] * t + f["phase"]
            ang["pelvis"] = np.stack([3 * np.sin(2 * phi), 4 * np.sin(phi), 6 * np.sin(phi)], -1)
            ang["trunk"] = np.stack([z - 5, z, -8 * np.sin(phi)], -1)
            ang["head"] = np.stack([4 * np.sin(2 * phi), z, z], -1)
            for side, p in (("left", phi), ("right", phi + np.pi)):
                ang[f"{side}_hip"] = np.stack([5 + 25 * np.sin(p), 3 * np.sin(p),
                                               2 * np.sin(p)], -1)
                ang[f"{side}_knee"] = np.stack([32 + 27 * np.sin(p - 0.9), z, z], -1)
                ang[f"{side}_ankle"] = np.stack([-2 + 8 * np.sin(p + 0.3), z, z], -1)
                ang[f"{side}_shoulder"] = np.stack([-20 * np.sin(p), z + 8, z], -1)
                ang[f"{side}_elbow"] = np.stack([20 + 12 * np.sin(p), z, z], -1)
                ang[f"{side}_hand"] = np.stack([10 * np.sin(p), z, z], -1)
            bounce = (0.02 * np.sin(2 * phi))[..., None] * upward + (
                0.02 * np.sin(phi))[..., None] * right
        else:
            w = 2 * np.pi * t + f["phase"]
            ang["pelvis"] = np.stack([z, 3 * np.sin(0.3 * w), 4 * np.sin(0.2 * w)], -1)
            ang["trunk"] = np.stack([z, -2 * np.sin(0.3 * w), z], -1)
            ang["head"] = np.stack([z, z, 20 * np.sin(0.3 * w)], -1)
            ang["right_shoulder"] = np.stack([z + 20, 50 + 25 * np.sin(0.6 * w), z], -1)
            ang["right_elbow"] = np.stack([70 + 40 * np.sin(1.5 * w), z, 30 + z], -1)
            ang["left_shoulder"] = np.stack([30 * np.sin(0.4 * w), z + 10, z], -1)
            ang["left_elbow"] = np.stack([z + 30, z, z], -1)
            for side in ("left", "right"):
                sgn = 1.0 if side == "left" else -1.0
                ang[f"{side}_hip"] = np.stack([z, sgn * 3 * np.sin(0.3 * w), z], -1)
                ang[f"{side}_knee"] = np.stack([5 + 5 * np.sin(0.3 * w), z, z], -1)
                ang[f"{side}_ankle"] = np.stack([z, z, z], -1)
                ang[f"{side}_hand"] = np.stack([15 * np.sin(1.5 * w), z, z], -1)
            bounce = (0.01 * np.sin(0.3 * w))[..., None] * right
        return {k: v * b[..., None] for k, v in ang.items()}, heading, bounce * b[..., None]

    def kinematics(self, t_s: Array) -> tuple[Array, Array]:
        """Segment orientations (A, K, N, 4) and sensor positions (A, K, N, 3) m at ``t_s``."""
        ang, heading, bounce = self.joint_angles_deg(t_s)
        right, forward, upward = body.body_axes(self.frame)
        c = quat.from_matrix(np.stack([right, forward, upward], axis=-1))
        kinds = {child: kind for kind, (_, child, _, _) in JOINTS.items()}
        full = body.Skeleton.from_height(self.height_m, "full", self.frame)
        q: dict[str, Array] = {}
        for i, name in enumerate(full.names):  # parents first
            side, _, kind = name.partition("_")
            if name == "pelvis":
                q[name] = quat.multiply(quat.from_axis_angle(upward, heading),
                                        _cardan(c, ang["pelvis"]))
                continue
            parent = full.names[full.parents[i]]
            if kind in kinds:
                joint = kinds[kind]
                signs = np.asarray(JOINTS[joint][3], float) * (_LEFT_SIGNS if side == "left"
                                                                else 1.0)
                rel = _cardan(c, ang[f"{side}_{joint}"] * signs)
            else:
                rel = _cardan(c, ang[name])
            q[name] = quat.multiply(q[parent], rel)
        sk = self.skeleton
        q_seg = np.stack([q[n] for n in sk.names], axis=1)  # (A, K, N, 4)
        a, k, n, _ = q_seg.shape
        root = self.root_positions_m[:, None, :] + bounce  # (A, N, 3)
        flat = np.swapaxes(q_seg, 1, 2).reshape(a * n, k, 4)
        joints, _ = body.positions(sk, flat, root.reshape(a * n, 3))
        mid = joints + quat.rotate(flat, 0.5 * sk.ends_m)
        return q_seg, np.swapaxes(mid.reshape(a, n, k, 3), 1, 2)

    def sensor_truth(self, t_s: Array) -> tuple[Array, Array]:
        """Sensor orientations (S, N, 4) and positions (S, N, 3) m at ``t_s`` (S = A·K)."""
        q_seg, pos = self.kinematics(t_s)
        q = quat.multiply(q_seg, quat.conjugate(self.mounting)[:, :, None, :])
        s = self.n_people * len(self.skeleton)
        return q.reshape(s, -1, 4), pos.reshape(s, -1, 3)

    def signals(self, first: int, count: int, block: int | None = None
                ) -> tuple[Array, Array, Array, Array]:
        """Samples ``first .. first+count-1``: t (N,), gyr, acc, mag (S, N, 3).

        Noise is drawn from ``default_rng([seed, block])`` (``block`` defaults to ``first``).
        """
        dt = 1.0 / self.rate_hz
        t = (first + np.arange(-1, count)) * dt
        q, p = self.sensor_truth(t)
        h = _FD_STEP_S
        _, p_plus = self.sensor_truth(t[1:] + h)
        _, p_minus = self.sensor_truth(t[1:] - h)
        acc_lin = (p_plus - 2 * p[:, 1:] + p_minus) / h**2
        delta = quat.multiply(quat.conjugate(q[:, :-1]), q[:, 1:])
        gyr = quat.to_rotvec(delta) / dt  # sim.body_rate's convention
        gyr[np.all(q[:, 1:] == q[:, :-1], axis=-1)] = 0.0
        q = q[:, 1:]
        acc = quat.rotate_inverse(q, acc_lin + gravity_reference(self.frame))
        mag = quat.rotate_inverse(q, mag_reference(self.frame, self.dip_deg, self.field_ut))
        if self.noise:
            rng = np.random.default_rng([self.seed, first if block is None else block])
            root_rate = math.sqrt(self.rate_hz)
            f = self._fixed
            for x, errors, bias in ((gyr, SensorErrors.mems_gyr(), f["gyr_bias"]),
                                    (acc, SensorErrors.mems_acc(), f["acc_bias"]),
                                    (mag, SensorErrors.mems_mag(), f["mag_bias"])):
                x += bias + rng.standard_normal(x.shape) * errors.noise_density * root_rate
        return t[1:], gyr, acc, mag


class SimulatorSource(BaseSource):
    """A :class:`PeopleSimulation` streamed in real time (or faster), block by block.

    Parameters
    ----------
    simulation : who moves how (default: one walking person, 15 sensors, 100 Hz).
    speed : playback speed factor > 0 (``math.inf``: as fast as polled).
    duration_s : stop after this much simulated time (None: run until closed).
    """

    def __init__(self, simulation: PeopleSimulation | None = None, speed: float = 1.0,
                 duration_s: float | None = None) -> None:
        sim = simulation if simulation is not None else PeopleSimulation()
        n_people = "1 person" if sim.n_people == 1 else f"{sim.n_people} people"
        super().__init__(SourceInfo(sim.sensor_names, sim.rate_hz, True,
                                    f"simulator: {n_people} ({sim.motion}, {sim.preset})"))
        if duration_s is not None and not duration_s > 0:
            raise ValueError(f"duration_s must be > 0 or None, got {duration_s}")
        self.simulation = sim
        self._block_n = max(1, round(sim.block_s * sim.rate_hz))
        self._end = None if duration_s is None else round(duration_s * sim.rate_hz) + 1
        self._pacer = Pacer(0.0, speed)
        self._next = 0  # next sample index to deliver
        self._buffer: tuple[int, tuple[Array, Array, Array, Array]] | None = None

    def open(self) -> None:
        """Start the simulation clock (idempotent)."""
        if not self._opened:
            self._pacer.start()
        super().open()

    def _block(self, k: int) -> tuple[Array, Array, Array, Array]:
        if self._buffer is None or self._buffer[0] != k:
            self._buffer = (k, self.simulation.signals(k * self._block_n, self._block_n, k))
        return self._buffer[1]

    def poll(self, timeout_s: float) -> list[Chunk]:
        """The samples due now (at most to the end of the current block)."""
        if self._finished:
            return []
        if not self._opened:
            self.open()
        dt = 1.0 / self.simulation.rate_hz
        wait = float(self._pacer.due_time(self._next * dt)) - self._pacer.now()
        if wait > timeout_s:
            time.sleep(max(timeout_s, 0.0))
            return []
        if wait > 0:
            time.sleep(wait)
        k, offset = divmod(self._next, self._block_n)
        stop = self._block_n
        if not self._pacer.unpaced:
            due = math.floor(self._pacer.data_time_now() * self.simulation.rate_hz + 1e-9)
            stop = min(stop, max(due - k * self._block_n + 1, offset + 1))
        if self._end is not None:
            stop = min(stop, self._end - k * self._block_n)
        t, gyr, acc, mag = self._block(k)
        sl = slice(offset, stop)
        arrival = (np.full(stop - offset, self._pacer.now()) if self._pacer.unpaced
                   else self._pacer.due_time(t[sl]))
        chunk = Chunk(t[sl], np.arange(self.info.n_sensors, dtype=np.intp), gyr[:, sl],
                      acc[:, sl], mag[:, sl], arrival)
        self._stats.samples += (stop - offset) * self.info.n_sensors
        self._next = k * self._block_n + stop
        if self._end is not None and self._next >= self._end:
            self._finished = True
        return [chunk]
