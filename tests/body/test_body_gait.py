"""Gait events and cycles: a synthetic shank gyroscope with known events, bad input, the
x-IMU3 walk."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.body import JointAngles, Skeleton, body_axes, normalise_cycles
from margtrack.body.gait import (
    analyse_gait,
    detect_events,
    gait_summary_lines,
    sagittal_rate,
    segment_rates,
    side_gait,
    write_gait_cycles_csv,
)
from margtrack.body.plot import plot_gait_cycles

RATE = 100.0


def _bump(t: np.ndarray, centre: float, sigma: float) -> np.ndarray:
    return np.exp(-0.5 * ((t - centre) / sigma) ** 2)


def synthetic_shank(seed: int = 7, n_strides: int = 8, still_s: float = 1.5,
                    noise_rad_s: float = 0.05):
    """A shank's sagittal rate (rad/s) at 100 Hz with known heel strikes and toe offs.

    Standing ``still_s``, then ``n_strides`` strides of 0.95-1.25 s with stance 57-66 %,
    then standing again. Per stride: a sharp negative dip at heel strike (-1.5 rad/s, 20 ms
    wide), a slow negative stance (the shank turning forward over the foot), a deeper dip
    at toe off (-2.5 rad/s, 30 ms), and the swing: a positive sin² arch (4-5.5 rad/s) from
    toe off to the next heel strike. Gaussian noise, seeded.
    """
    rng = np.random.default_rng(seed)
    strides = rng.uniform(0.95, 1.25, n_strides)
    stance = rng.uniform(0.57, 0.66, n_strides)
    # the walk starts with a first swing from standing: toe off, swing, heel strike
    first_swing = 0.42
    hs = still_s + first_swing + np.concatenate([[0.0], np.cumsum(strides)])
    to = np.concatenate([[still_s], hs[:-1] + stance * strides])
    t = np.arange(0.0, hs[-1] + 2.0, 1.0 / RATE)
    w = np.zeros_like(t)
    for k in range(hs.size):  # swing k: from to[k] to hs[k]
        u = (t - to[k]) / (hs[k] - to[k])
        arch = np.where((u > 0) & (u < 1), np.sin(np.pi * u) ** 2, 0.0)
        w += rng.uniform(4.0, 5.5) * arch
        w -= 1.5 * _bump(t, hs[k], 0.02) + 2.5 * _bump(t, to[k], 0.03)
        if k + 1 < to.size:  # stance k: from hs[k] to to[k + 1]
            v = (t - hs[k]) / (to[k + 1] - hs[k])
            w -= 0.6 * np.where((v > 0) & (v < 1), np.sin(np.pi * v), 0.0)
    w += rng.normal(scale=noise_rad_s, size=t.size)
    return t, w, hs, to


def test_detected_events_match_the_synthetic_truth() -> None:
    t, w, hs, to = synthetic_shank()
    mid, heel, toe = detect_events(t, w)
    assert mid.size == hs.size  # one mid-swing per swing, none while standing
    # 20 ms: two samples at 100 Hz (the noise moves a minimum by a sample at most)
    np.testing.assert_allclose(heel, hs, atol=0.02)
    np.testing.assert_allclose(toe, to, atol=0.02)
    assert np.all((mid > to) & (mid < hs))


def test_cycles_give_the_true_cadence_and_stance() -> None:
    t, w, hs, to = synthetic_shank(seed=11)
    g = side_gait("left", "left_shank", t, w)
    assert g.n_cycles == hs.size - 1
    duration = np.diff(hs)
    np.testing.assert_allclose(g.start_s, hs[:-1], atol=0.02)
    np.testing.assert_allclose(g.cadence_steps_min, 120.0 / duration, rtol=0.03)
    truth = 100.0 * (to[1:] - hs[:-1]) / duration
    np.testing.assert_allclose(g.stance_pct, truth, atol=3.0)  # 40 ms of ~1.1 s, two events
    assert g.message() is None


def test_the_sign_matters_a_reversed_axis_finds_other_events() -> None:
    # the method is not symmetric: the negated rate (a left-pointing axis) is not a walk
    t, w, hs, _ = synthetic_shank(seed=3)
    g = side_gait("right", "right_shank", t, -w)
    assert g.n_cycles == 0 or not np.allclose(g.start_s[:1], hs[:1], atol=0.05)


def test_a_pause_longer_than_max_cycle_s_splits_the_walk() -> None:
    t, w, hs, _ = synthetic_shank(seed=5)
    cut = int(np.searchsorted(t, hs[3] + 0.2))  # in the stance after the 4th heel strike
    pause = w[cut] + np.random.default_rng(1).normal(scale=0.05, size=200)  # 2 s standing
    w2 = np.concatenate([w[:cut], pause, w[cut:]])
    t2 = np.arange(w2.size) / RATE
    g = side_gait("left", "left_shank", t2, w2)
    assert g.n_cycles == hs.size - 2  # the cycle across the pause is dropped
    assert np.all(g.duration_s < 1.3)
    assert not np.any(np.isclose(g.start_s, hs[3], atol=0.02))


@pytest.mark.parametrize("n_swings", [0, 1, 2])
def test_fewer_than_two_cycles_is_a_plain_message(n_swings: int, tmp_path: Path) -> None:
    t, w, _, _ = synthetic_shank(seed=2, n_strides=max(n_swings - 1, 0))
    if n_swings == 0:
        w = np.random.default_rng(0).normal(scale=0.05, size=t.size)  # standing still
    g = side_gait("left", "left_shank", t, w)
    assert g.n_cycles == max(n_swings - 1, 0)
    assert g.message() is not None and "fewer than two" in g.message()
    lines = "\n".join(gait_summary_lines({"left": g}))
    assert "fewer than two, so no cycle average" in lines
    write_gait_cycles_csv(tmp_path / "c.csv", {"left": g})
    rows = (tmp_path / "c.csv").read_text().splitlines()
    assert rows[0].startswith("side,cycle,start (s)") and len(rows) == 1 + g.n_cycles
    angles = JointAngles(("left_knee",), (("flexion", "abduction", "internal_rotation"),),
                         np.zeros((t.size, 1, 3)))
    with pytest.raises(ValueError, match="no side has two gait cycles"):
        plot_gait_cycles(tmp_path / "c.png", t, angles, {"left": g})
    assert gait_summary_lines({}) == ["gait: no shank or foot sensor, so no gait events"]


def test_bad_input_is_refused_with_the_fix() -> None:
    t, w, _, _ = synthetic_shank()
    bad = w.copy()
    bad[123] = np.nan
    with pytest.raises(ValueError, match="non-finite value at sample 123"):
        detect_events(t, bad)
    uneven = t.copy()
    uneven[50:] += 0.5
    with pytest.raises(ValueError, match=r"evenly spaced.*sample 50"):
        detect_events(uneven, w)
    with pytest.raises(ValueError, match="strictly increasing"):
        detect_events(t[::-1], w)
    with pytest.raises(ValueError, match=r"shape \(N,\)"):
        detect_events(t, np.stack([w, w], axis=1))
    with pytest.raises(ValueError, match="min_swing_rad_s must be a finite number > 0"):
        detect_events(t, w, min_swing_rad_s=-1.0)
    with pytest.raises(ValueError, match="side must be 'left' or 'right'"):
        side_gait("middle", "left_shank", t, w)
    assert all(e.size == 0 for e in detect_events(t[:5], w[:5]))  # too short: no events


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_sagittal_rate_is_positive_when_the_shank_swings_forward(frame: str) -> None:
    right, forward, up = body_axes(frame)
    sk = Skeleton.from_height(1.75, "lower", frame)
    # a shank turning about the right axis: its distal end (down) moves forward
    q0 = quat.identity()
    dq = quat.from_axis_angle(right, 0.01)
    end0, end1 = quat.rotate(q0, -up), quat.rotate(quat.multiply(q0, dq), -up)
    assert (end1 - end0) @ forward > 0
    assert sagittal_rate(np.array([right * 2.0]), frame)[0] == pytest.approx(2.0)
    # a sensor mounted turned: the calibration offset turns its rate into the segment frame
    mount = quat.from_axis_angle([0.3, -0.5, 0.8], 1.1)  # q_sensor = q_segment ⊗ mount
    offsets = np.tile(quat.conjugate(mount), (len(sk), 1))
    t = np.arange(5) * 0.01
    gyr_sensor = np.tile(quat.rotate(quat.conjugate(mount), right * 2.0), (5, 1))
    rates = segment_rates(t, [t] * len(sk), [gyr_sensor] * len(sk), offsets)
    np.testing.assert_allclose(rates[:, 0], np.tile(right * 2.0, (5, 1)), atol=1e-12)
    gait = analyse_gait(t, sk, rates)
    assert set(gait) == {"left", "right"} and gait["left"].segment == "left_shank"


def test_normalise_cycles_interpolates_each_cycle() -> None:
    t = np.arange(0.0, 3.0, 0.01)
    values = np.stack([t, t**2], axis=1)
    out = normalise_cycles(t, values, [0.5, 1.5], [1.4, 2.9], n_points=11)
    assert out.shape == (2, 11, 2)
    np.testing.assert_allclose(out[1, :, 0], np.linspace(1.5, 2.9, 11), atol=1e-12)
    np.testing.assert_allclose(out[0, -1, 1], 1.4**2, atol=1e-3)
    with pytest.raises(ValueError, match="outside the samples"):
        normalise_cycles(t, values, [2.0], [3.5])
    with pytest.raises(ValueError, match="start < end"):
        normalise_cycles(t, values, [2.0], [1.0])


@pytest.mark.kernel
def test_xio_walk_has_cycles_with_plausible_cadence_and_stance(xio_folder: Path) -> None:
    from margtrack import body

    result = body.process_body(body.read_body(xio_folder))  # robust, pelvis heading, -z
    assert set(result.gait) == {"left", "right"}
    for side, g in result.gait.items():
        assert g.segment == f"{side}_shank"
        assert g.n_cycles >= 2, (side, g.heel_strike_s)
        assert np.all((g.cadence_steps_min > 80.0) & (g.cadence_steps_min < 140.0)), side
        assert np.all((g.stance_pct > 50.0) & (g.stance_pct < 75.0)), side
    # the subject walks away, turns and comes back: the pelvis travels metres, at hip
    # height over the floor throughout
    root = result.root
    assert root is not None and root.path_length_m > 3.0
    up = body_axes(result.skeleton.frame)[2]
    height = root.position_m @ up
    assert np.all(np.abs(height - result.skeleton.root_position_m @ up) < 0.1)
    assert np.allclose(result.pose.joints_m[:, 0], root.position_m)
