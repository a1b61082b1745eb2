"""The gyro null taken from the still start (000 Appendix B step 1), shared by bachmann and ekf."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.accuracy import error_series, summarize
from margtrack.methods.bachmann import Bachmann, BachmannParams
from margtrack.methods.ekf import MarinsEkf, MarinsEkfParams
from margtrack.methods.rest_null import RestNullState, subtract_rest_null

pytestmark = pytest.mark.kernel

RATE_HZ = 100.0
BIAS_RAD_S = np.radians([0.5, -0.3, 0.4])


def _still_then_turning(still_samples: int, n: int = 600, seed: int = 0):
    """Gyro (1, n, 3): bias + noise while still, then a 30 deg/s turn; acc/mag constant."""
    rng = np.random.default_rng(seed)
    gyr = BIAS_RAD_S + rng.normal(0.0, np.radians(0.2), (n, 3))
    gyr[still_samples:, 0] += np.radians(30.0)
    acc = np.tile([0.0, 0.0, 9.81], (n, 1)) + rng.normal(0.0, 0.02, (n, 3))
    mag = np.tile([0.0, 20.0, -40.0], (n, 1)) + rng.normal(0.0, 0.3, (n, 3))
    dt = np.full(n, 1.0 / RATE_HZ)
    dt[0] = 0.0
    return gyr[None], acc[None], mag[None], dt


def test_the_null_is_the_running_mean_while_still_then_frozen():
    gyr, acc, mag, dt = _still_then_turning(300)
    state = RestNullState.new(1)
    out, null = subtract_rest_null(state, gyr, acc, mag, dt, min_rest_s=1.0)
    running = np.cumsum(gyr[0, :300], axis=0) / np.arange(1, 301)[:, None]
    np.testing.assert_allclose(null[0, :300], running, rtol=0, atol=1e-15)
    np.testing.assert_allclose(null[0, 300:], np.tile(running[-1], (300, 1)), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(out, gyr - null)
    assert not state.still[0] and state.count[0] == 300
    assert state.duration_s[0] == pytest.approx(2.99)
    # 300 samples of 0.2 deg/s noise: the null is within 4 sigma of the true bias
    assert np.abs(null[0, -1] - BIAS_RAD_S).max() < 4 * np.radians(0.2) / np.sqrt(300)


def test_a_still_start_shorter_than_min_rest_gives_no_null():
    gyr, acc, mag, dt = _still_then_turning(50)  # 0.5 s
    out, null = subtract_rest_null(RestNullState.new(1), gyr, acc, mag, dt, min_rest_s=1.0)
    assert np.all(null[0, 50:] == 0.0)
    np.testing.assert_array_equal(out[0, 50:], gyr[0, 50:])
    out, null = subtract_rest_null(RestNullState.new(1), gyr, acc, mag, dt, min_rest_s=0.4)
    assert np.all(null[0, 50:] != 0.0)


def test_a_tilt_or_a_turn_of_the_field_ends_the_still_start():
    for signal, turn_deg in (("acc", 5.0), ("mag", 15.0)):
        gyr, acc, mag, dt = _still_then_turning(600)  # the gyro never moves
        vectors = {"acc": acc, "mag": mag}[signal]
        rot = quat.to_matrix(quat.from_axis_angle([1.0, 0.0, 0.0], np.radians(turn_deg)))
        vectors[0, 200:] = vectors[0, 200:] @ rot.T
        state = RestNullState.new(1)
        subtract_rest_null(state, gyr, acc, mag, dt, min_rest_s=1.0)
        assert state.count[0] == 200, signal


def test_min_rest_zero_switches_it_off_and_halves_through_the_state_equal_one_call():
    gyr, acc, mag, dt = _still_then_turning(300)
    out, null = subtract_rest_null(RestNullState.new(1), gyr, acc, mag, dt, min_rest_s=0.0)
    assert out is gyr and not null.any()
    whole = subtract_rest_null(RestNullState.new(1), gyr, acc, mag, dt, 1.0)[0]
    state = RestNullState.new(1)
    first = subtract_rest_null(state, gyr[:, :250], acc[:, :250], mag[:, :250], dt[:250], 1.0)[0]
    saved = state.copy()
    state.total_rad_s[:] = np.nan  # the copy must not share arrays
    second = subtract_rest_null(saved, gyr[:, 250:], acc[:, 250:], mag[:, 250:], dt[250:], 1.0)[0]
    np.testing.assert_array_equal(np.concatenate([first, second], axis=1), whole)


def _biased_recording(seed: int = 3):
    """5 s still, then a minute of random motion, with a constant gyro bias."""
    still = sim.static(5.0, RATE_HZ)
    moving = sim.random_motion(60.0, RATE_HZ, seed=seed, max_rate_deg_s=150.0)
    traj = sim.Trajectory(
        np.concatenate([still.t, still.t[-1] + 1.0 / RATE_HZ + moving.t]),
        np.concatenate([still.quat, moving.quat]),
        np.concatenate([still.pos_m, moving.pos_m]),
        np.concatenate([still.acc_lin_m_s2, moving.acc_lin_m_s2]),
        "still-then-random", {},
    )
    gyr_errors = sim.SensorErrors(noise_density=np.radians(0.01), bias=tuple(BIAS_RAD_S))
    return sim.simulate(traj, gyr_errors=gyr_errors, seed=seed)


@pytest.mark.parametrize("make", [
    lambda rest: Bachmann(BachmannParams(gyr_null_rest_s=rest)),
    lambda rest: MarinsEkf(MarinsEkfParams(gyr_null_rest_s=rest)),
])
def test_the_null_removes_the_bias_driven_error(make):
    rec = _biased_recording()
    errors = {}
    for rest in (0.0, 1.0):
        est = make(rest).run(rec)
        errors[rest] = summarize(
            error_series(est.quat, rec.quat_true, est.frame, rec.frame), None
        ).total_rmse_deg
        null = est.outputs["gyr_null_rad_s"]
        if rest:
            assert np.abs(null[-1] - BIAS_RAD_S).max() < np.radians(0.01)
        else:
            assert not null.any()
    assert errors[1.0] < 0.3 * errors[0.0], errors


def test_update_equals_run_with_the_null_measuring_and_frozen():
    rec = _biased_recording().slice(0, 700)  # 5 s still, then 2 s of motion
    whole = Bachmann().run(rec)
    est = Bachmann(rate_hz=RATE_HZ)
    quats = [est.update(rec.gyr[i], rec.acc[i], rec.mag[i]) for i in range(700)]
    np.testing.assert_allclose(np.array(quats), whole.quat, rtol=0, atol=1e-12)
    state = est.state
    assert state.get("rest_null_still")[0, 0] == 0.0  # the null was frozen on the way
    np.testing.assert_array_equal(est.gyr_bias_rad_s, whole.outputs["gyr_null_rad_s"][-1:])


@pytest.mark.parametrize("params", [BachmannParams, MarinsEkfParams])
def test_a_negative_or_non_finite_min_rest_is_refused(params):
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="gyr_null_rest_s"):
            params(gyr_null_rest_s=bad)
