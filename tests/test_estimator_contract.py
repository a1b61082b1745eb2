"""The estimator contract: update/run equivalence, state round trips, timing rules, errors."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import methods
from margtrack import quaternion as quat
from margtrack.estimators.base import initial_orientation
from margtrack.filters.gyro import GyroIntegration
from margtrack.recording import Recording

pytestmark = pytest.mark.kernel

def _signals(n: int = 400, seed: int = 3):
    rng = np.random.default_rng(seed)
    gyr = rng.normal(scale=1.0, size=(n, 3))
    acc = rng.normal(scale=0.5, size=(n, 3)) + [0.0, 0.0, 9.81]
    mag = rng.normal(scale=2.0, size=(n, 3)) + [0.0, 20.0, -40.0]
    return gyr, acc, mag


@pytest.mark.parametrize("name", methods.available())
def test_update_n_times_equals_run_once(name):
    gyr, acc, mag = _signals()
    batch = methods.create(name).run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    live = methods.create(name, rate_hz=100.0)
    stepped = np.array([live.update(gyr[i], acc[i], mag[i]) for i in range(len(acc))])
    np.testing.assert_allclose(stepped, batch.quat, atol=1e-12)


@pytest.mark.parametrize("name", methods.available())
def test_two_half_runs_joined_through_state_equal_one_run(name):
    gyr, acc, mag = _signals()
    t = np.cumsum(np.full(len(acc), 0.01)) + 5.0
    whole = methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=t)
    first = methods.create(name)
    a = first.run(gyr=gyr[:150], acc=acc[:150], mag=mag[:150], t=t[:150])
    saved = first.state
    second = methods.create(name)
    second.state = saved  # resume in a new object from the saved state
    b = second.run(gyr=gyr[150:], acc=acc[150:], mag=mag[150:], t=t[150:])
    np.testing.assert_allclose(np.concatenate([a.quat, b.quat]), whole.quat, atol=1e-12)
    np.testing.assert_array_equal(np.concatenate([a.t, b.t]), t)


def test_state_copy_is_independent_of_the_estimator():
    gyr, acc, mag = _signals(50)
    est = GyroIntegration()
    est.run(gyr=gyr, acc=acc, mag=mag, rate_hz=50.0)
    saved = est.state
    before = saved.quat.copy()
    est.run(gyr=gyr, acc=acc, mag=mag, rate_hz=50.0)
    np.testing.assert_array_equal(saved.quat, before)
    assert not np.allclose(est.state.quat, before)


def test_first_sample_is_the_initial_orientation_then_gyro_integrates():
    gyr, acc, mag = _signals(3)
    est = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, rate_hz=10.0)
    q0 = initial_orientation(acc[:1], mag[:1], "ENU")[0]
    np.testing.assert_allclose(est.quat[0], q0, atol=1e-15)
    expected = quat.integrate(quat.integrate(q0, gyr[1], 0.1), gyr[2], 0.1)
    np.testing.assert_allclose(est.quat[2], expected, atol=1e-14)


def test_reset_with_q0_starts_there_and_ignores_acc():
    gyr, acc, mag = _signals(5)
    q0 = quat.from_euler([0.3, -0.2, 1.0])
    est = GyroIntegration(rate_hz=100.0)
    est.reset(q0)
    out = est.run(gyr=gyr, acc=acc, mag=mag)
    np.testing.assert_allclose(out.quat[0], q0, atol=1e-15)


def test_multi_sensor_run_equals_each_sensor_alone():
    sensors = [_signals(120, seed) for seed in range(3)]
    gyr = np.stack([s[0] for s in sensors])
    acc = np.stack([s[1] for s in sensors])
    mag = np.stack([s[2] for s in sensors])
    together = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    assert together.quat.shape == (3, 120, 4)
    for s in range(3):
        alone = GyroIntegration().run(gyr=gyr[s], acc=acc[s], mag=mag[s], rate_hz=100.0)
        np.testing.assert_allclose(together.quat[s], alone.quat, atol=1e-15)


def test_initial_orientation_measures_gravity_and_north():
    q_true = quat.from_euler([0.7, 0.4, -1.2])
    for frame, dip_sign in (("ENU", -1.0), ("NED", 1.0)):
        up = np.array([0, 0, 1.0]) if frame == "ENU" else np.array([0, 0, -1.0])
        north = np.array([0, 1.0, 0]) if frame == "ENU" else np.array([1.0, 0, 0])
        field = 30.0 * north + dip_sign * 40.0 * np.array([0, 0, 1.0])
        acc = quat.rotate_inverse(q_true_f := q_true, 9.81 * up)
        mag = quat.rotate_inverse(q_true_f, field)
        q = initial_orientation(acc[None], mag[None], frame)[0]
        assert quat.angle_between(q, q_true) < 1e-12


def test_6d_initialisation_puts_acc_up():
    acc = np.array([[1.0, -2.0, 9.0]])
    q = initial_orientation(acc, None, "NED")[0]
    np.testing.assert_allclose(quat.rotate(q, acc[0] / np.linalg.norm(acc)), [0, 0, -1], atol=1e-15)


def test_timestamps_must_continue_across_runs():
    gyr, acc, mag = _signals(10)
    est = GyroIntegration()
    est.run(gyr=gyr, acc=acc, mag=mag, t=np.arange(10) * 0.01)
    with pytest.raises(ValueError, match="not after the last processed one"):
        est.run(gyr=gyr, acc=acc, mag=mag, t=np.arange(10) * 0.01)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"rate_hz": None}, "no sample times"),
        ({"t": np.array([0.0, 0.1, 0.1, 0.3])}, r"strictly: t\[1\] = 0.1, t\[2\] = 0.1"),
        ({"rate_hz": -5.0}, "rate_hz must be a finite number > 0"),
    ],
)
def test_timing_errors(kwargs, message):
    gyr, acc, mag = _signals(4)
    with pytest.raises(ValueError, match=message):
        GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, **kwargs)


def test_nan_sample_is_named_and_state_is_kept():
    gyr, acc, mag = _signals(20)
    est = GyroIntegration(rate_hz=100.0)
    est.run(gyr=gyr[:10], acc=acc[:10], mag=mag[:10])
    before = est.state
    bad = gyr[10:].copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match=r"gyr has a non-finite value .* at sample 7"):
        est.run(gyr=bad, acc=acc[10:], mag=mag[10:])
    np.testing.assert_array_equal(est.state.quat, before.quat)
    assert est.state.t_last_s == before.t_last_s


def test_shape_errors_and_units_detection():
    gyr, acc, mag = _signals(20)
    with pytest.raises(ValueError, match=r"acc must have shape \(N, 3\) or \(S, N, 3\)"):
        GyroIntegration().run(gyr=gyr, acc=acc[:, :2], mag=mag, rate_hz=10.0)
    with pytest.raises(ValueError, match=r"gyr has shape \(1, 19, 3\) but acc has \(1, 20, 3\)"):
        GyroIntegration().run(gyr=gyr[:19], acc=acc, mag=mag, rate_hz=10.0)
    with pytest.raises(ValueError, match="probably in g"):
        GyroIntegration().run(gyr=gyr, acc=acc / 9.81, mag=mag, rate_hz=10.0)
    with pytest.raises(ValueError, match="probably in deg/s"):
        GyroIntegration().run(gyr=gyr * 57.3, acc=acc, mag=mag, rate_hz=10.0)


def test_zero_first_accelerometer_sample_cannot_initialise():
    gyr, acc, mag = _signals(5)
    acc[0] = 0.0
    with pytest.raises(ValueError, match="first accelerometer sample is zero; pass q0"):
        GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, rate_hz=10.0, check_units=False)


def test_update_without_dt_or_rate_is_refused_after_the_first_sample():
    gyr, acc, mag = _signals(2)
    est = GyroIntegration()
    est.update(gyr[0], acc[0], mag[0])  # the first sample needs no interval
    with pytest.raises(ValueError, match="update\\(\\) needs dt"):
        est.update(gyr[1], acc[1], mag[1])


def test_run_on_a_recording_matches_arrays():
    gyr, acc, mag = _signals(30)
    rec = Recording.from_arrays(gyr, acc, mag, rate_hz=30.0)
    a = GyroIntegration().run(rec)
    b = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, rate_hz=30.0)
    np.testing.assert_allclose(a.quat, b.quat, atol=1e-15)


def test_registry_and_parameter_parsing():
    assert methods.get("default") is methods.get(methods.DEFAULT_METHOD)
    with pytest.raises(ValueError, match="unknown method 'nope'; available: default"):
        methods.get("nope")
    est = methods.create("gyro", ["frame=ned"])
    assert est.params.frame == "NED"
    with pytest.raises(ValueError, match=r"parameter\(s\) gain for GyroParams; valid: frame"):
        methods.create("gyro", ["gain=3"])
    with pytest.raises(ValueError, match="frame must be 'NED' or 'ENU'"):
        methods.create("gyro", {"frame": "NWU"})
    with pytest.raises(ValueError, match="name=value"):
        methods.create("gyro", ["frame"])


def test_frame_parameter_changes_the_output_frame_consistently():
    gyr, acc, mag = _signals(50)
    enu = methods.create("gyro", {"frame": "ENU"}).run(gyr=gyr, acc=acc, mag=mag, rate_hz=50.0)
    ned = methods.create("gyro", {"frame": "NED"}).run(gyr=gyr, acc=acc, mag=mag, rate_hz=50.0)
    converted = enu.in_frame("NED")
    np.testing.assert_allclose(quat.angle_between(converted.quat, ned.quat), 0.0, atol=1e-7)


def test_per_axis_tuple_parameters_parse_from_the_command_line():
    est = methods.create("ekf", ["tau_s=0.2,0.3,0.4", "gn_max_iterations=3"])
    assert est.params.tau_s == (0.2, 0.3, 0.4)
    assert est.params.gn_max_iterations == 3
    assert methods.create("ekf", ["tau_s=0.25"]).params.tau_s == 0.25
