"""Live segment orientations without magnetometers: the joint constraint down every chain.

With ``no_mag`` (``margtrack live --no-mag``) the engine runs every sensor's filter without
its magnetometer (6-D) and :class:`JointChain` replaces the orientation of every sensor but
each person's root (pelvis) by its parent's times the relative orientation across the joint
between them, parents first (as ``margtrack body --no-mag`` does offline,
:mod:`margtrack.body.chain`)::

    q_child[k] = q_parent[k] ⊗ rel[k],    rel = conj(q_parent_sensor) ⊗ q_child_sensor

with ``rel`` from the online joint filter fed sample by sample from both sensors' rates
and specific forces (:class:`~margtrack.live.joint_stream.JointStream`: two samples behind,
the newest two predicted by the gyroscopes; lever arms given or estimated once after a
few seconds of motion and then frozen). So every segment's heading follows its parent's
instead of drifting on its own gyroscope, and the joint angles do not drift.

Faults stay with their joint: a sensor missing from a frame (held) or stale makes its
joints' samples unmeasured (the filter predicts by the gyroscopes; a stale sensor's rate is
zero, so its segment holds its orientation), a restart of either sensor restarts the joint
filter (both levelled again, the relative heading searched again); segments below follow
through the chain. :meth:`JointChain.describe` counts per joint the samples that
had no usable measurement (``unmeasured_samples`` of :meth:`JointChain.describe`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack.body.chain import joint_name
from margtrack.joint.lever_arms import LeverArms
from margtrack.joint.params import JointParams
from margtrack.live.assembler import Frames
from margtrack.live.avatars import Avatars
from margtrack.live.joint_stream import BUFFER_S, JointStream

Array = NDArray[np.float64]

__all__ = ["JointChain", "RecentFrames", "lever_arms_from_json", "lever_arms_to_json",
           "read_chain_lever_arms"]


def read_chain_lever_arms(path: str | Path) -> dict[str, LeverArms]:
    """Lever arms of named joints from a JSON file (m, joint centre to sensor, sensor frames)::

        {"left_knee": {"parent_m": [0.0, -0.2, 0.0], "child_m": [0.0, 0.18, 0.0]}, ...}

    Joint names are those of the summary (``left_knee``, ``pelvis-trunk``); a joint not in
    the file has its lever arms estimated.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such lever-arms file: {p}")
    example = ('{"left_knee": {"parent_m": [0.0, -0.2, 0.0], "child_m": [0.0, 0.18, 0.0]}} '
               "(m, joint centre to sensor, each sensor's frame)")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
        if not isinstance(data, dict):
            raise TypeError("the file holds no JSON object")
        return {str(name): LeverArms.given([v["parent_m"], v["child_m"]])
                for name, v in data.items()}
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{p}: expected JSON like {example}: {exc}") from None


def lever_arms_to_json(arms: Mapping[str, LeverArms]) -> dict[str, Any]:
    """Joint name -> lever arms as JSON-ready values (floats round-trip exactly; a given
    arm's NaN std as None): ``parent_m``, ``child_m``, ``std_m``, ``source``."""
    return {name: {"parent_m": a.r_m[0].tolist(), "child_m": a.r_m[1].tolist(),
                   "std_m": [[None if np.isnan(v) else float(v) for v in row]
                             for row in a.std_m],
                   "source": a.source} for name, a in arms.items()}


def lever_arms_from_json(data: Mapping[str, Any]) -> dict[str, LeverArms]:
    """The inverse of :func:`lever_arms_to_json` (the source kept: an estimated arm stays
    estimated, so its joint counts as settled as it did in the session)."""
    out = {}
    for name, v in data.items():
        given = LeverArms.given([v["parent_m"], v["child_m"]])
        std = np.array([[np.nan if x is None else x for x in row] for row in v["std_m"]],
                       dtype=np.float64)
        out[str(name)] = LeverArms(given.r_m, std, str(v["source"]))
    return out


def _product(p: Array, q: Array) -> Array:
    """``normalize(p ⊗ q)`` for (N, 4) unit quaternions, without the checks of
    :func:`margtrack.quaternion.multiply` (the inputs are the filters' own)."""
    pw, px, py, pz = p.T
    qw, qx, qy, qz = q.T
    out = np.empty_like(p)
    out[:, 0] = pw * qw - px * qx - py * qy - pz * qz
    out[:, 1] = pw * qx + px * qw + py * qz - pz * qy
    out[:, 2] = pw * qy - px * qz + py * qw + pz * qx
    out[:, 3] = pw * qz + px * qy - py * qx + pz * qw
    out /= np.sqrt(np.einsum("ij,ij->i", out, out))[:, None]
    return out


class JointChain:
    """Chained orientations of every person of ``avatars`` (module docstring).

    Parameters
    ----------
    avatars : the body models (their skeleton's order is parents first).
    rate_hz : the source's nominal rate, Hz.
    lever_arms : joint name -> given lever arms (:func:`read_chain_lever_arms`); the
        others are estimated. For several people, one name serves every person's joint.
    params : the joint filter's parameters.
    """

    def __init__(self, avatars: Avatars, rate_hz: float,
                 lever_arms: Mapping[str, LeverArms] | None = None,
                 params: JointParams | None = None) -> None:
        sk = avatars.skeleton
        given = dict(lever_arms or {})
        self.avatars = avatars
        names = [joint_name(sk, k) for k in range(1, len(sk))]
        unknown = sorted(set(given) - set(names))
        if unknown:
            raise ValueError(f"lever arms given for {', '.join(unknown)}, which the body model "
                             f"has no joint of; its joints: {', '.join(names)}")
        #: per joint (person-major, parents first): (person, name, parent sensor, child sensor)
        self.joints: list[tuple[int, str, int, int]] = []
        self._streams: list[JointStream] = []
        for a in range(avatars.n_people):
            for k in range(1, len(sk)):
                name = names[k - 1]
                parent = int(avatars.index[a, sk.parents[k]])
                child = int(avatars.index[a, k])
                self.joints.append((a, name, parent, child))
                self._streams.append(JointStream(rate_hz, given.get(name), params))
        n = int(avatars.index.max()) + 1
        self.q_last = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))

    @property
    def settled(self) -> bool:
        """Every joint's lever arms in force and its relative heading found."""
        return all(s.settled for s in self._streams)

    def run(self, frames: Frames, q: Array) -> Array:
        """Orientations (S, N, 4) of a batch: the roots' from ``q`` (the 6-D filters'), every
        other sensor chained to its parent's (module docstring); ``q`` is not changed."""
        out = np.array(q, dtype=np.float64)
        held = frames.held
        if frames.stale is not None:
            held = held | frames.stale
        for (_, _, p, c), stream in zip(self.joints, self._streams, strict=True):
            pair = [p, c]
            restart = (np.zeros(frames.n_frames, dtype=bool) if frames.restart is None
                       else frames.restart[pair].any(axis=0))
            rel, _ = stream.step(frames.t_s, frames.gyr[pair], frames.acc[pair],
                                 held[pair].any(axis=0), restart)
            out[c] = _product(out[p], rel)
        self.q_last = np.ascontiguousarray(out[:, -1])
        return out

    def smoothed(self, t_s: Array, q: Array) -> Array:
        """Orientations (S, M, 4) at the recent frames ``t_s`` (M,) s: the roots' from ``q``
        (S, M, 4) (their 6-D filters' at those frames), every other sensor chained through its
        joint's backward-smoothed relative orientation (:meth:`JointStream.smoothed`), so a
        still pose before the joints moved is seen with the relative headings found since."""
        out = np.array(q, dtype=np.float64)
        for (_, _, p, c), stream in zip(self.joints, self._streams, strict=True):
            out[c] = _product(out[p], stream.smoothed(t_s))
        return out

    def lever_arms_in_force(self) -> dict[str, LeverArms]:
        """Joint name -> the lever arms in force, for the joints whose arms are in force and
        the same for every person (given ones; one person's estimated ones)."""
        by_name: dict[str, list[LeverArms | None]] = {}
        for (_, name, _, _), s in zip(self.joints, self._streams, strict=True):
            by_name.setdefault(name, []).append(s.lever_arms)
        return {name: arms[0] for name, arms in by_name.items()
                if arms[0] is not None and all(
                    a is not None and np.array_equal(a.r_m, arms[0].r_m) for a in arms)}

    def describe(self) -> list[dict[str, Any]]:
        """Per joint: person, name, sensors, lever arms (m, with std) and their state."""
        rows = []
        for (a, name, p, c), s in zip(self.joints, self._streams, strict=True):
            arms = s.lever_arms
            if arms is None:
                state = (f"estimating lever arms ({s.motion_s:.1f} of {s.fit_motion_s:g} s "
                         "of motion)" + (f"; last try: {s.fit_error}" if s.fit_error else ""))
            else:
                state = "settled" if s.settled else "finding the relative heading (move)"
            rows.append({
                "person": self.avatars.people[a], "joint": name,
                "parent_sensor": p, "child_sensor": c, "state": state,
                "lever_arms_m": None if arms is None else np.round(arms.r_m, 3).tolist(),
                "lever_arms_std_m": None if arms is None else [
                    [None if np.isnan(v) else round(float(v), 3) for v in row]
                    for row in arms.std_m],
                "lever_arms_source": None if arms is None else arms.source,
                "unmeasured_samples": s.unmeasured,
            })
        return rows


class RecentFrames:
    """The engine's frames while a calibration waits for the joints to settle.

    A calibration on the chained orientations needs every joint's relative heading, which
    the online filter finds only once the joint moves. While a request is pending and the
    chain has not settled, the roots' 6-D orientations of the last
    :data:`~margtrack.live.joint_stream.BUFFER_S` are kept here; once it settles they are
    chained with the joints' backward-smoothed relative orientations
    (:meth:`JointChain.smoothed`) and given to the request at once, so the still second
    at the start of a session (before the first steps) still serves as the reference pose.
    """

    def __init__(self, calibrations: Any) -> None:
        self._body = calibrations
        self._t: list[Array] = []
        self._q: list[Array] = []

    def feed(self, chain: JointChain, request: Any, t_s: Array, q6: Array) -> Any:
        """The request to feed this batch's chained frames to (None: not now)."""
        if request is None:
            self._t, self._q = [], []
            return None
        if not chain.settled:
            self._t.append(np.array(t_s))
            self._q.append(np.array(q6))
            while len(self._t) > 1 and self._t[-1][-1] - self._t[0][0] > BUFFER_S:
                self._t.pop(0)
                self._q.pop(0)
            return None
        if self._t:
            t = np.concatenate(self._t)
            q = chain.smoothed(t, np.concatenate(self._q, axis=1))
            self._t, self._q = [], []
            self._body.feed(request, t, np.swapaxes(q, 0, 1))
            return self._body.pending
        return request
