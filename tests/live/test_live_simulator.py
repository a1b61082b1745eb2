"""The simulated people: joint angles, measurement model, determinism, streaming."""

from __future__ import annotations

import math

import numpy as np
import pytest

from margtrack import body, sim
from margtrack import quaternion as quat
from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.live.avatars import Avatars
from margtrack.live.protocol import iter_chunks
from margtrack.live.simulator import PeopleSimulation, SimulatorSource


@pytest.mark.parametrize("motion", ["walk", "wave"])
@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_body_model_joint_angles_are_the_commanded_ones(motion, frame):
    people = PeopleSimulation(n_people=2, motion=motion, frame=frame, seed=5)
    t = np.arange(0.0, 6.0, 0.05)
    q_seg, _ = people.kinematics(t)
    commanded, _, _ = people.joint_angles_deg(t)
    for a in range(2):
        angles = body.joint_angles(people.skeleton, np.swapaxes(q_seg[a], 0, 1))
        assert len(angles.names) == 10
        for j, name in enumerate(angles.names):
            np.testing.assert_allclose(np.degrees(angles.angles_rad[:, j]), commanded[name][a],
                                       atol=1e-9, err_msg=name)
    # still in the reference pose facing north before still_s: every segment at identity
    still = t < people.still_s
    np.testing.assert_allclose(np.abs(q_seg[:, :, still, 0]), 1.0, atol=1e-15)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_signals_follow_the_simulators_measurement_model(frame):
    people = PeopleSimulation(frame=frame, noise=False, rate_hz=100.0, seed=1)
    t, gyr, acc, mag = people.signals(150, 400)
    q, pos = people.sensor_truth(t)
    h = 1e-3
    _, p_plus = people.sensor_truth(t + h)
    _, p_minus = people.sensor_truth(t - h)
    for s in (0, 5, 11):  # pelvis, left hand, left foot
        _, q_prev_pos = people.sensor_truth(t[:1] - 0.01)
        q_prev, _ = people.sensor_truth(t[:1] - 0.01)
        traj = sim.Trajectory(np.concatenate([t[:1] - 0.01, t]),
                              np.concatenate([q_prev[s], q[s]]),
                              np.concatenate([q_prev_pos[s], pos[s]]),
                              np.concatenate([np.zeros((1, 3)),
                                              (p_plus[s] - 2 * pos[s] + p_minus[s]) / h**2]))
        rec = sim.simulate(traj, frame=frame, dip_deg=people.dip_deg, field_ut=people.field_ut)
        np.testing.assert_allclose(gyr[s], rec.gyr[1:], atol=1e-9)
        np.testing.assert_allclose(acc[s], rec.acc[1:], atol=1e-9)
        np.testing.assert_allclose(mag[s], rec.mag[1:], atol=1e-9)


def test_pelvis_linear_acceleration_is_the_second_derivative_of_its_bounce():
    people = PeopleSimulation(preset="lower", noise=False, seed=0)  # one person: cadence 0.9 Hz
    t, _, acc, _ = people.signals(500, 200)  # 5-7 s: after the ramp, full motion
    q, _ = people.sensor_truth(t)
    acc_lin = quat.rotate(q[0], acc[0]) - np.array([0.0, 0.0, STANDARD_GRAVITY_M_S2])
    w = 2 * np.pi * 0.9
    phi = w * t  # phase 0 for one person
    right, _, up = body.body_axes("ENU")
    expected = (-0.02 * (2 * w) ** 2 * np.sin(2 * phi))[:, None] * up + (
        -0.02 * w**2 * np.sin(phi))[:, None] * right
    # central difference with a 1 ms step: truncation h² x''''/12 < 3e-5 m/s² here
    np.testing.assert_allclose(acc_lin, expected, atol=1e-4)


def test_still_phase_reads_gravity_and_no_rotation():
    people = PeopleSimulation(noise=False, seed=2)
    _, gyr, acc, _ = people.signals(0, 150)
    assert np.all(gyr == 0.0)
    np.testing.assert_allclose(np.linalg.norm(acc, axis=-1), STANDARD_GRAVITY_M_S2, rtol=1e-12)


def test_calibration_on_the_true_still_pose_recovers_the_mounting():
    people = PeopleSimulation(n_people=3, preset="lower", seed=9)
    t = np.arange(0.0, 1.0, 0.01)
    q, _ = people.sensor_truth(t)
    avatars = Avatars.from_names(people.sensor_names)
    calibrations = avatars.calibrate(np.swapaxes(q, 0, 1))
    for a, cal in enumerate(calibrations):
        angle = quat.angle_between(cal.offsets, people.mounting[a])
        assert np.max(angle) < 1e-9


def test_deterministic_under_a_seed_and_streamed_block_by_block():
    a = PeopleSimulation(preset="left_arm", motion="wave", block_s=0.5, seed=4)
    b = PeopleSimulation(preset="left_arm", motion="wave", block_s=0.5, seed=4)
    c = PeopleSimulation(preset="left_arm", motion="wave", block_s=0.5, seed=5)
    np.testing.assert_array_equal(a.signals(0, 50)[1], b.signals(0, 50)[1])
    assert not np.allclose(a.signals(0, 50)[1], c.signals(0, 50)[1])
    source = SimulatorSource(a, speed=math.inf, duration_s=2.0)
    chunks = list(iter_chunks(source))
    t = np.concatenate([ch.t_s for ch in chunks])
    gyr = np.concatenate([ch.gyr for ch in chunks], axis=1)
    np.testing.assert_allclose(t, np.arange(201) / 100.0, atol=1e-12)
    for k in range(4):  # blocks of 50 samples, noise from default_rng([seed, k])
        np.testing.assert_array_equal(gyr[:, 50 * k:50 * (k + 1)], a.signals(50 * k, 50, k)[1])
    assert source.finished and source.stats.samples == 201 * 3


def test_bad_configuration_is_refused():
    with pytest.raises(ValueError, match="motion must be one of"):
        PeopleSimulation(motion="dance")
    with pytest.raises(ValueError, match="preset must be one of"):
        PeopleSimulation(preset="tail")
    with pytest.raises(ValueError, match="n_people must be >= 1"):
        PeopleSimulation(n_people=0)
