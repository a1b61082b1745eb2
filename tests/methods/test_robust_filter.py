"""margtrack's robust filter: each mechanism on simulated data built to trigger it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.accuracy import error_series
from margtrack.estimator import Flag
from margtrack.methods.robust import Robust, RobustParams
from margtrack.single_frame.triad import Triad

pytestmark = pytest.mark.kernel


def _deg(x):
    return np.degrees(np.sqrt(np.mean(np.square(x))))


def test_noise_free_motion_raises_no_disturbance_flag():
    # the estimate against the truth in both frames is tests/test_registry_truth.py's
    traj = sim.random_motion(20.0, 100.0, seed=4, max_rate_deg_s=150.0, bandwidth_hz=1.0)
    est = Robust().run(sim.simulate(traj, seed=0))
    assert not np.any(est.flags & Flag.MAG_DISTURBED)


def test_rest_with_gyro_bias_learns_the_bias_and_flags_rest():
    bias = np.radians([0.4, -0.25, 0.3])
    rec = sim.simulate(
        sim.static(30.0, 100.0),
        gyr_errors=sim.SensorErrors(noise_density=np.radians(0.01), bias=bias),
        seed=2,
    )
    est = Robust().run(rec)
    rest = (est.flags & Flag.REST) != 0
    # still from the start: at rest once rest_min_s (1.5 s) has passed
    assert not rest[:140].any() and rest[160:].all()
    learned = est.outputs["gyr_bias_rad_s"][-1]
    sd = est.outputs["gyr_bias_sd_rad_s"][-1]
    # white noise of 0.01 deg/s/√Hz seen through the 0.5 s rest low-pass has a standard
    # deviation of 0.01 * sqrt(1 / (4 * 0.5)) = 0.007 deg/s, and the bias random walk keeps
    # the Kalman gain from averaging much longer: within 3 sigma, 0.02 deg/s
    assert np.all(np.abs(np.degrees(learned - bias)) < 0.02)
    assert np.all(np.degrees(sd) < 0.05)
    # a filter without the bias would have drifted by about 0.55 deg/s * 30 s
    assert np.degrees(error_series(est.quat, rec.quat_true).total_rad[-1]) < 0.5


def test_bias_is_learned_in_motion_from_the_inclination_correction():
    bias = np.radians([0.5, -0.3, 0.0])
    traj = sim.random_motion(120.0, 100.0, seed=3, max_rate_deg_s=90.0, bandwidth_hz=0.5)
    rec = sim.simulate(traj, gyr_errors=sim.SensorErrors(bias=bias), seed=1)
    est = Robust(bias_motion_noise_deg_s=1.0).run(rec)
    assert not np.any(est.flags & Flag.REST)
    learned = np.degrees(est.outputs["gyr_bias_rad_s"][-1])
    # the correction comes through the accelerometer low-pass, whose lag biases the
    # measurement while the sensor turns: the bias is learned to about 0.1 deg/s, from an
    # initial error of 0.58 deg/s; without the motion update it stays at zero
    assert np.linalg.norm(learned - np.degrees(bias)) < 0.15
    off = Robust(bias_motion_noise_deg_s=1e6).run(rec).outputs["gyr_bias_rad_s"][-1]
    assert np.degrees(np.abs(off).max()) < 1e-3


def test_sustained_linear_acceleration_does_not_tilt_the_estimate():
    # a sensor swinging on a 0.5 m limb: centripetal and tangential acceleration of m/s²
    traj = sim.limb_swing(60.0, 100.0, amplitude_deg=40.0, frequency_hz=1.0, length_m=0.5)
    rec = sim.simulate(traj, seed=0)
    robust = error_series(Robust().run(rec).quat, rec.quat_true)
    triad = error_series(Triad().run(rec).quat, rec.quat_true)
    # tangential acceleration amplitude 0.70 rad * (2 pi 1 Hz)² * 0.5 m = 13.8 m/s²; the
    # second-order low-pass with tau 3 s (f_c = 0.075 Hz) passes (f_c / 1 Hz)² = 0.56 % of
    # it, 0.077 m/s², a tilt of at most 0.45 deg (RMS about 0.32 deg)
    assert np.abs(traj.acc_lin_m_s2).max() > 5.0
    assert _deg(robust.inclination_rad[1000:]) < 0.35
    assert np.degrees(robust.inclination_rad[1000:].max()) < 0.6
    assert _deg(triad.inclination_rad[1000:]) > 10 * _deg(robust.inclination_rad[1000:])


def _magnet_pass_recording(peak_ut):
    traj = sim.constant_rotation((0.0, 0.0, 1.0), 20.0, 60.0, 100.0)
    magnet = sim.magnet_pass(
        t_center_s=30.0, duration_s=10.0, peak_ut=peak_ut, direction=(1.0, 0.0, 0.0)
    )
    return sim.simulate(traj, mag_disturbances=(magnet,), seed=0)


def test_magnet_passing_by_is_detected_rejected_and_left_behind():
    rec = _magnet_pass_recording(60.0)
    est = Robust().run(rec)
    flags = (est.flags & Flag.MAG_DISTURBED) != 0
    window = (rec.t > 25.0) & (rec.t < 35.0)
    assert flags[window].mean() > 0.5
    assert not flags[(rec.t < 24.0) | (rec.t > 36.0)].any()
    heading = error_series(est.quat, rec.quat_true).heading_rad
    blind = Robust(mag_norm_tol=100.0, mag_dip_tol_deg=90.0).run(rec)
    blind_heading = error_series(blind.quat, rec.quat_true).heading_rad
    # only the ramps of the bump, where the extra field is still under the 10 % norm and
    # 10 deg dip tolerances, reach the heading; a filter without detection follows it all
    assert np.degrees(np.abs(heading).max()) < 4.0
    assert np.degrees(np.abs(blind_heading).max()) > 4 * np.degrees(np.abs(heading).max())
    assert np.degrees(np.abs(heading[-1])) < 1.5


def test_6d_and_9d_come_from_the_same_run():
    traj = sim.random_motion(20.0, 100.0, seed=6, max_rate_deg_s=100.0, bandwidth_hz=1.0)
    rec = sim.simulate(traj, seed=0)
    est = Robust().run(rec)
    six = est.outputs["quat6d"]
    e9 = error_series(est.quat, rec.quat_true)
    e6 = error_series(six, rec.quat_true)
    # same inclination, heading differs only by the magnetometer's slow correction
    np.testing.assert_allclose(e6.inclination_rad, e9.inclination_rad, atol=1e-9)
    no_mag = Robust().run(rec.without_mag())
    np.testing.assert_allclose(no_mag.quat, no_mag.outputs["quat6d"], atol=0)


def test_variable_sample_intervals():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.005, 0.015, 3000))
    traj = sim.random_motion(30.0, 1000.0, seed=2, max_rate_deg_s=100.0, bandwidth_hz=1.0)
    idx = np.searchsorted(traj.t, t - t[0])
    sub = sim.Trajectory(traj.t[idx], traj.quat[idx], traj.pos_m[idx], traj.acc_lin_m_s2[idx])
    rec = sim.simulate(sub, seed=0)
    est = Robust().run(rec)
    assert np.degrees(error_series(est.quat, rec.quat_true).total_rad.max()) < 0.01


def _stepped(est, gyr, acc, mag, t):
    """Per-sample ``update`` calls: orientations, flags and the bias accessors."""
    q, flags, bias, sd = [], [], [], []
    for i in range(len(t)):
        q.append(est.update(gyr[i], acc[i], mag[i], dt=None if i == 0 else t[i] - t[i - 1]))
        flags.append(est.flags)
        bias.append(est.gyr_bias_rad_s)
        sd.append(est.gyr_bias_sd_rad_s)
    return np.array(q), np.array(flags), np.array(bias), np.array(sd)


def test_update_equals_run_and_halves_join_through_state():
    rec = sim.simulate_motion("random", duration_s=8.0, seed=3)
    gyr, acc, mag, t = rec.gyr.copy(), rec.acc.copy(), rec.mag.copy(), rec.t.copy()
    # unusable first samples, a zero acc and field stretch and a 1 s gap (a restart)
    acc[:20], mag[:35], acc[300:320], mag[400:450] = 0.0, 0.0, 0.0, 0.0
    t[500:] += 1.0
    whole = Robust().run(gyr=gyr, acc=acc, mag=mag, t=t)
    # (it starts at sample 20 from gravity alone, its heading from the first field)
    assert whole.flags[19] & Flag.INITIALISING and not whole.flags[20] & Flag.INITIALISING
    assert whole.flags[500] & Flag.GAP
    q, flags, bias, sd = _stepped(Robust(), gyr, acc, mag, t)
    np.testing.assert_allclose(q, whole.quat, atol=1e-12)
    np.testing.assert_array_equal(flags[:, 0], whole.flags)
    # the accessors read the state the outputs were written from
    np.testing.assert_allclose(bias[:, 0], whole.outputs["gyr_bias_rad_s"], atol=1e-15)
    np.testing.assert_allclose(sd[:, 0], whole.outputs["gyr_bias_sd_rad_s"], atol=1e-15)
    first = Robust()
    a = first.run(gyr=gyr[:333], acc=acc[:333], mag=mag[:333], t=t[:333])
    second = Robust()
    second.state = first.state
    b = second.run(gyr=gyr[333:], acc=acc[333:], mag=mag[333:], t=t[333:])
    np.testing.assert_allclose(np.concatenate([a.quat, b.quat]), whole.quat, atol=1e-12)
    for key in ("quat6d", "gyr_bias_rad_s", "gyr_bias_sd_rad_s"):
        joined = np.concatenate([a.outputs[key], b.outputs[key]])
        np.testing.assert_allclose(joined, whole.outputs[key], atol=1e-12, err_msg=key)


def test_update_of_several_sensors_equals_their_run():
    recs = [sim.simulate_motion("random", duration_s=4.0, seed=s) for s in range(3)]
    gyr, acc, mag = (np.stack([getattr(r, k) for r in recs]) for k in ("gyr", "acc", "mag"))
    acc[1, :40] = 0.0  # sensor 1 starts 40 samples later, at its own first usable sample
    t = recs[0].t
    whole = Robust(frame="NED").run(gyr=gyr, acc=acc, mag=mag, t=t)
    live = Robust(frame="NED")
    q = np.array(
        [
            live.update(gyr[:, i], acc[:, i], mag[:, i], dt=None if i == 0 else t[i] - t[i - 1])
            for i in range(len(t))
        ]
    )
    np.testing.assert_allclose(q, whole.quat.transpose(1, 0, 2), atol=1e-12)
    assert np.all(whole.flags[1, :40] & Flag.INITIALISING) and not whole.flags[1, 40:].any()
    # each sensor's series is its own run (sensor 1's start sample integrates nothing)
    alone = Robust(frame="NED").run(gyr=gyr[1, 40:], acc=acc[1, 40:], mag=mag[1, 40:], t=t[40:])
    np.testing.assert_allclose(whole.quat[1, 40:], alone.quat, atol=1e-12)


def test_a_new_time_constant_takes_effect_at_the_next_sample():
    # the interval's gains live in the state: a parameter change must renew them
    rec = sim.simulate(sim.static(4.0, 100.0), seed=3)  # perfect sensors, true heading 0
    offset = math.radians(30.0)
    est = Robust(converge_s=0.0, rate_hz=100.0)
    est.reset(quat.from_axis_angle([0.0, 0.0, 1.0], offset))
    first = est.run(rec.slice(0, 200))
    est.set_params(tau_mag_s=2.0)
    second = est.run(rec.slice(200))
    err = np.abs(np.concatenate([
        error_series(first.quat, rec.quat_true[:200]).heading_rad,
        error_series(second.quat, rec.quat_true[200:]).heading_rad,
    ]))  # fmt: skip
    # each sample takes 1 - exp(-dt / tau) of the heading error away (20 s, then 2 s)
    np.testing.assert_allclose(err[199], offset * math.exp(-0.01 / 20.0) ** 199, rtol=1e-9)
    np.testing.assert_allclose(err[299], err[199] * math.exp(-0.01 / 2.0) ** 100, rtol=1e-9)


def test_reset_q0_is_the_first_output():
    rec = sim.simulate_motion("limb", duration_s=2.0, seed=0)
    q0 = quat.from_euler([0.3, 0.1, -0.2])
    est = Robust()
    est.reset(q0)
    np.testing.assert_allclose(est.run(rec).quat[0], q0, atol=1e-15)


@pytest.mark.parametrize(
    ("name", "value"),
    [("tau_acc_s", 0.0), ("tau_mag_s", -1.0), ("mag_norm_tol", float("nan")), ("rest_min_s", -1)],
)
def test_bad_parameters_are_named(name, value):
    with pytest.raises(ValueError, match=name):
        RobustParams(**{name: value})
