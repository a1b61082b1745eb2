"""smoother: its Kalman algebra against numpy, the smoothing's properties, the input policy."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import methods, sim
from margtrack import quaternion as quat
from margtrack.accuracy import error_series
from margtrack.estimator import Flag
from margtrack.methods.robust import Robust
from margtrack.methods.smoother import Smoother, kernel

pytestmark = pytest.mark.kernel

BIAS_RAD_S = np.radians([0.4, -0.25, 0.3])


def _spd(rng: np.random.Generator) -> np.ndarray:
    a = rng.normal(size=(6, 6))
    return a @ a.T + 0.5 * np.eye(6)


def _rmse_deg(est, rec, frame: str = "ENU") -> float:
    err = error_series(est.quat, rec.quat_true, frame, frame).total_rad
    return float(np.degrees(np.sqrt(np.mean(err**2))))


# --- the algebra, against numpy ---------------------------------------------------------


def test_a_scalar_update_is_the_kalman_update():
    rng = np.random.default_rng(0)
    for i, sign in ((0, 1.0), (2, -1.0), (4, 1.0)):
        p, dx = _spd(rng), rng.normal(size=6)
        h = np.zeros(6)
        h[i] = sign
        z, r = 0.3, 0.7
        s = h @ p @ h + r
        k = p @ h / s
        want_dx = dx + k * (z - h @ dx)
        want_p = p - np.outer(k, h @ p)
        got_p, got_dx = p.copy(), dx.copy()
        kernel._scalar_update(got_p, got_dx, i, sign, z, r)
        assert np.allclose(got_dx, want_dx, atol=1e-12)
        assert np.allclose(got_p, want_p, atol=1e-12)


def test_an_update_of_one_state_alone_is_schmidts_with_josephs_covariance():
    rng = np.random.default_rng(1)
    p, dx = _spd(rng), rng.normal(size=6)
    i, sign, z, r = 2, -1.0, 0.2, 0.4
    h = np.zeros(6)
    h[i] = sign
    gain = np.zeros(6)
    gain[i] = p[i, i] / (p[i, i] + r) * sign  # only state i moves
    a = np.eye(6) - np.outer(gain, h)
    want_p = a @ p @ a.T + r * np.outer(gain, gain)
    want_dx = dx + gain * (z - h @ dx)
    got_p, got_dx = p.copy(), dx.copy()
    kernel._alone_update(got_p, got_dx, i, sign, z, r)
    assert np.allclose(got_p, want_p, atol=1e-12)
    assert np.allclose(got_dx, want_dx, atol=1e-12)
    # the other states and their cross-covariances do not move
    others = [j for j in range(6) if j != i]
    assert np.array_equal(got_dx[others], dx[others])
    assert np.array_equal(got_p[np.ix_(others, others)], p[np.ix_(others, others)])


def test_the_prediction_is_f_p_ft_plus_q():
    rng = np.random.default_rng(2)
    p = _spd(rng)
    r = quat.to_matrix(quat.normalize(rng.normal(size=4)))
    dt, q_angle, q_bias = 0.01, 3e-4, 2e-8
    f = np.eye(6)
    f[:3, 3:] = -dt * r
    want = f @ p @ f.T + np.diag([q_angle * dt] * 3 + [q_bias * dt] * 3)
    got = np.empty((6, 6))
    kernel._predict_cov(p, r, dt, q_angle, q_bias, got, np.empty((2, 3, 3)))
    assert np.allclose(got, want, atol=1e-12)


def test_the_gain_solve_is_m_times_the_inverse():
    rng = np.random.default_rng(3)
    p, m = _spd(rng), rng.normal(size=(6, 6))
    out = np.empty((6, 6))
    kernel._solve_spd(p, m, out, np.zeros((6, 6)), np.empty(6))
    assert np.allclose(out, m @ np.linalg.inv(p), atol=1e-10)


def test_left_exp_and_log_are_inverse():
    rng = np.random.default_rng(4)
    q = quat.normalize(rng.normal(size=4))
    e = np.array([0.3, -0.2, 0.5])
    moved = np.empty(4)
    kernel._left_exp(q, *e, moved)
    assert np.allclose(moved, quat.normalize(quat.multiply(quat.from_rotvec(e), q)), atol=1e-12)
    back = np.empty(3)
    kernel._left_log(moved, q, back)
    assert np.allclose(back, e, atol=1e-12)


# --- what smoothing gives ---------------------------------------------------------------


def _static_with_bias(seconds: float = 20.0):
    return sim.simulate(
        sim.static(seconds, 100.0),
        gyr_errors=sim.SensorErrors(noise_density=np.radians(0.01), bias=BIAS_RAD_S),
        seed=2,
    )


def test_the_bias_is_known_from_the_first_sample_and_its_variance_shrinks():
    rec = _static_with_bias()
    fwd = Robust().run(rec)
    est = Smoother().run(rec)
    assert np.all(fwd.outputs["gyr_bias_rad_s"][0] == 0.0)
    err = np.degrees(est.outputs["gyr_bias_rad_s"] - BIAS_RAD_S)
    assert np.all(np.abs(err[0]) < 0.02) and np.all(np.abs(err[-1]) < 0.02)
    # the first sample's bias is known from the rest after it: its deviation far below
    # the prior's 0.5 deg/s (filtered alone, sample 0 keeps the prior)
    sd = np.degrees(est.outputs["gyr_bias_sd_rad_s"])
    assert np.all(sd[0] < 0.05)
    assert _rmse_deg(est, rec) < 0.05 < _rmse_deg(fwd, rec)


def test_it_is_acausal_and_better_than_the_causal_filter_on_simulated_motion():
    traj = sim.random_motion(30.0, 100.0, seed=4, max_rate_deg_s=150.0, bandwidth_hz=1.0,
                             translation_m=0.05)
    for frame in ("ENU", "NED"):
        rec = sim.simulate(traj, frame=frame, seed=0, gyr_errors=sim.SensorErrors(
            noise_density=np.radians(0.02), bias=BIAS_RAD_S))
        smooth = Smoother(frame=frame).run(rec)
        causal = Robust(frame=frame).run(rec)
        # measured 0.39 against 1.36 deg (ENU): no low-pass lag, the start's bias known
        assert _rmse_deg(smooth, rec, frame) < 0.5 * _rmse_deg(causal, rec, frame)
        assert np.allclose(np.linalg.norm(smooth.quat, axis=-1), 1.0)
    # the same motion in ENU and NED: the same error against each frame's truth
    rec, ned_rec = sim.simulate(traj, seed=0), sim.simulate(traj, frame="NED", seed=0)
    enu, ned = Smoother().run(rec), Smoother(frame="NED").run(ned_rec)
    assert abs(_rmse_deg(enu, rec) - _rmse_deg(ned, ned_rec, "NED")) < 0.05
    # a change after 20 s moves the estimates before it
    late = enu.quat[:2000]
    gyr = rec.gyr.copy()
    gyr[2000:] += np.radians(1.0)
    other = Smoother().run(gyr=gyr, acc=rec.acc, mag=rec.mag, t=rec.t).quat[:2000]
    assert np.degrees(quat.angle_between(late, other)).max() > 1e-3


def test_a_rest_takes_the_heading_of_its_whole_field():
    # at rest the heading is the field's mean over the rest (a window of 20 s each side,
    # robust's time constant, over 30 s here)
    rng = np.random.default_rng(5)
    rec = sim.simulate(sim.static(30.0, 100.0), seed=3)
    mag = rec.mag + rng.normal(scale=2.0, size=rec.mag.shape)  # uT, about 3 deg of heading
    est = Smoother().run(gyr=rec.gyr, acc=rec.acc, mag=mag, t=rec.t)
    heading = np.degrees(error_series(est.quat, rec.quat_true).heading_rad)
    # 3000 samples of ~2.6 deg noise: the mean is good to 0.05 deg; allow for the start
    assert np.abs(heading).max() < 0.3


def test_each_rest_takes_its_own_fields_heading():
    # three rests joined by turns; through the middle one the field changes by 3 uT east
    # (6 %: no detector sees it). The variances follow the orientation's walk at rest, so
    # the field keeps its 20 s time constant there: the change stays in its own rest. With
    # the motion's variances at rest (the time constant 50 times longer) every rest's
    # heading was the mean of all their fields: 0.84 deg off at the first and last
    steps = [sim.Hold(40), sim.Rotate((0, 0, 1), 90, 45), sim.Hold(40),
             sim.Rotate((0, 0, 1), -90, 45), sim.Hold(40)]
    change = sim.magnet_pass(62.0, 36.0, 3.0, (1.0, 0.0, 0.0))
    rec = sim.simulate(sim.rotation_sequence(steps, 100.0), seed=1, mag_disturbances=[change],
                       gyr_errors=sim.SensorErrors(noise_density=np.radians(0.01),
                                                   bias=np.radians([0.2, -0.1, 0.15])))
    est = Smoother().run(rec)
    heading = np.degrees(error_series(est.quat, rec.quat_true).heading_rad)
    for start_s, end_s in ((5.0, 38.0), (90.0, 120.0)):
        rest = (rec.t > start_s) & (rec.t < end_s)
        assert np.sqrt(np.mean(heading[rest] ** 2)) < 0.1
    middle = (rec.t > 50.0) & (rec.t < 78.0)
    assert np.sqrt(np.mean(heading[middle] ** 2)) > 2.0  # the change, undetectable, is followed


def test_a_gap_is_not_smoothed_across_and_bad_samples_are_flagged_not_lost():
    traj = sim.random_motion(30.0, 100.0, seed=6, max_rate_deg_s=100.0, bandwidth_hz=0.5)
    rec = sim.simulate(traj, seed=1)
    keep = (rec.t < 14.0) | (rec.t >= 16.0)  # 2 s removed
    t, gyr, acc, mag = rec.t[keep], rec.gyr[keep].copy(), rec.acc[keep].copy(), rec.mag[keep]
    gyr[300] = np.nan
    acc[500] = np.inf
    est = Smoother().run(gyr=gyr, acc=acc, mag=mag, t=t)
    assert est.quat.shape == (t.size, 4) and np.all(np.isfinite(est.quat))
    assert est.flags[300] & Flag.INVALID and est.flags[500] & Flag.INVALID
    gap = int(np.flatnonzero(np.diff(t) > 1.0)[0]) + 1
    assert est.flags[gap] & Flag.GAP
    # what comes after the gap does not reach before it
    gyr2 = gyr.copy()
    gyr2[gap + 100:] += np.radians(2.0)
    other = Smoother().run(gyr=gyr2, acc=acc, mag=mag, t=t)
    assert np.array_equal(other.quat[:gap], est.quat[:gap])
    err = np.degrees(error_series(est.quat, rec.quat_true[keep]).total_rad)
    assert np.sqrt(np.mean(err[200:] ** 2)) < 2.0
    # a clock going back: flagged, the filter restarted there, nothing non-finite
    t2 = rec.t.copy()
    t2[400] = t2[398]
    est2 = Smoother().run(gyr=rec.gyr, acc=rec.acc, mag=rec.mag, t=t2)
    assert est2.flags[400] & Flag.CLOCK and np.all(np.isfinite(est2.quat))
    with pytest.raises(ValueError, match="acc_unit='g'"):
        Smoother().run(gyr=rec.gyr, acc=rec.acc / 9.80665, mag=rec.mag, t=rec.t)


def test_without_a_magnetometer_it_is_6d_and_a_disturbed_field_is_left_out():
    traj = sim.random_motion(40.0, 100.0, seed=7, max_rate_deg_s=100.0, bandwidth_hz=0.5)
    rec = sim.simulate(traj, seed=2)
    six = Smoother().run(gyr=rec.gyr, acc=rec.acc, t=rec.t)
    incl = np.degrees(error_series(six.quat, rec.quat_true).inclination_rad)
    assert np.sqrt(np.mean(incl**2)) < 1.0
    # 10 s of a strong field fixed in the room (a magnet nearby, not one carried by the
    # sensor, which robust's hard-iron fit would rightly explain): flagged, not used
    mag = rec.mag.copy()
    mag[1500:2500] += quat.rotate_inverse(rec.quat_true[1500:2500], [60.0, 0.0, 0.0])
    est = Smoother().run(gyr=rec.gyr, acc=rec.acc, mag=mag, t=rec.t)
    assert np.count_nonzero(est.flags[1500:2500] & Flag.MAG_DISTURBED) > 900
    head = np.degrees(error_series(est.quat, rec.quat_true).heading_rad)
    assert np.abs(head).max() < 3.0


def test_offline_only_and_one_recording_per_run():
    est = methods.create("smoother", rate_hz=100.0)
    assert isinstance(est, Smoother)
    with pytest.raises(TypeError, match="offline method"):
        est.update(np.zeros(3), np.array([0.0, 0.0, 9.81]), np.array([0.0, 20.0, -40.0]))
    rec = _static_with_bias(3.0)
    first = est.run(rec)
    with pytest.raises(ValueError, match=r"one whole recording per run.*reset\(\)"):
        est.run(rec)
    est.reset()
    assert np.array_equal(est.run(rec).quat, first.quat)


def test_two_sensors_at_once_equal_each_alone():
    recs = [_static_with_bias(10.0), sim.simulate(sim.static(10.0, 100.0), seed=7)]
    both = Smoother().run(recs)
    for s, rec in enumerate(recs):
        alone = Smoother().run(rec)
        assert np.array_equal(both.quat[s], alone.quat)


def test_a_restart_starts_from_robusts_settled_window_carried_back_by_the_gyro():
    from margtrack.methods.smoother import _start_orientations

    traj = sim.constant_rotation((0.3, -0.5, 0.8), 90.0, 2.0, 100.0)  # 90 deg/s
    rec = sim.simulate(traj, seed=0, gyr_errors=sim.SensorErrors(bias=np.radians([1, 0, 0])))
    n = rec.t.size
    restart = np.zeros(n, dtype=bool)
    restart[100] = True
    initialising = np.zeros(n, dtype=bool)
    initialising[100:140] = True  # robust's window after the restart
    q_rob = quat.multiply(rec.quat_true, quat.from_rotvec([0.0, 0.0, 0.5]))  # heading off
    q_rob[140] = rec.quat_true[140]  # settled at the window's end
    bias = np.tile(np.radians([1.0, 0.0, 0.0]), (n, 1))
    got = _start_orientations(rec.t, rec.gyr, np.ones(n, dtype=bool), restart, initialising,
                              q_rob, bias)
    # 0.4 s at 90 deg/s carried back: the truth at the restart, to the integration's error
    assert np.degrees(quat.angle_between(got[100], rec.quat_true[100])) < 0.05
    # no window (sample 0): robust's own start row
    assert np.array_equal(got[0], q_rob[0])


def test_the_live_engine_refuses_it_before_the_first_sample():
    from margtrack.live.engine import Engine
    from margtrack.live.replay import ReplaySource

    rec = _static_with_bias(1.0)
    source = ReplaySource(rec.t, rec.gyr[None], rec.acc[None], rec.mag[None], ["s0"])
    with pytest.raises(ValueError, match=r"'smoother' is offline.*'robust'"):
        Engine(source.info, "smoother")


def test_the_replaced_robust_offline_names_the_smoother():
    # the blend of robust passes it replaces lost on simulated disturbances and after gaps
    # (docs/methods.md); a script that still names it is told what to use, not run
    with pytest.raises(ValueError, match=r"'robust-offline' was replaced by 'smoother'.*use"):
        methods.create("robust-offline")



# --- the accelerometer's low-pass in the level frame -------------------------------------


def test_the_low_pass_is_butterworth_forwards_then_backwards_in_the_level_frame():
    from scipy.signal import lfilter, lfilter_zi

    from margtrack.methods.robust.gains import butterworth_coefficients

    rec = sim.simulate(sim.random_motion(10.0, 100.0, seed=3, translation_m=0.2), seed=1)
    b0, a1, a2 = butterworth_coefficients(0.01, np.sqrt(2.0) / (2.0 * np.pi * 0.5))
    b, a = [b0, 2.0 * b0, b0], [1.0, a1, a2]
    use = np.ones(rec.t.size, dtype=bool)
    restart = np.zeros(rec.t.size, dtype=bool)
    restart[600] = True  # two stretches, each filtered alone

    def oracle(q, acc):
        level = quat.rotate(q, acc)
        fwd = lfilter(b, a, level, axis=0, zi=np.outer(lfilter_zi(b, a), level[0]))[0]
        back = lfilter(b, a, fwd[::-1], axis=0, zi=np.outer(lfilter_zi(b, a), fwd[-1]))[0]
        return quat.rotate_inverse(q, back[::-1])

    got = np.empty_like(rec.acc)
    kernel.lowpassed_acc(rec.quat_true, rec.acc, use, restart, b0, a1, a2, got)
    for part in (slice(0, 600), slice(600, None)):
        np.testing.assert_allclose(got[part], oracle(rec.quat_true[part], rec.acc[part]),
                                   atol=1e-9)
    # gravity alone, carried by the true orientation, comes through whole
    gravity = quat.rotate_inverse(rec.quat_true, [0.0, 0.0, 9.81])
    kernel.lowpassed_acc(rec.quat_true, gravity, use, restart, b0, a1, a2, got)
    np.testing.assert_allclose(got, gravity, atol=1e-9)
    # a sample not used enters as the one before it: a nan there changes nothing else
    acc = rec.acc.copy()
    acc[300] = np.nan
    use[300] = False
    held = acc.copy()
    held[300] = quat.rotate_inverse(rec.quat_true[300], quat.rotate(rec.quat_true[299],
                                                                      rec.acc[299]))
    kernel.lowpassed_acc(rec.quat_true, acc, use, restart, b0, a1, a2, got)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got[:600], oracle(rec.quat_true[:600], held[:600]), atol=1e-9)


def test_a_swinging_limbs_acceleration_is_kept_out_of_the_inclination():
    # a sensor 0.6 m down a limb swinging 60 deg at 1 Hz: its linear acceleration turns with
    # it, and weighed sample by sample it leaks into the inclination (and through the bias
    # into the drift); low-passed in robust's level frame first it does not. Measured over
    # these 30 s: 0.99 deg against 2.63 without the low-pass
    rec = sim.simulate(sim.limb_swing(30.0, 100.0, 60.0, 1.0, 0.6), seed=0,
                       gyr_errors=sim.SensorErrors(noise_density=np.radians(0.01),
                                                   bias=np.radians([0.2, -0.1, 0.15])))
    low = Smoother().run(rec)
    raw = Smoother(acc_lowpass_hz=0.0).run(rec)
    incl = [np.degrees(np.sqrt(np.mean(error_series(e.quat, rec.quat_true).inclination_rad**2)))
            for e in (low, raw)]
    assert incl[0] < 0.5 * incl[1], incl


def test_a_low_pass_at_or_above_half_the_sample_rate_is_refused_with_the_fix():
    rec = _static_with_bias(2.0)  # 100 Hz
    with pytest.raises(ValueError, match=r"acc_lowpass_hz=60 Hz .*half the sample rate.*0 for"):
        Smoother(acc_lowpass_hz=60.0).run(rec)
