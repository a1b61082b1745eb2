"""One published pose of the live engine: every sensor's orientation and the body models'.

Quaternions [w, x, y, z], Hamilton, sensor (or segment) to earth, in the engine's earth
frame; positions in m; times on the session clock (s, 0 at the session's first frame) and
arrival/publishing times on the :func:`time.perf_counter` clock.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from margtrack.live.avatars import Avatars

Array = NDArray[np.float64]

__all__ = ["Pose"]


@dataclass(frozen=True, eq=False)
class Pose:
    """One published pose.

    index : frame number since the engine started (0-based); t_s : its sample time, s.
    q_sensor : (S, 4) sensor to earth. q_segment (A, K, 4), joints_m / ends_m (A, K, 3) m:
    the body models' segments and joints, or None without a body model.
    arrival_s / published_s : perf_counter times of the frame's arrival and of publishing.
    root_m : (A, 3) m, the roots moved by the feet's contacts
        (:class:`~margtrack.live.walking_root.WalkingRoot`; joints_m and ends_m follow), or
        None while the roots stay at the avatars' places.
    """

    index: int
    t_s: float
    q_sensor: Array
    q_segment: Array | None
    joints_m: Array | None
    ends_m: Array | None
    arrival_s: float
    published_s: float
    root_m: Array | None = None

    @classmethod
    def of(cls, index: int, t_s: float, arrival_s: float, q_sensor: Array,
           avatars: Avatars | None, offsets: Array | None) -> Pose:
        """The pose of frame ``index`` from the sensors' ``q_sensor`` (S, 4) (copied): every
        person's segments and joints at once (:meth:`Avatars.pose`, 000 eqs. 7, 11) if there
        is a body model; ``published_s`` NaN until published."""
        q_segment = joints = ends = None
        if avatars is not None and offsets is not None:  # copied while it is checked
            q_copy = np.empty(np.shape(q_sensor))
            q_segment, joints, ends = avatars.pose(q_sensor, offsets, q_copy=q_copy)
            q_sensor = q_copy
        else:
            q_sensor = np.array(q_sensor, dtype=np.float64)
        return cls(index, float(t_s), q_sensor, q_segment, joints, ends,
                   float(arrival_s), math.nan)

    def walked(self, root_m: Array, start_m: Array) -> Pose:
        """This pose with every person's root at ``root_m`` (A, 3) m instead of ``start_m``
        (A, 3) m: joints and ends shifted with it."""
        if self.joints_m is None or self.ends_m is None:
            return self
        shift = (np.asarray(root_m) - np.asarray(start_m))[:, None, :]
        return dataclasses.replace(self, joints_m=self.joints_m + shift,
                                   ends_m=self.ends_m + shift, root_m=np.array(root_m))

    @property
    def latency_s(self) -> float:
        """End-to-end latency of this pose, s."""
        return self.published_s - self.arrival_s
