"""Gradient filter: the estimator contract, behaviour on simulated and real data, parameters."""

from __future__ import annotations

import re

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.accuracy import error_series, summarize
from margtrack.bench.broad import evaluate_recording
from margtrack.estimator import Flag
from margtrack.io import broad_trials, read_broad
from margtrack.methods.gradient import DEFAULT_BETA, Gradient, GradientParams
from margtrack.recording import Recording
from margtrack.sim import (
    SensorErrors,
    random_motion,
    simulate,
    simulate_default,
    static,
    vertical_tilt,
)


def _mems():
    return {
        "gyr_errors": SensorErrors.mems_gyr(),
        "acc_errors": SensorErrors.mems_acc(),
        "mag_errors": SensorErrors.mems_mag(),
    }


@pytest.fixture(scope="module")
def noisy():
    return simulate_default(duration_s=20.0, rate_hz=100.0, seed=4)


def test_n_updates_equal_one_run_and_two_halves(noisy):
    rec = noisy.slice(0, 400)
    whole = Gradient().run(rec)
    live = Gradient(rate_hz=100.0)
    stepped = np.array([live.update(rec.gyr[i], rec.acc[i], rec.mag[i]) for i in range(400)])
    assert np.max(np.abs(stepped - whole.quat)) < 1e-12
    first = Gradient()
    first.run(rec.slice(0, 150))
    second = Gradient()
    second.state = first.state  # checkpoint and resume in another instance
    rest = second.run(rec.slice(150, 400))
    assert np.max(np.abs(rest.quat - whole.quat[150:])) < 1e-12
    for key in ("euler_rad", "lin_acc_earth_m_s2", "gravity_body_m_s2"):
        assert np.max(np.abs(rest.outputs[key] - whole.outputs[key][150:])) < 1e-12


def test_fixed_reference_lives_in_the_state(noisy):
    rec = noisy.slice(0, 300)
    whole = Gradient(mag_objective="fixed").run(rec)
    first = Gradient(mag_objective="fixed")
    first.run(rec.slice(0, 100))
    ref = first.state.get("mag_ref")
    # a unit reference with the simulator's 60 deg dip, up to the initial tilt error
    assert np.hypot(*ref[0]) == pytest.approx(1.0, abs=1e-9)
    assert np.degrees(np.arctan2(-ref[0, 1], ref[0, 0])) == pytest.approx(60.0, abs=3.0)
    rest = first.run(rec.slice(100, 300))
    assert np.max(np.abs(rest.quat - whole.quat[100:])) < 1e-12


def test_sensors_in_one_call_equal_separate_runs(noisy):
    other = simulate_default(3.0, 100.0, seed=9).slice(0, 300)
    recs = [noisy.slice(0, 300), Recording(t=noisy.t[:300], gyr=other.gyr, acc=other.acc,
                                           mag=other.mag)]
    both = Gradient().run(recs)
    for s, rec in enumerate(recs):
        alone = Gradient().run(rec)
        np.testing.assert_array_equal(both.quat[s], alone.quat)


def test_the_correction_halves_the_inclination_error_of_pure_gyro_integration():
    # the error bounds against the truth in both frames are tests/test_registry_truth.py's;
    # here: beta = 0 (pure gyro integration, bias 0.4 deg/s) drifts to twice the error
    rec = simulate(random_motion(30.0, 100.0, seed=2), seed=2, **_mems())
    s = summarize(error_series(Gradient().run(rec).quat, rec.quat_true), rec.t > 5.0)
    g = summarize(error_series(Gradient(beta=0.0).run(rec).quat, rec.quat_true), rec.t > 5.0)
    assert g.inclination_rmse_deg > 2 * s.inclination_rmse_deg


def test_six_d_without_magnetometer_keeps_inclination(noisy):
    est = Gradient().run(noisy.without_mag())
    same = Gradient(use_mag=False).run(noisy)
    np.testing.assert_array_equal(est.quat, same.quat)
    err = error_series(est.quat, noisy.quat_true)
    assert np.degrees(np.sqrt(np.mean(err.inclination_rad[noisy.t > 5] ** 2))) < 2.0


@pytest.mark.parametrize("objective", ["forward", "madgwick"])
def test_static_convergence_to_the_normalised_step_bound(objective):
    # noise-free, at rest, 20 deg off: the estimate converges and then chatters within
    # one normalised step, |Δq| = β Δt, i.e. an angle of 2 β Δt
    q_true = quat.from_euler([0.7, -0.3, 0.2])
    rec = simulate(static(10.0, 100.0, q0=q_true), seed=0)
    f = Gradient(beta=0.1, mag_objective=objective)
    f.reset(quat.multiply(quat.from_axis_angle([1.0, 2.0, 0.5], np.radians(20.0)), q_true))
    est = f.run(rec)
    late = quat.angle_between(est.quat[rec.t > 5.0], q_true)
    assert np.max(late) <= 2 * 0.1 * 0.01 * (1 + 1e-6)


def test_vertical_disturbance_does_not_tilt_the_forward_component():
    traj = random_motion(30.0, 100.0, seed=3)
    plain = simulate(traj, seed=1, **_mems())
    disturbed = simulate(traj, seed=1, mag_disturbances=[vertical_tilt(10.0, 50.0)], **_mems())
    after = plain.t >= 10.0
    # the objective's own immunity: the screening's norm/dip gate (which would reject this
    # field, +90 % norm and +16 deg dip) is opened wide
    no_gate = {"mag_norm_tol": 10.0, "mag_dip_tol_deg": 180.0}

    def incl(objective, rec, **gate):
        est = Gradient(mag_objective=objective, **gate).run(rec)
        return summarize(error_series(est.quat, rec.quat_true), after).inclination_rmse_deg

    assert incl("forward", disturbed, **no_gate) < incl("forward", plain, **no_gate) + 0.1
    # a filter trusting the full vector against a fixed reference tilts by degrees
    assert incl("fixed", disturbed, **no_gate) > incl("fixed", plain, **no_gate) + 2.0
    # with the default gate the disturbed field is flagged and not used: no tilt either
    est = Gradient(mag_objective="fixed").run(disturbed)
    assert np.count_nonzero(est.flags[after] & Flag.MAG_DISTURBED) > 1000
    assert incl("fixed", disturbed) < incl("fixed", plain) + 0.1


def test_linear_acceleration_without_noise():
    # the demo motion (simulate_default): 2 cm of translation, 0.29 m/s² rms, 60 s
    traj = random_motion(60.0, 100.0, seed=5, translation_m=0.02)
    rec = simulate(traj, seed=2)
    est = Gradient().run(rec)
    err = est.outputs["lin_acc_earth_m_s2"] - traj.acc_lin_m_s2
    rms = np.sqrt(np.mean(np.sum(err**2, axis=1)))
    assert rms < 0.1
    # what is left is the tilt the acceleration itself causes: |R a - R_true a| = 2 g sin(e/2)
    incl = error_series(est.quat, rec.quat_true).inclination_rad
    tilt_part = np.sqrt(np.mean((2 * 9.80665 * np.sin(incl / 2)) ** 2))
    assert rms == pytest.approx(tilt_part, rel=0.05)


def test_broad_slice_error_and_inclination_against_madgwick(broad_folder):
    # 42 s of the undisturbed fast-rotation trial 06 (rest, then up to 7 rad/s); measured:
    # forward 2.39 deg total, 0.61 deg inclination; Madgwick (β 0.08) 1.61 and 1.08 deg
    trial = next(t for t in broad_trials(broad_folder) if t.name.startswith("06_"))
    rec = read_broad(trial.path).slice(8000, 20000)
    ours, _ = evaluate_recording(Gradient(), rec)
    assert ours.total_rmse_deg < 3.0
    madgwick, _ = evaluate_recording(Gradient(mag_objective="madgwick", beta=0.08), rec)
    assert ours.inclination_rmse_deg < madgwick.inclination_rmse_deg


def test_default_beta_is_the_documented_one():
    assert GradientParams().beta == DEFAULT_BETA == 0.025
    assert "0.025" in (GradientParams.__doc__ or "")


@pytest.mark.parametrize(
    ("values", "match"),
    [
        ({"beta": -0.1}, "parameter beta must be a finite number, >= 0 rad/s; got -0.1"),
        ({"beta": float("nan")}, "parameter beta must be a finite number, >= 0 rad/s; got nan"),
        ({"mag_objective": "full"},
         "parameter mag_objective must be one of 'forward', 'forward_measured', 'madgwick', "
         "'fixed', got 'full'"),
        ({"integration": "rk4"}, "parameter integration must be one of 'exact', 'euler'"),
        ({"gravity_m_s2": 0.0}, "parameter gravity_m_s2 must be a finite number, > 0 m/s²"),
        ({"use_mag": "yes"}, "parameter use_mag must be "),  # (the generic text says "a number")
        ({"frame": "NWU"}, "frame must be "),
    ],
)
def test_bad_parameters_are_refused(values, match):
    with pytest.raises(ValueError, match=re.escape(match)):
        GradientParams(**values)


def test_cli_style_parameters_are_coerced():
    from margtrack.methods import parse_params

    p = parse_params(GradientParams, ["beta=0.05", "use-mag=false", "mag-objective=madgwick"])
    assert (p.beta, p.use_mag, p.mag_objective) == (0.05, False, "madgwick")


def test_linear_acceleration_is_given_in_the_output_frame(noisy):
    # (the orientations one conversion apart is tests/test_registry_truth.py's)
    enu = Gradient().run(noisy)
    ned = Gradient(frame="NED").run(noisy)
    # the linear acceleration is the same vector, in the other frame's coordinates
    p = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    np.testing.assert_allclose(
        ned.outputs["lin_acc_earth_m_s2"], enu.outputs["lin_acc_earth_m_s2"] @ p.T, atol=1e-9
    )
