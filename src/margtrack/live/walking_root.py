"""The live avatars' root (pelvis) from foot contacts: the planted foot held still, causally.

``margtrack body`` moves the root after the recording (:mod:`margtrack.body.root`: gait
events found with the whole shank signal). Live, every frame moves it at once with
what is known up to that frame, with the same geometry
(:func:`~margtrack.body.root.contact_points`, :func:`~margtrack.body.root.contact_lift_m`,
:func:`~margtrack.body.root.planted_weights`):

- gait events, causally (:class:`GaitEvents`), from each leg's shank (else foot) sagittal
  rate ``ω`` (its gyroscope in the segment frame, :func:`~margtrack.body.gait.sagittal_rate`;
  positive while the leg swings forward): the foot leaves the floor (toe off) when ``ω``
  rises above ``swing_rad_s`` and lands (heel strike) at the first minimum below zero after
  the swing's peak, seen once ``ω`` has risen ``prominence_rad_s`` above it (a sample or
  two late), or, a foot put down flat without that dip, once ``|ω|`` stays below
  ``flat_rad_s`` for ``flat_s`` after the peak; a swing longer than ``max_swing_s`` ends
  (the leg stopped in the air: stance);
- the anchor is the foot in stance that struck last; with no foot in stance, or both
  standing since the start, the foot that looks planted, the lower one and the one
  turning slower (``|ω|`` of its gyroscope; :func:`~margtrack.body.root.planted_weights`);
  it passes to a new foot over ``switch_s`` and never stays on a foot that left the floor
  (:func:`~margtrack.body.root.anchor_weights` done causally);
- horizontally, the root moves against the anchor's contact point, weighted by the
  anchor at the previous pose: ``Δroot = -Σ_k w_k Δc_k`` (``c_k`` foot ``k``'s contact
  relative to the root), so the stance foot stays where it is on the floor;
- vertically, the anchor's contact is on a level floor: ``root_up = lift - Σ_k w_k c_k,up``.

Each person starts at their avatar's place in the reference pose (:class:`Avatars`);
:meth:`WalkingRoot.reset` puts everyone back there. A person whose legs lack a shank or
foot on either side keeps the fixed root.
"""

from __future__ import annotations

import threading

import numpy as np
from numpy.typing import NDArray

from margtrack import quaternion as quat
from margtrack.body.gait import gait_segment
from margtrack.body.root import SIDES, contact_lift_m, contact_points, leg_ends, planted_weights
from margtrack.body.segments import body_axes
from margtrack.live.avatars import Avatars
from margtrack.live.pose import Pose

Array = NDArray[np.float64]

__all__ = ["GaitEvents", "LiveRoot", "WalkingRoot"]


class GaitEvents:
    """Each leg's stance from its sagittal rate, sample by sample (module docstring).

    ``in_stance`` (A, 2) bool and ``since_s`` (A, 2) s (the heel strike that began the
    stance; ``-inf`` for a stance held from the start) after the last sample stepped.
    """

    def __init__(self, n_people: int, swing_rad_s: float = 1.0, prominence_rad_s: float = 0.1,
                 flat_rad_s: float = 0.3, flat_s: float = 0.05, max_swing_s: float = 1.5
                 ) -> None:
        self.swing_rad_s = float(swing_rad_s)
        self.flat_rad_s = float(flat_rad_s)
        self.flat_s = float(flat_s)
        self.prominence_rad_s = float(prominence_rad_s)
        self.max_swing_s = float(max_swing_s)
        shape = (n_people, 2)
        self.in_stance = np.ones(shape, dtype=bool)
        self.since_s = np.full(shape, -np.inf)
        self._peaked = np.zeros(shape, dtype=bool)  # the swing's peak passed
        self._peak = np.zeros(shape)
        self._low = np.full(shape, np.inf)  # lowest rate since the peak
        self._low_t = np.zeros(shape)
        self._left_s = np.zeros(shape)  # toe off time
        self._flat_from = np.full(shape, np.nan)  # since when |ω| < flat_rad_s after the peak

    def step(self, t_s: Array, rate_rad_s: Array) -> None:
        """Advance over the samples ``t_s`` (N,) s of the sagittal rates (A, 2, N) rad/s."""
        for k in range(t_s.shape[0]):
            t, w = float(t_s[k]), rate_rad_s[..., k]
            leave = self.in_stance & (w > self.swing_rad_s)
            self.in_stance &= ~leave
            self._left_s[leave] = t
            self._peaked[leave] = False
            self._peak[leave] = w[leave]
            swing = ~self.in_stance
            rising = swing & ~self._peaked & (w >= self._peak)
            self._peak[rising] = w[rising]
            passed = swing & ~self._peaked & (w < self._peak - self.prominence_rad_s)
            self._peaked |= passed
            self._low[passed] = np.inf
            lower = swing & self._peaked & (w < self._low)
            self._low[lower] = w[lower]
            self._low_t[lower] = t
            dip = swing & self._peaked & (self._low < 0.0) & (
                w > self._low + self.prominence_rad_s)
            flat = swing & self._peaked & (np.abs(w) < self.flat_rad_s)
            self._flat_from[flat & np.isnan(self._flat_from)] = t
            self._flat_from[~flat] = np.nan
            put_down = flat & ~dip & (t - self._flat_from >= self.flat_s)
            stuck = swing & ~dip & ~put_down & (t - self._left_s > self.max_swing_s)
            self.in_stance |= dip | put_down | stuck
            self.since_s[dip] = self._low_t[dip]
            self.since_s[put_down] = self._flat_from[put_down]
            self.since_s[stuck] = t
            self._flat_from[self.in_stance] = np.nan


class WalkingRoot:
    """Root positions of every person of ``avatars`` from foot contacts (module docstring).

    Parameters
    ----------
    avatars : the body models (both legs needed: :attr:`available`).
    switch_s : s, how long the anchor takes to pass fully to the other foot.
    blend_m : m, height difference over which heel and toe share a foot's contact.
    gait : the options of :class:`GaitEvents`.
    """

    def __init__(self, avatars: Avatars, switch_s: float = 0.1, blend_m: float = 0.005,
                 **gait: float) -> None:
        self.avatars = avatars
        self.switch_s = float(switch_s)
        self.blend_m = float(blend_m)
        sk = avatars.skeleton
        ends = leg_ends(sk)
        self.available = set(ends) == set(SIDES)
        self._up = body_axes(sk.frame)[2]
        if self.available:
            #: (A, 2) sensor index of each person's left and right contact segment
            self.contact_sensors = np.stack(
                [avatars.index[:, sk.index(ends[s])] for s in SIDES], axis=1)
            #: (2,) segment index of the left and right gait segment (shank, else foot)
            self.gait_segments = np.array([sk.index(gait_segment(sk, s) or ends[s])
                                           for s in SIDES])
            self._lift = contact_lift_m(sk, self.blend_m)
        self._gait_options = gait
        self.reset()

    def reset(self) -> None:
        """Every root back at its avatar's reference position (and the anchors forgotten)."""
        start = np.array(self.avatars.root_positions_m, dtype=np.float64)
        self._horizontal = start - np.outer(start @ self._up, self._up)
        self.position_m = start.copy()
        self.weights = np.full((self.avatars.n_people, 2), 0.5)
        self.gait = GaitEvents(self.avatars.n_people, **self._gait_options)
        self._last: tuple[float, Array, Array, Array] | None = None

    def sagittal_rates(self, gyr_rad_s: Array, offsets: Array) -> Array:
        """(A, 2, N) rad/s, each person's left and right gait segment's sagittal rate from
        every sensor's rate (S, N, 3) rad/s and the calibration's offsets (A, K, 4)."""
        sensors = self.avatars.index[:, self.gait_segments]  # (A, 2)
        off = offsets[:, self.gait_segments]  # (A, 2, 4)
        g = quat.rotate(quat.conjugate(off)[:, :, None, :], gyr_rad_s[sensors])
        return g @ body_axes(self.avatars.skeleton.frame)[0]

    def update(self, t_s: float, q_segment: Array, rates_rad_s: Array) -> Array:
        """Root positions (A, 3) m at the pose of time ``t_s`` (s).

        q_segment (A, K, 4) segment orientations of every person (earth frame);
        rates_rad_s (A, 2) how fast each person's left and right contact segment turns,
        rad/s (their sensors' gyroscope).
        """
        if not self.available:
            return self.position_m
        sk = self.avatars.skeleton
        pts, share = contact_points(sk, q_segment, self.blend_m)  # (A, 2, P, 3), (A, 2, P)
        contact = np.einsum("akp,akpd->akd", share, pts)
        heights = contact @ self._up  # (A, 2)
        st, since = self.gait.in_stance, self.gait.since_s
        some = st.any(axis=1, keepdims=True)
        latest = np.where(st, since, -np.inf)
        lead = st & (latest == latest.max(axis=1, keepdims=True))
        guess = planted_weights(heights, rates_rad_s)
        tie = lead.all(axis=1, keepdims=True)  # both standing since the start (or a reset)
        target = np.where(some & ~tie, lead / np.maximum(lead.sum(axis=1, keepdims=True), 1),
                          guess)
        if self._last is None:
            w = target
        else:
            t_prev, w_prev, pts_prev, share_prev = self._last
            reach = min(max(t_s - t_prev, 0.0) / self.switch_s, 1.0)
            w = np.where(some, w_prev + np.clip(target - w_prev, -reach, reach), target)
            w = np.where(some, w * st, w)
            total = w.sum(axis=1, keepdims=True)
            w = np.where(total > 0, w / np.where(total > 0, total, 1.0), target)
            step = np.einsum("akp,akpd->akd", share_prev, pts - pts_prev)
            move = -np.einsum("ak,akd->ad", w_prev, step)
            self._horizontal = self._horizontal + move - np.outer(move @ self._up, self._up)
        self._last = (float(t_s), w, pts, share)
        self.weights = w
        vertical = self._lift - np.einsum("ak,ak->a", w, heights)
        self.position_m = self._horizontal + np.outer(vertical, self._up)
        return self.position_m


class LiveRoot:
    """The engine's walking roots: :class:`WalkingRoot` fed batch by batch, started at the
    avatars' places when a calibration comes in force (``count`` changes) or when asked
    (:meth:`request_reset`, thread-safe); before any calibration the roots stay put."""

    def __init__(self, avatars: Avatars) -> None:
        self.root = WalkingRoot(avatars)
        self._count = 0
        self._reset = threading.Event()

    def request_reset(self) -> None:
        """Every root back at its avatar's place from the next pose on."""
        self._reset.set()

    def batch(self, t_s: Array, gyr_rad_s: Array, q_sensor: Array, offsets: Array | None,
              count: int) -> Array | None:
        """Move the roots over a batch, frame by frame: ``t_s`` (N,) s, every sensor's rate
        (S, N, 3) rad/s and orientation (S, N, 4), under calibration number ``count`` (0:
        none yet) with its offsets (A, K, 4). Returns the roots at every frame (N, A, 3) m,
        or None while they stay at the avatars' places (no calibration yet)."""
        if count == 0 or offsets is None:
            return None
        root = self.root
        if count != self._count or self._reset.is_set():
            self._reset.clear()
            self._count = count
            root.reset()
        sag = root.sagittal_rates(gyr_rad_s, offsets)  # (A, 2, N)
        q_seg = quat.multiply(q_sensor[root.avatars.index], offsets[:, :, None, :])
        g = gyr_rad_s[root.contact_sensors]  # (A, 2, N, 3)
        rates = np.sqrt(np.einsum("aknd,aknd->akn", g, g))
        out = np.empty((t_s.shape[0], *root.position_m.shape))
        for k in range(t_s.shape[0]):
            root.gait.step(t_s[k:k + 1], sag[:, :, k:k + 1])
            out[k] = root.update(float(t_s[k]), q_seg[:, :, k], rates[:, :, k])
        return out

    def walk(self, pose: Pose) -> Pose:
        """``pose`` with every root where the feet moved it (joints and ends shifted)."""
        if self._count == 0 or pose.q_segment is None:
            return pose
        return pose.walked(self.root.position_m, self.root.avatars.root_positions_m)

    def moved_m(self, pose: Pose | None) -> list[list[float]] | None:
        """Per person, the root's offset from its avatar's place in ``pose``, m (rounded to
        mm), or None before the roots walk."""
        if pose is None or pose.root_m is None:
            return None
        return np.round(pose.root_m - self.root.avatars.root_positions_m, 3).tolist()
