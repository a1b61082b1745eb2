"""The live page's 3-D scene: avatars with volume (or sensor frames), framed by the camera.

The page's world is z-up ENU; poses in NED are shown through :func:`display` (positions
``(e, n, -d)``, quaternions by :func:`margtrack.frames.convert`). With a body model every
person is drawn as solids (:mod:`margtrack.live.avatar_solids`): batched unit cylinders,
balls and boxes, one draw call each, their instances updated per pose; each segment's axes
can be shown as well. Without one, one frame per sensor on a grid.

The camera starts framed on the avatars in the reference pose (or on the sensor grid): it
looks at the centre of their bounding box from in front of them (along the body's forward
axis, a little to the right and above), at the distance where the box's larger half-extent
fills ``fill`` of the vertical field of view.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack import frames as frames_mod
from margtrack.live.avatar_solids import SolidLayout, box_mesh, cylinder_mesh, sphere_mesh
from margtrack.live.avatars import Avatars

Array = NDArray[np.float64]

__all__ = ["AvatarScene", "camera_view", "display"]

_FOV_RAD = math.radians(50.0)


def display(frame: str, p: Array | None = None, q: Array | None = None
            ) -> tuple[Array | None, Array | None]:
    """Positions and orientations in the page's z-up world (ENU)."""
    if frame == "ENU":
        return p, q
    p2 = None if p is None else np.stack([p[..., 1], p[..., 0], -p[..., 2]], axis=-1)
    return p2, None if q is None else frames_mod.convert(q, frame, "ENU")


def camera_view(points_enu: Array, fov_rad: float = _FOV_RAD, fill: float = 0.75
                ) -> tuple[Array, Array]:
    """(position, look_at) of a camera framing ``points_enu`` (M, 3) from the front (+y
    north, the avatars' forward after a north-heading calibration), a little right and above.
    """
    lo, hi = points_enu.min(axis=0), points_enu.max(axis=0)
    centre = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    extent = max(half[2], math.hypot(half[0], half[1]), 0.3)
    direction = np.array([0.35, 1.0, 0.25])
    direction /= np.linalg.norm(direction)
    distance = extent / (fill * math.tan(0.5 * fov_rad)) + half[1]
    return centre + distance * direction, centre


class AvatarScene:
    """Scene objects of one engine's sources on one viser server (module docstring)."""

    def __init__(self, server: Any, avatars: Avatars | None, n_sensors: int, frame: str
                 ) -> None:
        self.server = server
        self.frame = frame
        self.avatars = avatars
        scene = server.scene
        scene.add_grid("/floor", width=8.0, height=8.0, cell_size=0.5)
        # the default environment light washes the side colours out to pastels
        scene.configure_environment_map("warehouse", environment_intensity=0.45)
        self.layout = SolidLayout.from_avatars(avatars) if avatars is not None else None
        if self.layout is not None:
            ref = self.layout.reference()
            self._cyl = self._add("/avatars/limbs", cylinder_mesh(), len(ref.capsule_radius),
                                  ref.capsule_colors)
            _, radius, ball_colors = ref.balls()
            self._ball = self._add("/avatars/joints", sphere_mesh(), len(radius), ball_colors)
            self._box = self._add("/avatars/trunk", box_mesh(), len(ref.box_scales),
                                  ref.box_colors) if len(ref.box_scales) else None
            n_seg = avatars.n_people * len(avatars.skeleton)  # type: ignore[union-attr]
            self._frames = scene.add_batched_axes(
                "/avatars/axes", np.tile([1.0, 0, 0, 0], (n_seg, 1)), np.zeros((n_seg, 3)),
                axes_length=0.15, axes_radius=0.01, visible=False)
            self.show_solids(ref)
            points, _ = display(frame, ref.points())
        else:
            cols = math.ceil(math.sqrt(n_sensors))
            grid = np.array([(0.6 * (i % cols), -0.6 * (i // cols), 1.0)
                             for i in range(n_sensors)], dtype=float)
            self._sensor_positions = grid - np.array([0.3 * (cols - 1), 0.0, 0.0])
            self._frames = scene.add_batched_axes(
                "/sensors", np.tile([1.0, 0, 0, 0], (n_sensors, 1)), self._sensor_positions,
                axes_length=0.25, axes_radius=0.02)
            points = np.concatenate([self._sensor_positions - 0.3, self._sensor_positions + 0.3])
        position, look_at = camera_view(np.asarray(points))
        self.camera_position, self.camera_look_at = position, look_at
        cam = server.initial_camera
        cam.fov = _FOV_RAD
        cam.position = tuple(position)
        cam.look_at = tuple(look_at)
        cam.up = (0.0, 0.0, 1.0)

    def _add(self, name: str, mesh: tuple[Array, NDArray[np.int32]], n: int,
             colors: NDArray[np.uint8]) -> Any:
        vertices, faces = mesh
        return self.server.scene.add_batched_meshes_simple(
            name, vertices.astype(np.float32), faces.astype(np.uint32),
            batched_wxyzs=np.tile([1.0, 0, 0, 0], (n, 1)).astype(np.float32),
            batched_positions=np.zeros((n, 3), np.float32),
            batched_scales=np.ones((n, 3), np.float32), batched_colors=colors,
            lod="off", cast_shadow=False, receive_shadow=False)

    def set_axes_visible(self, visible: bool) -> None:
        """Show or hide the segment axes (always shown without a body model)."""
        if self.layout is not None:
            self._frames.visible = bool(visible)

    def show_solids(self, solids: Any) -> None:
        """Move the solids' instances (skeleton frame in, page frame out)."""
        pos, q, scale = solids.cylinders()
        pos, q = display(self.frame, pos, q)
        self._cyl.batched_positions = pos.astype(np.float32)
        self._cyl.batched_wxyzs = q.astype(np.float32)
        self._cyl.batched_scales = scale.astype(np.float32)
        centres, radius, _ = solids.balls()
        centres, _ = display(self.frame, centres)
        self._ball.batched_positions = centres.astype(np.float32)
        self._ball.batched_scales = np.repeat(radius[:, None], 3, axis=1).astype(np.float32)
        if self._box is not None:
            bpos, bq = display(self.frame, solids.box_positions, solids.box_wxyzs)
            self._box.batched_positions = bpos.astype(np.float32)
            self._box.batched_wxyzs = bq.astype(np.float32)
            self._box.batched_scales = solids.box_scales.astype(np.float32)

    def show(self, pose: Any) -> None:
        """Draw one published pose (``Pose`` of :mod:`margtrack.live.engine`)."""
        with self.server.atomic():
            if self.layout is not None and pose.joints_m is not None:
                self.show_solids(self.layout.solids(pose.q_segment, pose.joints_m, pose.ends_m))
                joints, ends = pose.joints_m, pose.ends_m
                mid, q = display(self.frame, (0.5 * (joints + ends)).reshape(-1, 3),
                                 pose.q_segment.reshape(-1, 4))
                self._frames.batched_positions = mid.astype(np.float32)
                self._frames.batched_wxyzs = q.astype(np.float32)
            else:
                _, q = display(self.frame, None, pose.q_sensor)
                self._frames.batched_wxyzs = q.astype(np.float32)

