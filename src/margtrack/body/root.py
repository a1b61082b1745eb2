"""The root (pelvis) path from foot contacts: the stance foot stays put, the pelvis follows.

Orientations alone give every joint relative to the root (:func:`positions` from a fixed
root). Where the body is over the floor comes from its contacts: while a foot is in stance
its contact point does not move, so

    root(t) = contact point - (contact point - root)(t),

the second term being the chain's vector from the root to that foot at ``t``. With
``c_k(t)`` foot ``k``'s contact point relative to the root:

- horizontally, the root moves against the anchor foot's contact: from frame ``n - 1`` to
  ``n``, ``Δroot = -Σ_k w_k(n - 1) Δc_k`` (weights at the step's start; summed from the
  first frame, which keeps the skeleton's reference position), so a change of anchor foot
  changes the velocity, never the position;
- vertically, the contact point is on a level floor: ``root_up = -Σ_k w_k(t) c_k,up(t)``
  plus the height that puts the reference pose's contact on the floor, so the height
  does not drift (stairs and slopes are not modelled).

The contact point of a foot is its heel (below the ankle) or its toe (the foot's end),
whichever is lower, blended over a few millimetres (``blend_m``) so rolling from heel to
toe moves no joint; a leg without a foot sensor contacts through the shank's end (the
ankle, its height above the floor taken from the reference pose).

The anchor weights ``w`` (:func:`anchor_weights`) come from the gait events
(:mod:`margtrack.body.gait`): a foot is in stance from its heel strike to its toe off.
With one foot in stance it is the anchor; in double support the anchor passes from the
trailing foot to the foot that struck last, linearly over ``switch_s`` (or until the
trailing foot's toe off, if sooner); with no foot in stance by the events (a missed heel
strike, a turn on the spot, a flight phase) the anchor is the foot that looks planted:
lower and turning slower than the other.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.body._checks import frame_times, sensor_quaternions
from margtrack.body.kinematics import positions
from margtrack.body.segments import body_axes, positive
from margtrack.body.skeleton import Skeleton

Array = NDArray[np.float64]

__all__ = ["RootPath", "anchor_weights", "contact_lift_m", "contact_points", "leg_ends",
           "planted_weights", "root_from_contacts", "stance"]

SIDES = ("left", "right")
#: Scales of the soft guess of the planted foot where the events show no stance: height
#: (the chain's heights are good to a centimetre or two) and turning rate.
_GUESS_HEIGHT_M = 0.02
_GUESS_RATE_RAD_S = 0.5


def stance(t_s: ArrayLike, heel_strike_s: ArrayLike, toe_off_s: ArrayLike
           ) -> tuple[NDArray[np.bool_], Array]:
    """Stance of one foot at each frame from its events, and when that stance began.

    The latest event at or before a frame decides: heel strike -> stance, toe off -> swing.
    Before the first event the foot is in stance if that event is a toe off (standing
    before the first step), else in swing. NaN events (missed) are ignored.

    Returns
    -------
    in_stance : (N,) bool.
    since_s : (N,) s, the heel strike that began the stance, ``-inf`` for a stance held
        from the start, NaN in swing.
    """
    t = np.asarray(t_s, dtype=np.float64)
    hs = np.asarray(heel_strike_s, dtype=np.float64).ravel()
    to = np.asarray(toe_off_s, dtype=np.float64).ravel()
    hs, to = hs[np.isfinite(hs)], to[np.isfinite(to)]
    times = np.concatenate([hs, to])
    kinds = np.concatenate([np.ones(hs.size, bool), np.zeros(to.size, bool)])
    order = np.argsort(times, kind="stable")
    times, kinds = times[order], kinds[order]
    last = np.searchsorted(times, t, side="right") - 1
    before_first = last < 0
    in_stance = np.where(before_first, not (kinds[0] if kinds.size else False),
                         kinds[np.maximum(last, 0)] if kinds.size else True)
    since = np.where(in_stance, np.where(before_first, -np.inf,
                                         times[np.maximum(last, 0)] if times.size else -np.inf),
                     np.nan)
    return in_stance.astype(bool), since


def anchor_weights(t_s: ArrayLike, in_stance: ArrayLike, since_s: ArrayLike,
                   planted: ArrayLike, switch_s: float = 0.1) -> Array:
    """(N, K) weights of K feet as the anchor, each row summing to 1 (module docstring).

    Parameters
    ----------
    t_s : (N,) s, strictly increasing.
    in_stance : (N, K) bool, each foot's stance (:func:`stance`).
    since_s : (N, K) s, when each stance began (``-inf`` from the start, NaN in swing).
    planted : (N, K) how likely each foot is the one on the floor, rows summing to 1,
        used where no foot is in stance.
    switch_s : s, how long the anchor takes to pass to the foot that just struck: the
        trailing mean over ``round(switch_s / dt)`` frames (median ``dt``) of the target.
    """
    t = np.asarray(t_s, dtype=np.float64)
    st = np.asarray(in_stance, dtype=bool)
    since = np.asarray(since_s, dtype=np.float64)
    guess = np.asarray(planted, dtype=np.float64)
    if (st.ndim != 2 or st.shape[0] != t.size or since.shape != st.shape
            or guess.shape != st.shape):
        raise ValueError(f"in_stance, since_s and planted must all have shape ({t.size}, K); "
                         f"got {st.shape}, {since.shape}, {guess.shape}")
    switch = positive(switch_s, "switch_s")
    n, k = st.shape
    latest = np.where(st, np.nan_to_num(since, nan=-np.inf), -np.inf)
    target = guess.copy()
    some = st.any(axis=1)
    # the foot in stance that struck last; a tie (standing from the start) shares the weight
    lead = st & (latest == latest.max(axis=1, keepdims=True))
    target[some] = lead[some] / lead[some].sum(axis=1, keepdims=True)
    # the anchor passes over switch_s: a trailing mean of the target (not before a strike)
    span = max(1, round(switch / float(np.median(np.diff(t))))) if n > 1 else 1
    cum = np.vstack([np.zeros((1, k)), np.cumsum(target, axis=0)])
    idx = np.arange(n)
    first = np.maximum(idx + 1 - span, 0)
    w = (cum[idx + 1] - cum[first]) / (idx + 1 - first)[:, None]
    # a foot that has left the floor anchors nothing; with no foot in stance the guess
    # (soft already) is taken as it is, not blended with a foot that just left
    w = np.where(some[:, None], w * st, target)
    total = w.sum(axis=1, keepdims=True)
    return np.where(total > 0, w / np.where(total > 0, total, 1.0), target)


def _soft_smaller(a: Array, b: Array, scale: float) -> Array:
    """Weight of ``a`` being the smaller of two values: 1 well below ``b``, 0.5 equal."""
    return 0.5 * (1.0 + np.tanh((b - a) / scale))


def leg_ends(skeleton: Skeleton) -> dict[str, str]:
    """Each leg's contact segment in ``skeleton`` (the foot, else the shank), by side."""
    out = {}
    for side in SIDES:
        for seg in (f"{side}_foot", f"{side}_shank"):
            if seg in skeleton.names:
                out[side] = seg
                break
    return out


def contact_points(skeleton: Skeleton, q_segment: ArrayLike, blend_m: float = 0.005
                   ) -> tuple[Array, Array]:
    """Each leg's contact point relative to the root and its rolling share of the motion.

    Parameters
    ----------
    skeleton : the body model, with a left and a right leg.
    q_segment : (N, S, 4) segment orientations.
    blend_m : m, the height difference over which heel and toe share the contact.

    Returns
    -------
    points : (N, 2, P, 3) m, the candidate points of each leg (left, right) relative to the
        root: heel and toe for a foot (P = 2), the ankle twice for a shank.
    share : (N, 2, P) weights of the points (the lower one near 1), summing to 1.
    """
    ends = leg_ends(skeleton)
    if set(ends) != set(SIDES):
        raise ValueError(f"root from foot contacts needs a shank or foot on both legs; the "
                         f"skeleton has {', '.join(skeleton.names)}")
    q = sensor_quaternions(q_segment, skeleton, "q_segment")
    if q.ndim != 3:
        raise ValueError(f"q_segment must have shape (N, S, 4), got {q.shape}")
    joints, _ = positions(skeleton, q, np.zeros(3))
    up = body_axes(skeleton.frame)[2]
    pts = np.empty((q.shape[0], 2, 2, 3))
    for j, side in enumerate(SIDES):
        i = skeleton.index(ends[side])
        end = skeleton.segments[i].end_m
        heel = (end @ up) * up if ends[side].endswith("_foot") else end
        pts[:, j] = joints[:, i, None, :] + quat.rotate(q[:, i, None, :], np.stack([heel, end]))
    h = pts @ up
    heel_low = _soft_smaller(h[..., 0], h[..., 1], positive(blend_m, "blend_m"))
    return pts, np.stack([heel_low, 1.0 - heel_low], axis=-1)


def planted_weights(heights_m: ArrayLike, rates_rad_s: ArrayLike) -> Array:
    """(..., 2) how likely each foot (left, right) is the one on the floor.

    heights_m (..., 2) m, each foot's contact point along the up axis; rates_rad_s (..., 2)
    rad/s, how fast each foot (or shank) turns. The lower foot and the foot that turns
    slower (a planted foot hardly turns; a swinging one turns at several rad/s), each a
    soft choice over ``_GUESS_HEIGHT_M`` and ``_GUESS_RATE_RAD_S``, multiplied: either clue
    decides when the other is even (both feet level at the start and end of a swing; both
    still at mid-swing's turn of the foot). Each row sums to 1 (0.5 each when both clues
    cancel).
    """
    h = np.asarray(heights_m, dtype=np.float64)
    r = np.asarray(rates_rad_s, dtype=np.float64)
    low = _soft_smaller(h[..., 0], h[..., 1], _GUESS_HEIGHT_M)
    slow = _soft_smaller(r[..., 0], r[..., 1], _GUESS_RATE_RAD_S)
    left, right = low * slow, (1.0 - low) * (1.0 - slow)
    total = left + right
    left = np.where(total > 0, left / np.where(total > 0, total, 1.0), 0.5)
    return np.stack([left, 1.0 - left], axis=-1)


def _planted(skeleton: Skeleton, q: Array, t: Array, heights: Array) -> Array:
    """(N, 2) :func:`planted_weights` with each foot's turning rate from its orientations."""
    ends = leg_ends(skeleton)
    idx = [skeleton.index(ends[s]) for s in SIDES]
    rate = np.zeros((t.size, 2))
    if t.size > 1:
        rate[1:] = quat.angle_between(q[:-1, idx], q[1:, idx]) / np.diff(t)[:, None]
        rate[0] = rate[1]
    return planted_weights(heights, rate)


def contact_lift_m(skeleton: Skeleton, blend_m: float = 0.005) -> float:
    """Height of the root above the floor minus the contacts' mean height (relative to the
    root) in the reference pose, m: the root's height is this minus the anchor's contact
    height relative to the root."""
    up = body_axes(skeleton.frame)[2]
    ref_pts, ref_share = contact_points(skeleton, quat.identity((1, len(skeleton))), blend_m)
    return float(skeleton.root_position_m @ up + float(
        np.einsum("nkp,nkpd->nkd", ref_share, ref_pts)[0].mean(axis=0) @ up))


@dataclass(frozen=True, eq=False)
class RootPath:
    """The root's path over N frames (module docstring).

    Attributes
    ----------
    position_m : (N, 3) m, the root joint, in the earth frame ``frame``.
    weights : (N, 2) the left and right feet's share as the anchor.
    frame : ``"ENU"`` or ``"NED"``.
    guessed : (N,) bool, frames with no foot in stance by the events, where the foot that
        looked planted was taken as the anchor.
    """

    position_m: Array
    weights: Array
    frame: str
    guessed: NDArray[np.bool_]

    @property
    def horizontal_m(self) -> Array:
        """(N, 3) m, the path with its vertical part removed."""
        up = body_axes(self.frame)[2]
        return self.position_m - np.outer(self.position_m @ up, up)

    @property
    def drift_m(self) -> float:
        """Horizontal distance from the first frame's position to the last's, m."""
        h = self.horizontal_m
        return float(np.linalg.norm(h[-1] - h[0]))

    @property
    def path_length_m(self) -> float:
        """Horizontal distance travelled, m."""
        return float(np.linalg.norm(np.diff(self.horizontal_m, axis=0), axis=1).sum())

    def write_csv(self, path: str | Path, t_s: ArrayLike, root: str = "pelvis") -> None:
        """``t (s)``, the root's earth-frame coordinates (m) and the feet's anchor shares.

        Columns ``<root>_east (m)``, ``<root>_north (m)``, ``<root>_up (m)`` (ENU; NED:
        north, east, down), then ``left_anchor``, ``right_anchor`` (0-1).
        """
        t = frame_times(t_s, self.position_m.shape[0])
        axes = ("east", "north", "up") if self.frame == "ENU" else ("north", "east", "down")
        header = ",".join(["t (s)", *(f"{root}_{a} (m)" for a in axes), "left_anchor",
                           "right_anchor"])
        np.savetxt(path, np.column_stack([t, self.position_m, self.weights]), fmt="%.10g",
                   delimiter=",", header=header, comments="")


def root_from_contacts(
    skeleton: Skeleton,
    q_segment: ArrayLike,
    t_s: ArrayLike,
    heel_strike_s: Mapping[str, ArrayLike],
    toe_off_s: Mapping[str, ArrayLike],
    *,
    switch_s: float = 0.1,
    blend_m: float = 0.005,
    start_m: ArrayLike | None = None,
) -> RootPath:
    """The root's path from the orientations and the feet's contacts (module docstring).

    Parameters
    ----------
    skeleton : the body model, with both legs.
    q_segment : (N, S, 4) segment orientations (earth frame ``skeleton.frame``).
    t_s : (N,) s, strictly increasing.
    heel_strike_s, toe_off_s : ``"left"``/``"right"`` -> (E,) s, each foot's events
        (:class:`margtrack.body.gait.SideGait`); NaN entries are ignored, a side without
        events stays in stance.
    switch_s : s, how long the anchor takes to pass to the foot that just struck.
    blend_m : m, height difference over which heel and toe share a foot's contact.
    start_m : (3,) m, the first frame's horizontal position (its vertical part is
        ignored); default ``skeleton.root_position_m``.
    """
    q = sensor_quaternions(q_segment, skeleton, "q_segment")
    t = frame_times(t_s, q.shape[0] if q.ndim == 3 else -1)
    for name, events in (("heel_strike_s", heel_strike_s), ("toe_off_s", toe_off_s)):
        extra = set(events) - set(SIDES)
        if extra:
            raise ValueError(f"{name} takes the sides 'left' and 'right', got {sorted(extra)}")
    pts, share = contact_points(skeleton, q, blend_m)
    up = body_axes(skeleton.frame)[2]
    start = skeleton.root_position_m if start_m is None else np.asarray(start_m, float)
    if start.shape != (3,) or not np.all(np.isfinite(start)):
        raise ValueError(f"start_m must be a finite 3-vector in m, got {start_m!r}")
    contact = np.einsum("nkp,nkpd->nkd", share, pts)  # (N, 2, 3) each foot's contact
    phases = [stance(t, heel_strike_s.get(s, ()), toe_off_s.get(s, ())) for s in SIDES]
    in_stance = np.stack([p[0] for p in phases], axis=1)
    since = np.stack([p[1] for p in phases], axis=1)
    heights = contact @ up
    w = anchor_weights(t, in_stance, since, _planted(skeleton, q, t, heights), switch_s)
    # each step weighted by the contact at its start: a foot that strikes at frame n was
    # still swinging from n - 1, and one that leaves at n was still on the floor
    step = np.einsum("nkp,nkpd->nkd", share[:-1], np.diff(pts, axis=0))
    horizontal = -np.einsum("nk,nkd->nd", w[:-1], step)
    horizontal -= np.outer(horizontal @ up, up)
    position = np.empty((t.size, 3))
    position[0] = start - (start @ up) * up
    position[1:] = position[0] + np.cumsum(horizontal, axis=0)
    # the contact's height above the floor in the reference pose (0 on a foot's sole)
    lift = contact_lift_m(skeleton, blend_m)
    position += np.outer(lift - np.einsum("nk,nk->n", w, heights), up)
    guessed = ~in_stance.any(axis=1)
    for arr in (position, w, guessed):
        arr.setflags(write=False)
    return RootPath(position, w, skeleton.frame, guessed)
