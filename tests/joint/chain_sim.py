"""A simulated two-segment chain: two rigid bodies joined at a point, with exact kinematics.

The parent turns smoothly (a rotation vector of sines under a slow heading turn), the child
turns relative to it (a rotation vector of sines: a 3-DOF joint, or one axis: a hinge), the
joint centre moves (sines, analytic acceleration). Body rates come from central differences
of the orientations on a 1 kHz grid (their error is far below the sensor noise), each
sensor's specific force from the joint centre's acceleration and the rigid-body terms:
``p̈_i = p̈_J + R_i (ω̇_i × r_i + ω_i × (ω_i × r_i))``, ``f_i = R_iᵀ (p̈_i + g ẑ)`` (ENU).
Samples are instantaneous (margtrack.joint's ``gyr_timing="instant"``), then seeded white
noise and constant gyroscope biases are added.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from margtrack import quaternion as qt
from margtrack.recording import Recording

G = 9.81


@dataclass(frozen=True)
class Chain:
    parent: Recording
    child: Recording
    q_parent: np.ndarray  # (N, 4) true orientations, ENU
    q_child: np.ndarray
    lever_arms_m: np.ndarray  # (2, 3) joint centre to sensor, sensor frames

    @property
    def q_rel(self) -> np.ndarray:
        return qt.multiply(qt.conjugate(self.q_parent), self.q_child)


def _sines(rng: np.random.Generator, t: np.ndarray, amp: float, fmax: float,
           k: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) sum of k sines per axis, with its second derivative."""
    freq = rng.uniform(0.1, fmax, (3, k))
    phase = rng.uniform(0, 2 * np.pi, (3, k))
    a = rng.uniform(0.3, 1.0, (3, k)) * amp / k
    arg = 2 * np.pi * freq[None] * t[:, None, None] + phase[None]
    w = 2 * np.pi * freq[None]
    return np.sum(a * np.sin(arg), -1), -np.sum(a * w**2 * np.sin(arg), -1)


def _body_rates(q: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Body rate and its derivative from central differences of q on a grid of step h."""
    dq = np.gradient(q, h, axis=0, edge_order=2)
    w = 2.0 * qt.multiply(qt.conjugate(q), dq)[:, 1:]
    return w, np.gradient(w, h, axis=0, edge_order=2)


def simulate_chain(
    duration_s: float = 60.0,
    rate_hz: float = 100.0,
    seed: int = 0,
    lever_arms_m: tuple = ((0.02, -0.03, 0.18), (-0.01, 0.04, -0.15)),
    hinge: bool = False,
    gyr_noise_rad_s: float = 0.005,
    acc_noise_m_s2: float = 0.05,
    gyr_bias_rad_s: tuple = ((0.004, -0.006, 0.008), (-0.005, 0.008, -0.006)),
    joint_motion_m: float = 0.15,
) -> Chain:
    rng = np.random.default_rng([seed, 39])
    fine = 10
    h = 1.0 / (rate_hz * fine)
    n_fine = round(duration_s * rate_hz) * fine + 1
    t = np.arange(n_fine) * h
    theta1, _ = _sines(rng, t, 1.2, 0.8)
    heading = np.zeros((n_fine, 3))
    heading[:, 2] = 0.4 * t + 0.8 * np.sin(2 * np.pi * 0.05 * t)
    q1 = qt.multiply(qt.from_rotvec(heading), qt.from_rotvec(theta1))
    rel, _ = _sines(rng, t, 1.4, 1.0)
    if hinge:
        rel[:, 0] = rel[:, 2] = 0.0
    q2 = qt.multiply(q1, qt.from_rotvec(rel))
    _, acc_j = _sines(rng, t, joint_motion_m, 1.5)
    r = np.asarray(lever_arms_m, dtype=float)
    recs, truth = [], []
    for s, q in enumerate((q1, q2)):
        q = qt.continuous(q)
        w, wd = _body_rates(q, h)
        lin = acc_j + qt.rotate(q, np.cross(wd, r[s]) + np.cross(w, np.cross(w, r[s])))
        f = qt.rotate_inverse(q, lin + np.array([0.0, 0.0, G]))
        keep = slice(0, None, fine)
        gyr = w[keep] + np.asarray(gyr_bias_rad_s[s]) + gyr_noise_rad_s * rng.standard_normal(
            w[keep].shape)
        acc = f[keep] + acc_noise_m_s2 * rng.standard_normal(f[keep].shape)
        recs.append(Recording(t=t[keep], gyr=gyr, acc=acc, name=("parent", "child")[s]))
        truth.append(q[keep])
    return Chain(recs[0], recs[1], truth[0], truth[1], r)


def angle_deg(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Angle between two orientation series, deg."""
    e = qt.multiply(qt.conjugate(ref), q)
    return np.degrees(2 * np.arccos(np.clip(np.abs(e[:, 0]), 0, 1)))


def heading_deg(q: np.ndarray, ref: np.ndarray, q_parent: np.ndarray) -> np.ndarray:
    """Error of a relative orientation about the vertical, deg: the earth-frame rotation
    ``R_parent (q ref*) R_parentᵀ`` split into heading ``2 atan(|e_z / e_w|)``."""
    e = qt.multiply(q_parent, qt.multiply(qt.multiply(q, qt.conjugate(ref)),
                                          qt.conjugate(q_parent)))
    return np.degrees(2 * np.arctan(np.abs(e[:, 3] / e[:, 0])))
