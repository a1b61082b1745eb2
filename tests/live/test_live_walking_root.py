"""The live walking root: a compass gait of known step length, and the engine's poses."""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.body import body_axes, dimensions_from_height
from margtrack.body.gait import sagittal_rate
from margtrack.live.avatars import Avatars, identity_calibration
from margtrack.live.engine import Engine
from margtrack.live.protocol import iter_chunks
from margtrack.live.simulator import PeopleSimulation, SimulatorSource
from margtrack.live.walking_root import GaitEvents, WalkingRoot

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "body"))
from test_body_root import H, _compass  # a compass gait whose pelvis path is known

THETA_DEG, STEPS = 20.0, 6


def _walk_live(frame: str, every: int, noise_rad_s: float):
    """The compass gait's poses every ``every`` frames of 100 Hz, the events from its shanks'
    rates (plus white noise) sample by sample; returns (t, root (M, 3), weights (M, 2))."""
    sk, q, t, _ = _compass(frame, THETA_DEG, STEPS, rocker=False)
    avatars = Avatars.from_names(sk.names, H, frame)
    root = WalkingRoot(avatars)
    shanks = [sk.index("left_shank"), sk.index("right_shank")]
    feet = [sk.index("left_foot"), sk.index("right_foot")]
    # body rates (segment frame) over each interval, as a gyroscope measures them
    w = np.zeros((t.size, len(sk), 3))
    w[1:] = quat.to_rotvec(quat.multiply(quat.conjugate(q[:-1]), q[1:])) / np.diff(t)[:, None, None]
    w += np.random.default_rng(1).normal(0.0, noise_rad_s, w.shape)
    sag = np.stack([sagittal_rate(w[:, i], frame) for i in shanks], axis=0)  # (2, N)
    out_t, out_root, out_w = [], [], []
    for k in range(t.size):
        root.gait.step(t[k:k + 1], sag[None, :, k:k + 1])
        if k % every == 0:  # a coarser rate of frames
            rates = np.linalg.norm(w[k, feet], axis=1)[None]
            out_root.append(root.update(t[k], q[k][None], rates)[0].copy())
            out_w.append(root.weights[0].copy())
            out_t.append(t[k])
    return np.array(out_t), np.array(out_root), np.array(out_w)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_compass_gait_advances_its_known_step_length_live(frame):
    right, forward, up = body_axes(frame)
    dims = dimensions_from_height(H)
    leg = dims["thigh"] + dims["shank"]
    truth = STEPS * 2 * leg * math.sin(math.radians(THETA_DEG))  # 3.53 m
    for every in (1, 4):  # every frame, and the engine's 25 Hz poses of a 100 Hz stream
        _, root, w = _walk_live(frame, every, noise_rad_s=0.05)
        moved = root - root[0]
        # causal events and 25 Hz poses: within 1.5 % of the geometry's 2 L sin(theta) a
        # step (0.4-0.8 % short: each landing seen 0.05 s late, the first step's toe off
        # taken from the planted-foot guess)
        assert moved[-1] @ forward == pytest.approx(truth, rel=0.015)
        np.testing.assert_allclose(moved @ right, 0.0, atol=1e-9)
        # the height stays between double support (L cos theta) and mid-stance (L) above
        # the ankle's height, within a centimetre
        heights = root @ up
        assert heights.min() > dims["ankle_height"] + leg * math.cos(math.radians(THETA_DEG)) - 0.01
        assert heights.max() < dims["ankle_height"] + leg + 0.01
        np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)


def test_gait_events_from_a_shank_rate_with_a_dip_a_flat_landing_and_a_stop():
    rate_hz = 100.0
    t = np.arange(0, 3.0, 1 / rate_hz)
    # stance (0), swing peak 3 rad/s, a dip to -1 at 0.9 s, stance; then a swing put down flat
    w = np.zeros_like(t)
    swing1 = (t >= 0.3) & (t < 0.9)
    w[swing1] = 3.0 * np.sin(np.pi * (t[swing1] - 0.3) / 0.6)
    dip = (t >= 0.9) & (t < 1.1)
    w[dip] = -np.sin(np.pi * (t[dip] - 0.9) / 0.2)
    swing2 = (t >= 1.5) & (t < 2.1)
    w[swing2] = 3.0 * np.sin(np.pi * (t[swing2] - 1.5) / 0.6)
    events = GaitEvents(1)
    stance = []
    for k in range(t.size):
        events.step(t[k:k + 1], np.array([[[w[k]], [0.0]]]))
        stance.append(events.in_stance[0, 0])
    stance = np.array(stance)
    changes = t[1:][np.diff(stance.astype(int)) != 0]
    # toe off when the rate passes 1 rad/s: asin(1/3) / pi * 0.6 s after the swing starts
    assert changes[0] == pytest.approx(0.3 + 0.6 * math.asin(1 / 3) / math.pi, abs=0.011)
    # heel strike at the dip's minimum (1.0 s), seen once the rate rose 0.1 rad/s above it
    assert 1.0 < changes[1] < 1.1 and events.since_s[0, 1] == -np.inf
    # the second swing ends flat: landed 0.05 s after |rate| fell below 0.3 rad/s
    assert changes[2] == pytest.approx(1.5 + 0.6 * math.asin(1 / 3) / math.pi, abs=0.011)
    end_flat = 2.1 - 0.6 * math.asin(0.3 / 3) / math.pi
    assert changes[3] == pytest.approx(end_flat + 0.05, abs=0.021)
    assert events.since_s[0, 0] == pytest.approx(end_flat, abs=0.011)
    assert changes.size == 4


def test_engine_walks_the_avatar_once_calibrated_and_puts_it_back_on_reset():
    people = PeopleSimulation(preset="lower", seed=3, still_s=2.0)
    source = SimulatorSource(people, speed=math.inf, duration_s=12.0)
    engine = Engine(source.info, "default", walking_root=True)
    poses = []
    engine.subscribe(poses.append)
    chunks = list(iter_chunks(source))
    for chunk in chunks[:3]:  # not calibrated yet: the root stays at the avatar's place
        engine.push([chunk])
    assert poses and all(p.root_m is None for p in poses)
    engine.set_calibrations([dataclasses.replace(identity_calibration(people.skeleton),
                                                 offsets=people.mounting[0])])
    for chunk in chunks[3:8]:
        engine.push([chunk])
    walked = [p for p in poses if p.root_m is not None]
    start = engine.avatars.root_positions_m
    # the root joint is the root; every joint moved with it (the body's shape kept)
    for p in walked:
        np.testing.assert_allclose(p.joints_m[:, 0], p.root_m, atol=1e-12)
    # the simulated person walks on the spot like on a treadmill: the feet move back under
    # the pelvis, so the avatar walks across the floor
    moved = np.hypot(*(walked[-1].root_m - start)[0, :2])
    assert 0.5 < moved < 10.0  # m in the 5 s of walking
    engine.reset_root()
    for chunk in chunks[8:9]:
        engine.push([chunk])
    assert np.hypot(*(poses[-1].root_m - start)[0, :2]) < 1.0  # back, then one second on
    summary = engine.summary()["engine"]
    assert len(summary["root_moved_m"]) == 1
