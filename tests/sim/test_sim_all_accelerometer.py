"""All-accelerometer IMU simulation (003 II-B/C, Fig. 1): kinematics, channels, noise, errors."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import frames, sim
from margtrack import quaternion as quat
from margtrack.sim import all_accelerometer as aa

ARRAY = aa.AccelerometerArray.handheld_instrument()


def test_tremor_rates_match_the_orientation_series():
    # ω analytic (ZYX kinematics) vs the rate that integrates the quaternions: equal to
    # O(T²) (the interval average of ω is its midpoint value plus T² ω''/24)
    m = aa.tremor_motion(3.0, 20000.0, seed=1, hand_amplitude_deg=40.0, tremor_amplitude_m=3e-3)
    w_mid = 0.5 * (m.omega_rad_s[1:] + m.omega_rad_s[:-1])
    np.testing.assert_allclose(sim.body_rate(m.trajectory)[1:], w_mid,
                               atol=1e-5 * np.abs(m.omega_rad_s).max())
    t = m.trajectory.t
    alpha_fd = np.gradient(m.omega_rad_s, t, axis=0)[2:-2]
    np.testing.assert_allclose(alpha_fd, m.alpha_rad_s2[2:-2],
                               atol=1e-5 * np.abs(m.alpha_rad_s2).max())
    acc_fd = np.gradient(np.gradient(m.trajectory.pos_m, t, axis=0), t, axis=0)[4:-4]
    np.testing.assert_allclose(acc_fd, m.trajectory.acc_lin_m_s2[4:-4],
                               atol=1e-5 * np.abs(m.trajectory.acc_lin_m_s2).max())


def test_motion_starts_at_rest_and_has_tremor_amplitude_and_band():
    m = aa.tremor_motion(20.0, 500.0, seed=3, hand_amplitude_deg=0.0, hand_translation_m=0.0)
    assert np.all(m.omega_rad_s[0] == 0.0) and np.all(m.alpha_rad_s2[0] == 0.0)
    assert np.all(m.trajectory.acc_lin_m_s2[0] == 0.0)
    pos = m.trajectory.pos_m[500:]  # after the one-second fade-in: pure tremor
    np.testing.assert_allclose(np.max(np.abs(pos), axis=0), 30e-6, rtol=0.01)
    spectrum = np.abs(np.fft.rfft(pos[:, 0]))
    freq = np.fft.rfftfreq(len(pos), 1 / 500.0)
    bin_hz = freq[1]  # the peak lies within one FFT bin of the tremor frequency
    assert 8.0 - bin_hz <= freq[np.argmax(spectrum)] <= 12.0 + bin_hz


def test_specific_forces_match_twice_differentiated_sensor_positions():
    # independent oracle: p_i(t) = pos(t) + R(t) r_i, f_i = Rᵀ (p̈_i + g_up)
    rate = 20000.0
    m = aa.tremor_motion(0.5, rate, seed=4, hand_amplitude_deg=60.0, hand_bandwidth_hz=2.0,
                         hand_translation_m=0.05, tremor_amplitude_m=1e-3)
    tr = m.trajectory
    g_up = frames.gravity_reference("ENU")
    f0 = quat.rotate_inverse(tr.quat, tr.acc_lin_m_s2 + g_up)
    readings = aa.specific_forces(ARRAY, m.omega_rad_s, m.alpha_rad_s2, f0)
    for k, (sensor, axis) in enumerate(aa.CHANNELS):
        p = tr.pos_m + quat.rotate(tr.quat, ARRAY.positions()[sensor])
        acc = np.gradient(np.gradient(p, tr.t, axis=0), tr.t, axis=0)
        f = quat.rotate_inverse(tr.quat, acc + g_up)[:, axis]
        np.testing.assert_allclose(readings[5:-5, k], f[5:-5], atol=2e-4)


def test_differences_cancel_gravity_and_linear_acceleration():
    rng = np.random.default_rng(0)
    w, a = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    one = aa.specific_forces(ARRAY, w, a, rng.normal(size=(50, 3)))
    two = aa.specific_forces(ARRAY, w, a, 10 * rng.normal(size=(50, 3)))
    d = np.stack([one[:, 4] - one[:, 0], one[:, 5] - one[:, 2], one[:, 3] - one[:, 1]], 1)
    d2 = np.stack([two[:, 4] - two[:, 0], two[:, 5] - two[:, 2], two[:, 3] - two[:, 1]], 1)
    np.testing.assert_allclose(d, d2, atol=1e-12)
    p13, p23, p12 = ARRAY.baselines()  # eq. 1: (Ω×Ω× + Ω̇×) P_ij
    expected = np.stack([
        (np.cross(w, np.cross(w, p13)) + np.cross(a, p13))[:, 0],
        (np.cross(w, np.cross(w, p23)) + np.cross(a, p23))[:, 1],
        (np.cross(w, np.cross(w, p12)) + np.cross(a, p12))[:, 2],
    ], 1)
    np.testing.assert_allclose(d, expected, atol=1e-12)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_at_rest_every_channel_reads_up_and_mag_the_field_in_either_frame(frame):
    q0 = quat.from_euler([0.4, -0.3, 0.2])
    m = aa.motion_from_trajectory(sim.static(1.0, 100.0, q0=q0))
    rec = aa.simulate_all_accelerometer(m, ARRAY, frame=frame)
    up = quat.rotate_inverse(q0, frames.gravity_reference(frame))
    for k, (_, axis) in enumerate(aa.CHANNELS):
        np.testing.assert_allclose(rec.readings_m_s2[:, k], up[axis], atol=1e-12)
    field = quat.rotate_inverse(q0, frames.mag_reference(frame, sim.DEFAULT_DIP_DEG,
                                                         sim.DEFAULT_FIELD_UT))
    np.testing.assert_allclose(rec.mag, np.tile(field, (101, 1)), atol=1e-12)
    np.testing.assert_allclose(rec.quat_true, np.tile(q0, (101, 1)), atol=1e-15)


def test_motion_from_trajectory_is_exact_for_a_constant_rotation():
    traj = sim.constant_rotation((0.0, 1.0, 1.0), 45.0, 2.0, 100.0)
    m = aa.motion_from_trajectory(traj)
    rate = np.radians(45.0) * np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0)
    body = quat.rotate_inverse(traj.quat, rate)  # constant in the body frame too
    np.testing.assert_allclose(m.omega_rad_s, body, atol=1e-12)
    np.testing.assert_allclose(m.alpha_rad_s2, 0.0, atol=1e-9)


def test_channel_noise_has_the_given_density():
    m = aa.motion_from_trajectory(sim.static(200.0, 500.0))
    rec = aa.simulate_all_accelerometer(m, ARRAY, acc_noise_m_s2_sqrt_hz=1e-3, seed=5)
    clean = aa.simulate_all_accelerometer(m, ARRAY)
    std = np.std(rec.readings_m_s2 - clean.readings_m_s2, axis=0)
    # σ = density √rate; sampling error of a std ≈ 1/sqrt(2N) = 0.2 %
    np.testing.assert_allclose(std, 1e-3 * np.sqrt(500.0), rtol=0.01)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: aa.AccelerometerArray(((0, 0, 0), (1, 1, 0))), "3 finite"),
        (lambda: aa.tremor_motion(1.0, 20.0, 0), "tremor_band_hz"),
        (lambda: aa.tremor_motion(1.0, 500.0, -1), "seed"),
        (lambda: aa.simulate_all_accelerometer(
            aa.motion_from_trajectory(sim.limb_swing(1.0, 100.0, frame="NED")), frame="ENU"),
         "built for 'NED'"),
        (lambda: aa.simulate_all_accelerometer(
            aa.motion_from_trajectory(sim.static(1.0, 100.0)), acc_noise_m_s2_sqrt_hz=-1.0),
         "acc_noise_m_s2_sqrt_hz"),
    ],
)
def test_bad_input_is_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call()
