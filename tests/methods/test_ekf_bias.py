"""MarinsEkf with ``bias_states``: the gyro bias recovered, contract, covariance health, errors."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.estimator import Flag
from margtrack.estimator import skeleton as kc
from margtrack.methods.ekf import MarinsEkf, MarinsEkfParams
from margtrack.methods.ekf import bias_kernel as ekf_bias

BIAS_RAD_S = np.radians([1.0, -0.7, 0.5])


def _biased(seconds, rate=100.0, seed=3, noise=True, bias=BIAS_RAD_S):
    traj = sim.random_motion(seconds, rate, seed=seed, max_rate_deg_s=100.0, translation_m=0.02)
    gyr_errors = (sim.SensorErrors(bias=tuple(bias), noise_density=3e-4) if noise
                  else sim.SensorErrors(bias=tuple(bias)))
    return sim.simulate(traj, frame="ENU", gyr_errors=gyr_errors,
                        acc_errors=sim.SensorErrors.mems_acc(),
                        mag_errors=sim.SensorErrors.mems_mag(), seed=seed)


def _cov(est, n=10):
    return est.state.get("cov")[0].reshape(n, n)


def test_a_constant_bias_is_recovered_and_the_attitude_error_falls():
    # 2 min of motion at 100 Hz with a 1 deg/s bias (no still start: nothing to null)
    rec = _biased(120.0)
    plain = MarinsEkf().run(rec)
    est = MarinsEkf(bias_states=True)
    out = est.run(rec)
    b, sd = out.outputs["gyr_bias_rad_s"], out.outputs["gyr_bias_sd_rad_s"]
    # after 120 s each axis within 0.1 deg/s (measured 0.05, 0.04, 0.01) and within 3 sd
    err = np.degrees(np.abs(b[-1] - BIAS_RAD_S))
    assert np.all(err < 0.1), err
    assert np.all(np.abs(b[-1] - BIAS_RAD_S) < 3.0 * sd[-1])
    # the uncertainty shrinks from the initial 0.01 rad/s as the bias is learned
    np.testing.assert_allclose(sd[0], 0.01, rtol=1e-3)
    assert np.all(sd[-1] < 0.25 * sd[0])
    # the state: the bias of the raw rate is null + b (no null here) with that sd
    np.testing.assert_array_equal(est.gyr_bias_rad_s[0], b[-1])
    np.testing.assert_array_equal(est.gyr_bias_sd_rad_s[0], sd[-1])
    np.testing.assert_array_equal(est.state.get("bias_state_rad_s")[0], b[-1])
    np.testing.assert_allclose(out.outputs["cov_diag"][:, 7:], sd**2, rtol=1e-12)

    def rms_deg(q):
        e = np.degrees(quat.angle_between(q[3000:], rec.quat_true[3000:]))
        return np.sqrt(np.mean(e**2))

    # 001's model takes the bias as signal: 11.2 deg against 3.4 with the bias state
    assert rms_deg(out.quat) < 0.5 * rms_deg(plain.quat)


def test_the_still_start_null_is_part_of_the_reported_bias():
    rec = _biased(20.0, seed=5)
    still = sim.simulate(sim.static(3.0, 100.0, q0=rec.quat_true[0]), frame="ENU",
                         gyr_errors=sim.SensorErrors(bias=tuple(BIAS_RAD_S)), seed=5)
    gyr = np.concatenate([still.gyr, rec.gyr])
    acc, mag = np.concatenate([still.acc, rec.acc]), np.concatenate([still.mag, rec.mag])
    t = np.arange(len(gyr)) / 100.0
    out = MarinsEkf(bias_states=True).run(gyr=gyr, acc=acc, mag=mag, t=t)
    null, b = out.outputs["gyr_null_rad_s"], out.outputs["gyr_bias_rad_s"]
    # the null: the still start's mean rate (its noise averaged over 3 s)
    np.testing.assert_allclose(null[-1], BIAS_RAD_S, atol=1e-4)
    np.testing.assert_array_equal(null[:300].any(axis=1), True)  # subtracted while still
    # b starts from the null (not from 0): the reported bias stays within its sd of the
    # truth and nearer to it than without the null (b learning the whole bias)
    sd = out.outputs["gyr_bias_sd_rad_s"]
    assert np.all(np.abs(b[-1] - BIAS_RAD_S) < 3.0 * sd[-1])
    raw = MarinsEkf(bias_states=True, gyr_null_rest_s=0.0).run(gyr=gyr, acc=acc, mag=mag, t=t)
    assert not raw.outputs["gyr_null_rad_s"].any()
    err = np.linalg.norm(b[300:] - BIAS_RAD_S, axis=1)
    err_raw = np.linalg.norm(raw.outputs["gyr_bias_rad_s"][300:] - BIAS_RAD_S, axis=1)
    assert np.mean(err) < 0.5 * np.mean(err_raw), (np.mean(err), np.mean(err_raw))


@pytest.mark.parametrize("approach", [1, 2])
def test_update_n_times_equals_run_once(approach):
    rec = _biased(3.0)
    batch = MarinsEkf(approach=approach, bias_states=True).run(rec)
    live = MarinsEkf(approach=approach, bias_states=True, rate_hz=100.0)
    stepped = np.array([live.update(rec.gyr[i], rec.acc[i], rec.mag[i]) for i in range(300)])
    np.testing.assert_allclose(stepped, batch.quat[:300], atol=1e-12)
    np.testing.assert_allclose(live.gyr_bias_rad_s[0], batch.outputs["gyr_bias_rad_s"][299],
                               atol=1e-12)
    np.testing.assert_allclose(np.diagonal(_cov(live)), batch.outputs["cov_diag"][299],
                               rtol=1e-12, atol=0)


def test_two_half_runs_joined_through_state_equal_one_run():
    rec = _biased(4.0)
    whole = MarinsEkf(bias_states=True).run(rec)
    first = MarinsEkf(bias_states=True)
    a = first.run(rec.slice(0, 170))
    second = MarinsEkf(bias_states=True)
    second.state = first.state
    b = second.run(rec.slice(170))
    for key in ("gyr_bias_rad_s", "gyr_bias_sd_rad_s", "cov_diag", "gyr_est_rad_s"):
        np.testing.assert_allclose(np.concatenate([a.outputs[key], b.outputs[key]]),
                                   whole.outputs[key], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.concatenate([a.quat, b.quat]), whole.quat, atol=1e-12)


def test_several_sensors_in_one_run_equal_each_sensor_alone():
    recs = [_biased(2.0, seed=s) for s in (1, 2)]
    t = recs[0].t
    both = MarinsEkf(bias_states=True).run(
        gyr=np.stack([r.gyr for r in recs]), acc=np.stack([r.acc for r in recs]),
        mag=np.stack([r.mag for r in recs]), t=t)
    for s, r in enumerate(recs):
        alone = MarinsEkf(bias_states=True).run(gyr=r.gyr, acc=r.acc, mag=r.mag, t=t)
        np.testing.assert_allclose(both.quat[s], alone.quat, atol=1e-15)
        np.testing.assert_allclose(both.outputs["gyr_bias_rad_s"][s],
                                   alone.outputs["gyr_bias_rad_s"], atol=1e-15)


@pytest.mark.parametrize("approach", [1, 2])
def test_covariance_stays_symmetric_positive_definite_over_one_hour_at_100_hz(approach):
    traj = sim.random_motion(3600.0, 100.0, seed=7, max_rate_deg_s=200.0, bandwidth_hz=1.0,
                             translation_m=0.05)
    rec = sim.simulate(traj, frame="ENU", gyr_errors=sim.SensorErrors.mems_gyr(),
                       acc_errors=sim.SensorErrors.mems_acc(),
                       mag_errors=sim.SensorErrors.mems_mag(), seed=7)
    est = MarinsEkf(approach=approach, bias_states=True)
    for chunk in np.array_split(np.arange(rec.n_samples), 4):
        est.run(rec.slice(chunk[0], chunk[-1] + 1))
        p = _cov(est)
        np.testing.assert_array_equal(p, p.T)
        eig = np.linalg.eigvalsh(p)
        assert eig[0] > 1e-12 * eig[-1]  # far above rounding (~1e-16 of the largest)
    assert np.all(np.isfinite(est.state.get("quat")))
    assert np.all(est.gyr_bias_sd_rad_s > 0.0)


def test_a_restart_keeps_the_bias_and_its_covariance_block():
    rec = _biased(8.0, seed=4)
    keep = np.ones(rec.n_samples, dtype=bool)
    keep[500:600] = False  # a 1 s gap
    t, gyr, acc, mag = rec.t[keep], rec.gyr[keep], rec.acc[keep], rec.mag[keep]
    est = MarinsEkf(bias_states=True)
    est.run(gyr=gyr[:500], acc=acc[:500], mag=mag[:500], t=t[:500])
    b, p = est.state.get("bias_state_rad_s")[0], _cov(est)
    out = est.run(gyr=gyr[500:], acc=acc[500:], mag=mag[500:], t=t[500:])
    assert out.flags[0] & Flag.GAP
    # the restart sample, the window's last (nothing integrated): b and its block as they
    # were, the rest fresh
    i = int(np.argmin(out.flags & Flag.INITIALISING))
    assert i > 0
    np.testing.assert_allclose(out.outputs["gyr_bias_rad_s"][i], b, atol=1e-15)
    pr = est.params
    init = np.r_[np.full(3, pr.init_rate_std_rad_s**2), np.full(4, pr.init_quat_std**2)]
    np.testing.assert_array_equal(out.outputs["cov_diag"][i, :7], init)
    np.testing.assert_array_equal(out.outputs["cov_diag"][i, 7:], np.diagonal(p)[7:])


def test_the_option_off_is_the_seven_state_filter_and_the_layouts_follow_it():
    assert MarinsEkf.state_layout["cov"][1] == 49  # on the class: 001's filter
    on, off = MarinsEkf(bias_states=True), MarinsEkf()
    assert on.kernel is ekf_bias and off.state_layout["cov"] == MarinsEkf.state_layout["cov"]
    assert dict(on.outputs_layout)["cov_diag"] == 10 and "gyr_bias_rad_s" not in dict(
        off.outputs_layout)
    rec = _biased(1.0)
    out = on.run(rec)
    assert on.state.rows.shape == (1, ekf_bias.N_ROW)
    assert out.outputs["cov_diag"].shape == (rec.n_samples, 10)
    # changing the mode while a state is held would misread it
    with pytest.raises(ValueError, match="bias_states cannot change while running; reset"):
        on.set_params(bias_states=False)
    on.reset()
    on.set_params(bias_states=False)
    np.testing.assert_array_equal(on.run(rec).quat, off.run(rec).quat)
    # a 7-state row is refused by the 10-state filter
    with pytest.raises(ValueError, match=r"the state rows must have shape \(S, \d+\)"):
        MarinsEkf(bias_states=True).state = off.state


def test_kernel_stays_finite_for_absurd_finite_input():
    n = 6
    gyr = np.zeros((n, 3))
    gyr[2] = [1e300, -1e300, 1e300]
    gyr[3] = [1e308, 0.0, 0.0]
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    acc[4] = [1e300, 1e-300, 0.0]
    mag = np.tile([0.0, 20.0, -40.0], (n, 1))
    mag[5] = [1e-320, 0.0, 1e300]
    dt = np.array([0.0, 0.01, 1e10, 0.01, 0.01, 0.01])
    for approach in (1, 2):
        coef = MarinsEkf(approach=approach, bias_states=True)._coefs[kc.N_SCOEF:]
        row = np.zeros(ekf_bias.N_ROW)
        ekf_bias._start(row, coef, True, 1.0, 0.0, 0.0, 0.0)
        q, x = np.empty((n, 4)), np.empty((n, ekf_bias.N_OUT))
        for i in range(n):
            ekf_bias._step(row, coef, dt[i], *gyr[i], *acc[i], *mag[i], True, q[i], x[i])
        assert np.all(np.isfinite(q)) and np.allclose(np.linalg.norm(q, axis=-1), 1.0)
        assert np.all(np.isfinite(x)) and np.all(np.isfinite(row[ekf_bias.E_P:][:100]))


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("bias_states", 1, "parameter bias_states must be true or false"),
        ("gyr_bias_walk_rad_s_sqrt_s", -1e-4, "parameter gyr_bias_walk_rad_s_sqrt_s must be"),
        ("gyr_bias_walk_rad_s_sqrt_s", (1e-4, 1e-4), "one per body axis"),
        ("init_bias_std_rad_s", 0.0, r"parameter init_bias_std_rad_s must .* > 0 rad/s"),
        ("init_bias_std_rad_s", float("inf"), "parameter init_bias_std_rad_s must be"),
    ],
)
def test_bad_bias_parameters_are_refused(field, value, message):
    with pytest.raises(ValueError, match=message):
        MarinsEkfParams(**{field: value})
