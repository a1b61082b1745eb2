"""Body models for the people among a source's sensors: sensor names to skeleton segments.

Sensor names select the model: ``"<segment>"`` (one person) or ``"<person>/<segment>"``
(several), with segment names or aliases of :mod:`margtrack.body.skeleton`
(``left_upper_leg`` is ``left_thigh``). Every person must wear one sensor on each segment
of the same preset (``full``: 15, ``lower``: 7, an arm or a leg: 3); otherwise the source
has no body model and the viewer shows the sensors' own frames.

Per frame, for A people of K segments, vectorised over people (000, eqs. 7, 11)::

    q_segment[a, k] = q_sensor[index[a, k]] ⊗ q_offset[a, k]
    joints, ends    = margtrack.body.positions(skeleton, q_segment, root_positions_m)

People stand on a grid ``spacing_m`` apart, facing their own heading reference.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import body
from margtrack import quaternion as quat
from margtrack.body.kinematics import people_pose
from margtrack.body.offsets import Heading
from margtrack.body.skeleton import PRESETS, canonical_name

Array = NDArray[np.float64]

__all__ = ["Avatars", "identity_calibration"]


def identity_calibration(skeleton: body.Skeleton) -> body.Calibration:
    """The calibration before any reference pose: segment orientation = sensor orientation."""
    n = len(skeleton)
    offsets = quat.identity(n)
    q_h = quat.identity()
    spread = np.zeros(n)
    for arr in (offsets, q_h, spread):
        arr.setflags(write=False)
    return body.Calibration(skeleton.names, skeleton.frame, offsets, "north", q_h, 0.0, spread)


def _split(name: str) -> tuple[str, str] | None:
    person, _, segment = str(name).rpartition("/")
    try:
        return person, canonical_name(segment)
    except ValueError:
        return None


@dataclass(frozen=True, eq=False)
class Avatars:
    """A people x segments map onto sensor indices, with one skeleton shared by all.

    Attributes
    ----------
    skeleton : the preset's skeleton (every person has the same proportions).
    people : person labels (``""`` for a single unnamed person).
    index : (A, K) int, sensor index of person ``a``'s segment ``k`` (skeleton order).
    root_positions_m : (A, 3) m, root joint of each person in the reference pose.
    height_m : body height the skeleton was built for, m (sizes the avatar's volume).
    """

    skeleton: body.Skeleton
    people: tuple[str, ...]
    index: NDArray[np.intp]
    root_positions_m: Array
    height_m: float = 1.75

    @property
    def n_people(self) -> int:
        """Number of people A."""
        return len(self.people)

    @classmethod
    def from_names(
        cls,
        sensor_names: Sequence[str],
        height_m: float = 1.75,
        frame: str = "ENU",
        spacing_m: float = 1.5,
    ) -> Avatars | None:
        """Body models for ``sensor_names`` (module docstring), or None if they name none."""
        groups: dict[str, dict[str, int]] = {}
        for i, name in enumerate(sensor_names):
            parsed = _split(name)
            if parsed is None:
                return None
            person, segment = parsed
            if segment in groups.setdefault(person, {}):
                return None
            groups[person][segment] = i
        if not groups:
            return None
        first = set(next(iter(groups.values())))
        if any(set(g) != first for g in groups.values()):
            return None
        preset = next((p for p, names in PRESETS.items() if set(names) == first), None)
        if preset is None:
            return None
        skeleton = body.Skeleton.from_height(height_m, preset, frame)
        people = tuple(groups)
        index = np.array([[groups[p][n] for n in skeleton.names] for p in people],
                         dtype=np.intp)
        right, forward, _ = body.body_axes(frame)
        columns = math.ceil(math.sqrt(len(people)))
        grid = np.array([(a % columns, a // columns) for a in range(len(people))], float)
        roots = (skeleton.root_position_m
                 + spacing_m * (grid[:, :1] * right + grid[:, 1:] * forward))
        index.setflags(write=False)
        roots.setflags(write=False)
        return cls(skeleton, people, index, roots, float(height_m))

    def identity(self) -> list[body.Calibration]:
        """One :func:`identity_calibration` per person."""
        return [identity_calibration(self.skeleton)] * self.n_people

    def calibrate(
        self,
        q_window: ArrayLike,
        heading: Heading = "north",
        forward_axis: ArrayLike | None = None,
        max_spread_deg: float = 5.0,
    ) -> list[body.Calibration]:
        """Offsets of every person from sensor orientations (N, S, 4) held in the reference pose.

        :func:`margtrack.body.calibrate` per person (000, eq. 10); ``ValueError`` if a sensor
        moved more than ``max_spread_deg``.
        """
        q = np.asarray(q_window, dtype=np.float64)
        if q.ndim == 2:
            q = q[None]
        return [body.calibrate(self.skeleton, q[:, idx], heading, forward_axis, max_spread_deg)
                for idx in self.index]

    @staticmethod
    def offsets(calibrations: Sequence[body.Calibration]) -> Array:
        """(A, K, 4) the ``q_offset`` of every person's calibration, stacked."""
        return np.stack([c.offsets for c in calibrations])

    def pose(self, q_sensor: ArrayLike, offsets: ArrayLike, q_copy: Array | None = None
             ) -> tuple[Array, Array, Array]:
        """Segment orientations (A, K, 4), joints (A, K, 3) m and ends (A, K, 3) m of one frame.

        ``q_sensor`` (S, 4) sensor to earth; ``offsets`` (A, K, 4) (:meth:`offsets`); segment
        quaternions with ``w >= 0``. One compiled pass over people and segments
        (:func:`margtrack.body.kinematics.people_pose`, 000 eqs. 7, 11); ``q_copy`` (S, 4),
        if given, receives a copy of ``q_sensor`` in the same pass as its check.
        """
        return people_pose(self.skeleton, q_sensor, self.index, offsets, self.root_positions_m,
                           q_copy=q_copy)
