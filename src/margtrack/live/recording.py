"""What the engine recorded between ``start_recording`` and ``stop_recording``, and its export.

The engine records every processed frame's sensor orientations (at the sensors' rate, not
the display rate); the body model is applied at export with the calibration in force when
the recording stopped, so an export is the offline body model of the recorded orientations:
BVH via :func:`margtrack.body.write_bvh`, joint angles via
:func:`margtrack.body.write_joint_angles_csv`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from margtrack import body
from margtrack.live.avatars import Avatars

Array = NDArray[np.float64]

__all__ = ["LiveRecording"]


@dataclass(frozen=True, eq=False)
class LiveRecording:
    """Recorded sensor orientations and what is needed to turn them into body motion.

    Attributes
    ----------
    t_s : (N,) s, sample times.
    q_sensor : (N, S, 4) sensor to earth (``frame``), one per source sensor.
    sensor_names : S names.
    frame : earth frame.
    avatars : the body models (None if the sensors name none).
    calibrations : per person, the offsets in force at the end of the recording.
    """

    t_s: Array
    q_sensor: Array
    sensor_names: tuple[str, ...]
    frame: str
    avatars: Avatars | None
    calibrations: tuple[body.Calibration, ...]

    @property
    def n_frames(self) -> int:
        """Number of frames N."""
        return int(self.t_s.shape[0])

    def _check(self, person: int) -> Avatars:
        if self.avatars is None:
            raise ValueError("this recording has no body model: its sensors name no segments")
        if not 0 <= person < self.avatars.n_people:
            raise ValueError(f"person must be in 0..{self.avatars.n_people - 1}, got {person}")
        if self.n_frames < 2:
            raise ValueError(f"the recording has {self.n_frames} frame(s); record at least 2")
        return self.avatars

    def segment_orientations(self, person: int = 0) -> Array:
        """(N, K, 4) segment to earth of one person (000, eq. 7)."""
        avatars = self._check(person)
        q = self.q_sensor[:, avatars.index[person]]
        return body.segment_orientations(avatars.skeleton, self.calibrations[person], q)

    def joint_angles(self, person: int = 0) -> body.JointAngles:
        """Joint angles (N, J, 3) rad of one person."""
        avatars = self._check(person)
        return body.joint_angles(avatars.skeleton, self.segment_orientations(person))

    def frame_time_s(self) -> float:
        """Median interval between frames, s (the BVH frame time)."""
        return float(np.median(np.diff(self.t_s)))

    def write_bvh(self, path: str | Path, person: int = 0, unit: str = "cm") -> Path:
        """BVH of one person at the recording's median frame interval; returns the path."""
        avatars = self._check(person)
        body.write_bvh(path, avatars.skeleton, self.segment_orientations(person),
                       self.frame_time_s(), avatars.root_positions_m[person], unit)
        return Path(path)

    def write_joint_angles_csv(self, path: str | Path, person: int = 0) -> Path:
        """CSV of one person's joint angles in degrees with ``t (s)``; returns the path."""
        body.write_joint_angles_csv(path, self.t_s, self.joint_angles(person))
        return Path(path)

    def export(self, folder: str | Path, stem: str = "live", people: Sequence[int] = (0,)
               ) -> list[Path]:
        """BVH and joint-angle CSV of each listed person into ``folder``; returns the files."""
        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        files = []
        for a in people:
            suffix = "" if len(people) == 1 else f"_{a}"
            files.append(self.write_bvh(out / f"{stem}{suffix}.bvh", a))
            files.append(self.write_joint_angles_csv(out / f"{stem}{suffix}_joints.csv", a))
        return files
