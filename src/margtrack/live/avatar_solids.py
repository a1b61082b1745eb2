"""The avatar's volume: a capsule per limb, boxes for trunk and pelvis, a shoulder girdle, a head.

Built once per body model (:meth:`SolidLayout.from_avatars`), evaluated per displayed pose
(:meth:`SolidLayout.solids`), vectorised over people and segments. Everything is in the
skeleton's earth frame (``skeleton.frame``); orientations map a solid's local axes to that
frame, so converting a solid to another earth frame is the frame change of its position
and of its quaternion (:func:`margtrack.frames.convert`).

Solids (sizes as fractions of body height H, after Winter 2009's proportions):

- *capsules*: a unit cylinder (radius 1, along local ``z`` from -1/2 to 1/2) scaled by
  ``(r, r, length)`` between two points, and a ball of radius ``r`` at each end (the caps):
  every limb segment from its joint to its distal end; the links between a parent's distal
  end and a child's joint when they are apart (neck to shoulders: the shoulder girdle; hip
  centre to hips); the neck;
- *boxes*: a unit cube scaled to (width along the body's right axis, depth forward, height
  up), turning with its segment: the trunk (from hips to shoulders) and the pelvis;
- *head*: a ball on the head segment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from margtrack import quaternion as quat
from margtrack.body.skeleton import body_axes
from margtrack.live.avatars import Avatars

Array = NDArray[np.float64]

__all__ = ["SolidLayout", "Solids", "box_mesh", "cylinder_mesh", "sphere_mesh"]

#: limb radius / H per segment kind (upper arm ~5 cm, thigh ~8 cm for H = 1.75 m)
_RADIUS = {"upper_arm": 0.030, "forearm": 0.025, "hand": 0.022, "thigh": 0.045,
           "shank": 0.036, "foot": 0.026}
_GIRDLE_RADIUS = 0.032
_HIP_RADIUS = 0.045
_NECK_RADIUS = 0.028
_TRUNK = (0.20, 0.11)  # width, depth / H
_PELVIS = (0.20, 0.12, 0.10)  # width, depth, height / H
_HEAD = 0.30  # radius / head segment length (about 10 cm for H = 1.8 m)
COLORS = {"left": (40, 110, 220), "right": (220, 60, 50), "": (120, 175, 120),
          "head": (225, 185, 150)}


def _side(name: str) -> str:
    side = name.split("_")[0]
    return side if side in ("left", "right") else ""


def _kind(name: str) -> str:
    side = _side(name)
    return name[len(side) + 1:] if side else name


@dataclass(frozen=True, eq=False)
class Solids:
    """One frame's solids (instances over all people), in the skeleton's earth frame.

    capsule_a/b (C, 3) m: capsule ends; capsule_radius (C,) m; capsule_colors (C, 3) uint8.
    box_positions (X, 3) m, box_wxyzs (X, 4), box_scales (X, 3) m (local x, y, z), box_colors.
    head_positions (P, 3) m, head_radius (P,) m.
    """

    capsule_a: Array
    capsule_b: Array
    capsule_radius: Array
    capsule_colors: NDArray[np.uint8]
    box_positions: Array
    box_wxyzs: Array
    box_scales: Array
    box_colors: NDArray[np.uint8]
    head_positions: Array
    head_radius: Array

    def cylinders(self) -> tuple[Array, Array, Array]:
        """Positions (C, 3), orientations (C, 4) and scales (C, 3) of the unit cylinders."""
        d = self.capsule_b - self.capsule_a
        length = np.linalg.norm(d, axis=-1)
        z = np.broadcast_to([0.0, 0.0, 1.0], d.shape)
        q = quat.shortest_arc(z, np.where(length[:, None] > 0, d, z))
        r = self.capsule_radius
        return 0.5 * (self.capsule_a + self.capsule_b), q, np.stack([r, r, length], axis=-1)

    def balls(self) -> tuple[Array, Array, NDArray[np.uint8]]:
        """Centres (B, 3), radii (B,) and colours of the capsules' caps and the heads."""
        pos = np.concatenate([self.capsule_a, self.capsule_b, self.head_positions])
        radius = np.concatenate([self.capsule_radius, self.capsule_radius, self.head_radius])
        head = np.tile(np.array(COLORS["head"], np.uint8), (len(self.head_radius), 1))
        colors = np.concatenate([self.capsule_colors, self.capsule_colors, head])
        return pos, radius, colors

    def points(self) -> Array:
        """(M, 3) m points on the surface's extremes (for framing a camera)."""
        pos, radius, _ = self.balls()
        box_r = 0.5 * np.linalg.norm(self.box_scales, axis=-1)
        offsets = np.concatenate([radius, box_r])[:, None] * np.concatenate(
            [np.eye(3), -np.eye(3)])[:, None, :]
        centres = np.concatenate([pos, self.box_positions])
        return (centres[None] + offsets).reshape(-1, 3)


@dataclass(frozen=True, eq=False)
class SolidLayout:
    """Which solids join which joints (module docstring); built once per body model."""

    avatars: Avatars
    capsules: tuple[tuple[str, int, str, int], ...]  # (point kind a, seg a, kind b, seg b)
    capsule_radius_m: Array
    capsule_colors: NDArray[np.uint8]
    boxes: tuple[tuple[int, float, Array], ...]  # (segment, centre fraction, local scale m)
    head: int | None
    head_radius_m: float

    @classmethod
    def from_avatars(cls, avatars: Avatars) -> SolidLayout:
        """The layout of ``avatars``' skeleton at its height."""
        sk = avatars.skeleton
        h = avatars.height_m
        right, forward, up = (np.abs(v) for v in body_axes(sk.frame))
        capsules, radius, colors = [], [], []
        names = sk.names
        zero = np.zeros(3)
        for k, name in enumerate(names):
            kind = _kind(name)
            if kind in _RADIUS:
                capsules.append(("joint", k, "end", k))
                radius.append(_RADIUS[kind] * h)
                colors.append(COLORS[_side(name)])
            p = int(sk.parents[k])
            if p >= 0 and not np.allclose(sk.segments[k].offset_m - sk.segments[p].end_m, zero):
                # parent's distal end -> this joint: shoulder girdle, hip links
                capsules.append(("end", p, "joint", k))
                radius.append((_GIRDLE_RADIUS if "arm" in kind else _HIP_RADIUS) * h)
                colors.append(COLORS[""])
        boxes = []
        if "trunk" in names:
            k = names.index("trunk")
            length = float(np.linalg.norm(sk.segments[k].end_m))
            scale = _TRUNK[0] * h * right + _TRUNK[1] * h * forward + 0.8 * length * up
            boxes.append((k, 0.55, scale))
        if "pelvis" in names and len(names) > 3:
            k = names.index("pelvis")
            scale = _PELVIS[0] * h * right + _PELVIS[1] * h * forward + _PELVIS[2] * h * up
            boxes.append((k, 0.0, scale))
        head = names.index("head") if "head" in names else None
        head_r = 0.0
        if head is not None:
            capsules.append(("joint", head, "head_centre", head))
            radius.append(_NECK_RADIUS * h)
            colors.append(COLORS["head"])
            head_r = _HEAD * float(np.linalg.norm(sk.segments[head].end_m))
        return cls(avatars, tuple(capsules), np.array(radius, float),
                   np.array(colors, np.uint8).reshape(-1, 3), tuple(boxes), head, head_r)

    def solids(self, q_segment: Array, joints_m: Array, ends_m: Array) -> Solids:
        """The solids of one frame from the pose (A, K, 4), (A, K, 3) m, (A, K, 3) m."""
        q = np.asarray(q_segment, float)
        j = np.asarray(joints_m, float)
        e = np.asarray(ends_m, float)
        n_people = j.shape[0]
        head_c = None
        if self.head is not None:
            head_c = j[:, self.head] + 0.6 * (e[:, self.head] - j[:, self.head])
        points = {"joint": j, "end": e}

        def point(kind: str, k: int) -> Array:
            return head_c if kind == "head_centre" else points[kind][:, k]  # type: ignore[return-value]

        a = np.stack([point(ka, k) for ka, k, _, _ in self.capsules], axis=1) if self.capsules \
            else np.zeros((n_people, 0, 3))
        b = np.stack([point(kb, k) for _, _, kb, k in self.capsules], axis=1) if self.capsules \
            else np.zeros((n_people, 0, 3))
        box_pos, box_q, box_s = [], [], []
        up = body_axes(self.avatars.skeleton.frame)[2]
        h = self.avatars.height_m
        for k, frac, scale in self.boxes:
            if frac > 0:
                centre = j[:, k] + frac * (e[:, k] - j[:, k])
            else:  # the pelvis box sits a little above the hip centre, turning with the pelvis
                centre = j[:, k] + quat.rotate(q[:, k], 0.02 * h * up)
            box_pos.append(centre)
            box_q.append(q[:, k])
            box_s.append(np.broadcast_to(scale, (n_people, 3)))
        n_box = len(self.boxes)

        def stack(xs: list[Array], w: int) -> Array:
            return np.stack(xs, axis=1).reshape(-1, w) if xs else np.zeros((0, w))

        box_colors = np.tile(np.array(COLORS[""], np.uint8), (n_box * n_people, 1))
        heads = head_c if head_c is not None else np.zeros((0, 3))
        return Solids(
            capsule_a=a.reshape(-1, 3), capsule_b=b.reshape(-1, 3),
            capsule_radius=np.tile(self.capsule_radius_m, n_people),
            capsule_colors=np.tile(self.capsule_colors, (n_people, 1)),
            box_positions=stack(box_pos, 3), box_wxyzs=stack(box_q, 4),
            box_scales=stack(box_s, 3), box_colors=box_colors,
            head_positions=heads, head_radius=np.full(len(heads), self.head_radius_m),
        )

    def reference(self) -> Solids:
        """The solids of every person standing in the reference pose (identity segments)."""
        av = self.avatars
        q = np.tile(quat.identity(), (av.n_people, len(av.skeleton), 1))
        from margtrack import body

        joints, ends = body.positions(av.skeleton, q, av.root_positions_m)
        return self.solids(q, joints, ends)


def cylinder_mesh(sides: int = 16) -> tuple[Array, NDArray[np.int32]]:
    """Unit cylinder (radius 1, z in [-1/2, 1/2]) with caps: vertices (V, 3), faces (F, 3)."""
    a = 2 * np.pi * np.arange(sides) / sides
    ring = np.stack([np.cos(a), np.sin(a)], axis=-1)
    bottom = np.column_stack([ring, np.full(sides, -0.5)])
    top = np.column_stack([ring, np.full(sides, 0.5)])
    verts = np.concatenate([bottom, top, [[0, 0, -0.5], [0, 0, 0.5]]])
    i = np.arange(sides)
    n = (i + 1) % sides
    side = np.concatenate([np.stack([i, n, sides + i], -1),
                           np.stack([n, sides + n, sides + i], -1)])
    caps = np.concatenate([np.stack([np.full(sides, 2 * sides), n, i], -1),
                           np.stack([np.full(sides, 2 * sides + 1), sides + i, sides + n], -1)])
    return verts, np.concatenate([side, caps]).astype(np.int32)


def sphere_mesh(rings: int = 10, segments: int = 16) -> tuple[Array, NDArray[np.int32]]:
    """Unit UV sphere: vertices (V, 3), faces (F, 3), outward winding."""
    theta = np.pi * np.arange(1, rings) / rings
    phi = 2 * np.pi * np.arange(segments) / segments
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring = np.stack([st * np.cos(phi), st * np.sin(phi), np.repeat(ct, segments, axis=1)],
                    axis=-1).reshape(-1, 3)
    verts = np.concatenate([[[0, 0, 1.0]], ring, [[0, 0, -1.0]]])
    faces = []
    s = segments
    for j in range(s):
        faces.append((0, 1 + j, 1 + (j + 1) % s))
    for r in range(rings - 2):
        for j in range(s):
            a, b = 1 + r * s + j, 1 + r * s + (j + 1) % s
            faces += [(a, a + s, b), (b, a + s, b + s)]
    last = len(verts) - 1
    base = 1 + (rings - 2) * s
    for j in range(s):
        faces.append((last, base + (j + 1) % s, base + j))
    return verts, np.array(faces, np.int32)


def box_mesh() -> tuple[Array, NDArray[np.int32]]:
    """Unit cube centred at the origin (edges 1): vertices (8, 3), faces (12, 3)."""
    v = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
             (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    return v, np.array(faces, np.int32)
