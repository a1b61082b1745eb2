"""MarinsEkf (001): contract, frames, 001 5.2's convergence test, covariance health, errors."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import frames, sim
from margtrack import quaternion as quat
from margtrack.bench.experiments.kalman_marins import STEADY_STATE, convergence_run
from margtrack.estimator.compiled import CompiledState
from margtrack.methods.ekf import MarinsEkf, MarinsEkfParams, kernel


def _cov(state, s=0):
    """Sensor s's 7 x 7 covariance from a state (stored row-major in the row)."""
    return state.get("cov")[s].reshape(7, 7)


def _noisy_recording(seconds=3.0, rate=100.0, seed=2, frame="ENU"):
    traj = sim.random_motion(seconds, rate, seed=seed, max_rate_deg_s=150.0, translation_m=0.02)
    return sim.simulate(
        traj, frame=frame, gyr_errors=sim.SensorErrors.mems_gyr(),
        acc_errors=sim.SensorErrors.mems_acc(), mag_errors=sim.SensorErrors.mems_mag(), seed=seed,
    )


@pytest.mark.parametrize("approach", [1, 2])
def test_update_n_times_equals_run_once(approach):
    rec = _noisy_recording()
    batch = MarinsEkf(approach=approach).run(rec)
    live = MarinsEkf(approach=approach, rate_hz=100.0)
    stepped = np.array([live.update(rec.gyr[i], rec.acc[i], rec.mag[i]) for i in range(300)])
    np.testing.assert_allclose(stepped, batch.quat[:300], atol=1e-12)
    np.testing.assert_allclose(live.state.get("gyr_est_rad_s")[0],
                               batch.outputs["gyr_est_rad_s"][299], atol=1e-12)
    np.testing.assert_allclose(np.diagonal(_cov(live.state)), batch.outputs["cov_diag"][299],
                               rtol=1e-12, atol=0)


@pytest.mark.parametrize("approach", [1, 2])
def test_two_half_runs_joined_through_state_equal_one_run(approach):
    rec = _noisy_recording(4.0)
    whole = MarinsEkf(approach=approach).run(rec)
    first = MarinsEkf(approach=approach)
    a = first.run(rec.slice(0, 170))
    second = MarinsEkf(approach=approach)
    second.state = first.state  # resume in a new object: dip, rate and covariance carried
    b = second.run(rec.slice(170))
    for key in ("gyr_est_rad_s", "cov_diag", "iterations", "degenerate"):
        np.testing.assert_allclose(np.concatenate([a.outputs[key], b.outputs[key]]),
                                   whole.outputs[key], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.concatenate([a.quat, b.quat]), whole.quat, atol=1e-12)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
@pytest.mark.parametrize("approach", [1, 2])
def test_noise_free_static_pose_is_exact_in_both_frames(frame, approach):
    q0 = quat.from_euler([2.1, -0.4, 0.9])
    rec = sim.simulate(sim.static(2.0, 100.0, q0=q0), frame=frame, seed=0)
    est = MarinsEkf(frame=frame, approach=approach).run(rec)
    assert est.frame == frame
    assert np.max(quat.angle_between(est.quat, rec.quat_true)) < 1e-12
    assert np.max(np.abs(est.outputs["gyr_est_rad_s"])) < 1e-12


@pytest.mark.parametrize("frame", ["ENU", "NED"])
@pytest.mark.parametrize("approach", [1, 2])
def test_noise_free_motion_tracks_truth_within_the_models_half_sample_lag(frame, approach):
    # the gyro sample is the rate over the past interval (margtrack's timing); the model
    # integrates the state rate from the start of the interval, the filter blends the two
    # ends: an orientation lag of at most half a sample of rotation, h |ω| / 2
    h = 0.01
    rec = sim.simulate(sim.random_motion(20.0, 1 / h, seed=3, max_rate_deg_s=100.0),
                       frame=frame, seed=1)
    est = MarinsEkf(frame=frame, approach=approach).run(rec)
    err = quat.angle_between(est.quat, rec.quat_true)
    assert err.max() < 0.5 * h * np.linalg.norm(rec.gyr, axis=1).max()
    assert not est.outputs["degenerate"].any()


@pytest.mark.parametrize("frame", ["NED", "ENU"])
def test_001_5_2_converges_from_all_ones_within_half_a_second(frame):
    # ideal data, body at rest 120 deg about [1, 1, 1]: steady state [0, 0, 0, .5, .5, .5, .5]
    t, state = convergence_run(frame, 100.0, 1.0)
    np.testing.assert_allclose(STEADY_STATE[3:],
                               quat.from_axis_angle([1, 1, 1], np.radians(120.0)), atol=1e-15)
    np.testing.assert_array_equal(state[0], np.ones(7))
    err = np.abs(state - STEADY_STATE).max(axis=1)
    assert err[0] == 1.0
    assert np.all(err[t >= 0.5] < 1e-3)


@pytest.mark.parametrize("approach", [1, 2])
def test_covariance_stays_symmetric_positive_definite_over_one_hour(approach):
    traj = sim.random_motion(3600.0, 25.0, seed=7, max_rate_deg_s=200.0, bandwidth_hz=1.0,
                             translation_m=0.05)
    rec = sim.simulate(traj, frame="ENU", gyr_errors=sim.SensorErrors.mems_gyr(),
                       acc_errors=sim.SensorErrors.mems_acc(),
                       mag_errors=sim.SensorErrors.mems_mag(), seed=7)
    est = MarinsEkf(approach=approach)
    for chunk in np.array_split(np.arange(rec.n_samples), 6):
        est.run(rec.slice(chunk[0], chunk[-1] + 1))
        p = _cov(est.state)
        assert np.max(np.abs(p - p.T)) <= 1e-12 * np.max(np.abs(p))
        eig = np.linalg.eigvalsh(p)
        assert eig[0] > 0.0
        assert eig[0] > 1e-12 * eig[-1]  # far above rounding (~1e-16 of the largest)
    assert np.all(np.isfinite(est.state.get("quat")))
    assert np.linalg.norm(est.state.get("quat")[0]) == pytest.approx(1.0, abs=1e-15)


def test_degenerate_samples_are_flagged_and_corrected_by_the_gyroscope_alone():
    rec = _noisy_recording(1.0)
    acc, mag = rec.acc.copy(), rec.mag.copy()
    acc[40] = 0.0
    mag[50] = 0.0
    acc[60] = mag[60]  # parallel to the field
    est = MarinsEkf().run(gyr=rec.gyr, acc=acc, mag=mag, t=rec.t)
    flags = est.outputs["degenerate"]
    assert (flags[40], flags[50], flags[60]) == (kernel.ZERO_ACC, kernel.ZERO_MAG,
                                                 kernel.PARALLEL)
    assert np.count_nonzero(flags) == 3
    assert np.all(est.outputs["iterations"][[40, 50, 60]] == 0)
    # sample 40 again from the state before it, with H = [I₃ 0]: the textbook update
    part = MarinsEkf()
    part.run(gyr=rec.gyr[:40], acc=acc[:40], mag=mag[:40], t=rec.t[:40])
    s = part.state
    x0 = np.r_[s.get("gyr_est_rad_s")[0], s.get("quat")[0]]
    xp, f, g, d, qn = np.empty(7), np.empty((7, 7)), np.empty((4, 3)), np.empty((4, 3)), \
        np.empty((7, 7))
    p = part.params
    tau = p.axis_values("tau_s")
    kernel.transition(x0, 0.01, tau, xp, f, g, d)
    kernel.process_noise(g, 0.01, tau, p.axis_values("rate_noise_rad_s_sqrt_hz") ** 2, qn)
    pp = f @ _cov(s) @ f.T + qn
    hm = np.c_[np.eye(3), np.zeros((3, 4))]
    r = np.diag(p.axis_values("gyr_noise_rad_s_sqrt_hz") ** 2 / 0.01)
    gain = pp @ hm.T @ np.linalg.inv(hm @ pp @ hm.T + r)
    x = xp + gain @ (rec.gyr[40] - xp[:3])
    np.testing.assert_allclose(est.quat[40], x[3:] / np.linalg.norm(x[3:]), atol=1e-13)
    np.testing.assert_allclose(est.outputs["gyr_est_rad_s"][40], x[:3], atol=1e-12)


def test_measurement_sign_follows_the_prediction_through_half_turns():
    # start at -q0 and turn through 360 deg: Gauss-Newton gives w >= 0, the filter keeps
    # its own sign (002's closing remark) and the output is continuous
    steps = [sim.Rotate((1.0, 0.0, 0.0), 360.0, 90.0)]
    rec = sim.simulate(sim.rotation_sequence(steps, 100.0), frame="ENU", seed=0)
    est = MarinsEkf()
    est.reset(-rec.quat_true[0])
    out = est.run(rec)
    assert np.max(quat.angle_between(out.quat, rec.quat_true)) < 0.5 * 0.01 * np.radians(90.0)
    assert np.min(np.sum(out.quat[1:] * out.quat[:-1], axis=1)) > 0.99  # no sign jumps
    assert out.quat[0] @ rec.quat_true[0] < 0.0
    assert out.quat[-1] @ rec.quat_true[-1] < 0.0  # still the truth's opposite sign
    assert out.quat[-1] @ out.quat[0] < 0.0  # a full turn flips q (2π ↦ -1)


def test_several_sensors_in_one_run_equal_each_sensor_alone():
    recs = [_noisy_recording(2.0, seed=s) for s in (1, 2)]
    t = recs[0].t
    both = MarinsEkf().run(gyr=np.stack([r.gyr for r in recs]),
                           acc=np.stack([r.acc for r in recs]),
                           mag=np.stack([r.mag for r in recs]), t=t)
    for s, r in enumerate(recs):
        alone = MarinsEkf().run(gyr=r.gyr, acc=r.acc, mag=r.mag, t=t)
        np.testing.assert_allclose(both.quat[s], alone.quat, atol=1e-15)


def test_dip_is_measured_from_the_first_sample_or_taken_from_the_parameter():
    rec = sim.simulate(sim.static(0.5, 100.0, q0=quat.from_euler([0.3, 0.2, -0.1])),
                       frame="NED", dip_deg=55.0, seed=0)
    est = MarinsEkf(frame="NED")
    est.run(rec)
    assert np.degrees(est.state.get("dip_rad")[0, 0]) == pytest.approx(55.0, abs=1e-10)
    # the shared reference dip is the filter's (the screening's gate opened: 35 deg off
    # would otherwise reject the field, which is the screening's job, not this test's)
    wrong = MarinsEkf(frame="NED", mag_dip_ref_deg=20.0, mag_dip_tol_deg=360.0)
    out = wrong.run(rec)
    assert np.isnan(wrong.state.get("dip_rad")[0, 0])  # not measured when given
    # a wrong dip makes the Gauss-Newton measurement biased: the estimate leaves the truth
    assert np.max(quat.angle_between(out.quat, rec.quat_true)) > np.radians(1.0)


def test_iterations_are_capped_and_approach_1_runs_none():
    rec = _noisy_recording(2.0)
    a2 = MarinsEkf(gn_max_iterations=2).run(rec).outputs["iterations"]
    assert a2[0] == 0 and a2[1:].min() >= 1 and a2.max() == 2
    assert not MarinsEkf(approach=1).run(rec).outputs["iterations"].any()


def test_real_data_slice_beats_its_two_sources(broad_folder):
    # BROAD trial 01, first 50 s (motion starts after 34 s): the filter beats gyro
    # integration (its rate input) and the Gauss-Newton fit (its quaternion input) alone
    from margtrack.accuracy import error_series, summarize
    from margtrack.io import read_broad
    from margtrack.methods.gyro import GyroIntegration
    from margtrack.single_frame.gauss_newton import GaussNewton

    rec = read_broad(broad_folder / "01_undisturbed_slow_rotation_A.hdf5").slice(0, 14300)

    def total(q):
        return summarize(error_series(q, rec.quat_true, "ENU", rec.frame),
                         rec.movement).total_rmse_deg

    ekf = total(MarinsEkf().run(rec).quat)
    gyro = total(GyroIntegration().run(rec).quat)
    fit = total(GaussNewton().run(rec).quat)
    assert ekf < 0.7 * min(gyro, fit)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("approach", 3, r"parameter approach must be a finite number, >= 1 and <= 2"),
        ("approach", 1.5, "parameter approach must be a whole number"),
        ("tau_s", 0.0, "parameter tau_s must be a finite number, > 0 s"),
        ("tau_s", (0.1, 0.2), "one per body axis"),
        ("tau_s", (0.1, -0.2, 0.3), "parameter tau_s must be a finite number, > 0 s"),
        ("rate_noise_rad_s_sqrt_hz", float("nan"), "parameter rate_noise_rad_s_sqrt_hz must"),
        ("gyr_noise_rad_s_sqrt_hz", -1.0, "parameter gyr_noise_rad_s_sqrt_hz must be"),
        ("quat_noise_per_sqrt_hz", 0.0, "parameter quat_noise_per_sqrt_hz must .* > 0"),
        ("mag_noise_rel_sqrt_hz", 0.0, "parameter mag_noise_rel_sqrt_hz must .* > 0"),
        ("mag_weight", -1.0, "parameter mag_weight must be"),
        ("gn_max_iterations", 0, r"parameter gn_max_iterations must .* >= 1 and <= 1000"),
        ("gn_tolerance", -1e-3, "parameter gn_tolerance must be a finite number, >= 0"),
        ("mag_dip_ref_deg", 95.0, r"parameter mag_dip_ref_deg must .* >= -90 and <= 90"),
        ("init_quat_std", 3.0, r"parameter init_quat_std must .* > 0 and <= 2"),
        ("frame", "NWU", "frame must be 'NED' or 'ENU'"),
    ],
)
def test_bad_parameters_are_refused_with_the_allowed_range(field, value, message):
    with pytest.raises(ValueError, match=message):
        MarinsEkfParams(**{field: value})


def test_per_axis_parameters_are_accepted():
    p = MarinsEkfParams(tau_s=(0.1, 0.2, 0.3))
    np.testing.assert_array_equal(p.axis_values("tau_s"), [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(p.axis_values("gyr_noise_rad_s_sqrt_hz"),
                                  np.full(3, p.gyr_noise_rad_s_sqrt_hz))


def test_bad_input_and_state_are_refused():
    rec = _noisy_recording(0.5)
    with pytest.raises(ValueError, match="needs a magnetometer"):
        MarinsEkf().run(rec.without_mag())
    est = MarinsEkf()
    est.run(rec)
    before = est.state
    with pytest.raises(ValueError, match=r"the state rows must have shape \(S, \d+\)"):
        est.state = CompiledState(np.zeros((1, 10)), np.array([10.0]))
    state = est.state
    offset, _ = MarinsEkf.state_layout["quat"]
    state.rows[:, offset : offset + 4] = 0.0
    with pytest.raises(ValueError, match="quaternion must be finite and non-zero"):
        est.state = state
    np.testing.assert_array_equal(est.state.rows, before.rows)  # left as it was
    assert frames.check_frame(est.params.frame) == "ENU"


def test_interval_constants_survive_timestamp_rounding_and_follow_a_new_rate():
    """The interval's constants (a dozen exp/expm1) are kept while the interval moves only
    by its timestamps' rounding (``DT_REUSE_REL``) and renewed when the rate changes; the
    estimate equals the one of exactly regular intervals to the constants' error."""
    rec = _noisy_recording(3.0, rate=100.0)
    n = rec.t.shape[0]
    t_rounded = 1000.0 + np.arange(n) * 0.01  # intervals differ by ~1e-13 s
    assert np.ptp(np.diff(t_rounded)) > 0.0
    est = MarinsEkf()
    out = est.run(gyr=rec.gyr, acc=rec.acc, mag=rec.mag, t=t_rounded)
    row = est.state.rows[0]
    assert row[kernel.E_DT] == t_rounded[1] - t_rounded[0]  # computed once, then kept
    regular = MarinsEkf().run(gyr=rec.gyr, acc=rec.acc, mag=rec.mag, t=np.arange(n) * 0.01)
    np.testing.assert_allclose(out.quat, regular.quat, rtol=0, atol=1e-9)
    # a new rate renews them
    t_next = t_rounded[-1] + 0.02 * np.arange(1, 11)
    est.run(gyr=rec.gyr[:10], acc=rec.acc[:10], mag=rec.mag[:10], t=t_next)
    assert est.state.rows[0][kernel.E_DT] == pytest.approx(0.02, rel=1e-9)
