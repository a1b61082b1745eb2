"""The root path from foot contacts: compass gaits whose pelvis path is known from geometry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.body import Skeleton, body_axes, bvh_axes, dimensions_from_height, write_bvh
from margtrack.body.root import anchor_weights, root_from_contacts, stance

H = 1.75
RATE = 100.0


def _compass(frame: str, theta_deg: float, n_steps: int, rocker: bool, single: int = 40,
             double: int = 15):
    """A straight-legged compass gait of the ``lower`` skeleton, with its events.

    The stance leg (thigh and shank in line) turns from +theta to -theta about the subject's
    right axis while the swing leg, knee bent, swings from -theta to +theta; then both legs
    stand still for ``double`` frames (double support) before the trailing foot leaves.
    Flat feet (``rocker=False``): the stance foot stays level and the leg pivots about the
    ankle, so the pelvis moves ``2 L sin(theta)`` a step, ``L`` hip to ankle; the swing
    foot turns its toes up and back to level. ``rocker=True``: each
    foot is rigid with its leg and rolls over its heel, then its toe.
    """
    sk = Skeleton.from_height(H, "lower", frame)
    right = body_axes(frame)[0]
    theta = np.radians(theta_deg)
    names = sk.names
    frames: list[np.ndarray] = []
    heel = {"left": [], "right": []}
    toe = {"left": [], "right": []}
    lead, trail = "left", "right"  # left in front at +theta, right behind at -theta

    def pose(phi: dict[str, float], knee: dict[str, float], toe_up: float = 0.0
             ) -> np.ndarray:
        q = quat.identity((len(sk),))
        for side in ("left", "right"):
            thigh = quat.from_axis_angle(right, phi[side])
            q[names.index(f"{side}_thigh")] = thigh
            q[names.index(f"{side}_shank")] = quat.multiply(
                thigh, quat.from_axis_angle(right, -knee[side]))
            q[names.index(f"{side}_foot")] = (
                q[names.index(f"{side}_shank")] if rocker
                else quat.from_axis_angle(right, toe_up if knee[side] else 0.0))
        return q

    def add_double() -> None:
        for _ in range(double):
            frames.append(pose({lead: theta, trail: -theta}, {lead: 0.0, trail: 0.0}))

    add_double()
    for _ in range(n_steps):
        toe[trail].append(len(frames) - 1)  # the trailing foot leaves after double support
        for j in range(1, single + 1):
            u = j / single
            phi = {lead: theta - 2 * theta * u, trail: -theta + 2 * theta * u}
            knee = {lead: 0.0, trail: np.radians(40.0) * np.sin(np.pi * u)}
            # a flat swing foot turns toes up and back to level
            frames.append(pose(phi, knee, toe_up=0.5 * np.sin(np.pi * u)))
        lead, trail = trail, lead
        heel[lead].append(len(frames) - 1)  # the swing foot lands
        add_double()
    t = np.arange(len(frames)) / RATE
    events = ({s: t[v] for s, v in heel.items()}, {s: t[v] for s, v in toe.items()})
    return sk, np.stack(frames), t, events


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_flat_footed_compass_gait_moves_the_pelvis_2_l_sin_theta_a_step(frame: str) -> None:
    theta, n_steps = 20.0, 6
    sk, q, t, (hs, to) = _compass(frame, theta, n_steps, rocker=False)
    root = root_from_contacts(sk, q, t, hs, to)
    right, forward, up = body_axes(frame)
    dims = dimensions_from_height(H)
    leg = dims["thigh"] + dims["shank"]  # hip to ankle
    step = 2 * leg * np.sin(np.radians(theta))
    p = root.position_m
    # each stance ends with both feet down: the pelvis has moved one step more
    ends = np.concatenate([[0], np.concatenate([hs["left"], hs["right"]])])
    ends = np.sort(np.searchsorted(t, ends))
    np.testing.assert_allclose(p[ends] @ forward, step * np.arange(n_steps + 1), atol=1e-9)
    np.testing.assert_allclose(p @ right, 0.0, atol=1e-9)
    # height: ankle height plus the stance leg's vertical extent, a + L cos(phi)
    heights = p @ up
    assert heights.max() == pytest.approx(dims["ankle_height"] + leg, abs=1e-3)  # mid-stance
    np.testing.assert_allclose(heights[ends], dims["ankle_height"] + leg *
                               np.cos(np.radians(theta)), atol=1e-9)
    # without foot sensors the shank's end (the ankle) is the contact, at ankle height
    legs = Skeleton.from_segments([n for n in sk.names if not n.endswith("_foot")], H, frame)
    no_feet = root_from_contacts(legs, q[:, [sk.index(n) for n in legs.names]], t, hs, to)
    np.testing.assert_allclose(no_feet.position_m, p, atol=1e-9)
    assert root.drift_m == pytest.approx(n_steps * step, abs=1e-9)
    assert root.path_length_m == pytest.approx(n_steps * step, abs=1e-9)
    # the swing foot never anchors: its weight is 0 while it swings
    w = root.weights
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    mid_swing = ends[1] - 20  # a frame in the middle of the first single support (left stance)
    assert w[mid_swing, 0] == 1.0 and w[mid_swing, 1] == 0.0


def test_rolling_over_heel_then_toe_adds_the_foot_lever() -> None:
    # rigid leg and foot: heel pivot from +theta to 0, toe pivot from 0 to -theta, so a step
    # is 2 (L + a) sin(theta) + f (1 - cos(theta)), f the heel-to-toe length
    theta, n_steps = 15.0, 4
    sk, q, t, (hs, to) = _compass("ENU", theta, n_steps, rocker=True)
    root = root_from_contacts(sk, q, t, hs, to)
    dims = dimensions_from_height(H)
    th = np.radians(theta)
    step = (2 * (dims["thigh"] + dims["shank"] + dims["ankle_height"]) * np.sin(th)
            + dims["foot_length"] * (1 - np.cos(th)))
    forward = body_axes("ENU")[1]
    strikes = np.sort(np.searchsorted(t, np.concatenate([hs["left"], hs["right"]])))
    got = root.position_m[strikes] @ forward
    # the heel-toe blend over 5 mm of height moves the pivot by less than a millimetre
    np.testing.assert_allclose(got, step * np.arange(1, n_steps + 1), atol=1e-3)
    flat = 2 * (dims["thigh"] + dims["shank"] + dims["ankle_height"]) * np.sin(th)
    assert abs(got[-1] - n_steps * flat) > 5e-3  # the foot lever is seen, not missed


def test_a_missed_heel_strike_falls_back_on_the_planted_foot() -> None:
    sk, q, t, (hs, to) = _compass("ENU", 20.0, 6, rocker=False)
    full = root_from_contacts(sk, q, t, hs, to)
    missed = {"left": hs["left"], "right": hs["right"][1:]}  # the right's first strike lost
    root = root_from_contacts(sk, q, t, missed, to)
    assert root.guessed.sum() >= 40  # the next single support has no stance foot by events
    # the right foot, planted and still, is recognised: lower and not turning (a shared
    # anchor would be 0.59 m off, one step; the height alone 0.30 m, as the swinging foot
    # is level with the planted one at the ends of its swing); what is left, 4 mm, comes
    # from the frames where neither clue is sharp
    assert np.abs(root.position_m - full.position_m).max() < 0.01


def test_anchor_passes_over_switch_s_and_never_to_a_swinging_foot() -> None:
    t = np.arange(100) / 100.0
    # left in stance throughout until its toe off at 0.5 s; right strikes at 0.3 s
    left = stance(t, [], [0.5])
    rgt = stance(t, [0.3], [0.05])
    assert left[0][:50].all() and not left[0][50:].any() and np.isneginf(left[1][0])
    assert not rgt[0][5:30].any() and rgt[0][30:].all() and rgt[1][40] == pytest.approx(0.3)
    in_st = np.stack([left[0], rgt[0]], axis=1)
    since = np.stack([left[1], rgt[1]], axis=1)
    w = anchor_weights(t, in_st, since, np.full((100, 2), 0.5), switch_s=0.1)
    assert w[0].tolist() == [0.5, 0.5]  # standing on both feet: a shared anchor
    assert w[10].tolist() == [1.0, 0.0]  # right foot in the air
    # from the strike at 0.30 s the weight moves linearly to the right foot over 0.1 s
    np.testing.assert_allclose(w[30:40, 1], np.arange(1, 11) / 10, atol=1e-12)
    np.testing.assert_allclose(w[40:, 1], 1.0)
    short = anchor_weights(t, in_st, since, np.full((100, 2), 0.5), switch_s=0.5)
    assert short[49, 1] < 1.0 and short[50, 1] == 1.0  # the left foot left: all to the right
    with pytest.raises(ValueError, match="switch_s must be a finite number > 0"):
        anchor_weights(t, in_st, since, np.full((100, 2), 0.5), switch_s=0.0)


def test_bad_input_is_refused_with_the_reason() -> None:
    sk, q, t, (hs, to) = _compass("ENU", 10.0, 1, rocker=False)
    with pytest.raises(ValueError, match="needs a shank or foot on both legs"):
        arm = Skeleton.from_height(H, "right_arm")
        root_from_contacts(arm, quat.identity((3, 3)), [0.0, 0.1, 0.2], {}, {})
    with pytest.raises(ValueError, match="strictly increasing"):
        root_from_contacts(sk, q, t[::-1], hs, to)
    with pytest.raises(ValueError, match="sides 'left' and 'right'"):
        root_from_contacts(sk, q, t, {"middle": [0.1]}, to)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_bvh_root_channels_carry_the_path_in_the_chosen_unit(tmp_path: Path,
                                                             frame: str) -> None:
    bvhio = pytest.importorskip("bvhio", reason="bvhio (dev extra) reads the BVH back")
    sk, q, t, (hs, to) = _compass(frame, 20.0, 2, rocker=False)
    root = root_from_contacts(sk, q, t, hs, to)
    read = {}
    for unit in ("cm", "m"):
        path = tmp_path / f"{unit}.bvh"
        write_bvh(path, sk, q, 1.0 / RATE, root.position_m, unit=unit)
        hierarchy = bvhio.readAsHierarchy(str(path))
        pelvis = next(j for j, _, _ in hierarchy.layout() if j.Name == "pelvis")
        got = []
        for f in range(0, t.size, 7):
            hierarchy.loadPose(f, recursive=True)
            got.append(np.array(pelvis.PositionWorld, dtype=np.float64))
        read[unit] = np.array(got)
    expected_m = root.position_m[::7] @ bvh_axes(frame).T
    np.testing.assert_allclose(read["m"], expected_m, atol=1e-5)
    np.testing.assert_allclose(read["cm"], 100.0 * expected_m, atol=1e-3)
    # the avatar walks: the pelvis moves forward (BVH +Z is north, the facing direction)
    assert read["m"][-1, 2] - read["m"][0, 2] > 0.9
