"""The estimator contract: timing rules, restarts, held outputs, accessors, strict mode."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import methods
from margtrack import quaternion as quat
from margtrack.estimator import Flag
from margtrack.estimator.initial import initial_orientation
from margtrack.methods.gyro import GyroIntegration
from margtrack.recording import Recording
from margtrack.units import UnitError

#: methods with update(); smoother refuses it (tests/methods/test_smoother.py)
ONLINE = [r.name for r in methods.RECORDS if r.online]

pytestmark = pytest.mark.kernel


def _signals(n: int = 400, seed: int = 3):
    rng = np.random.default_rng(seed)
    gyr = rng.normal(scale=1.0, size=(n, 3))
    acc = rng.normal(scale=0.5, size=(n, 3)) + [0.0, 0.0, 9.81]
    mag = rng.normal(scale=2.0, size=(n, 3)) + [0.0, 20.0, -40.0]
    return gyr, acc, mag


def test_repeated_timestamps_across_runs_are_skipped_and_held():
    gyr, acc, mag = _signals(10)
    est = GyroIntegration()
    first = est.run(gyr=gyr, acc=acc, mag=mag, t=np.arange(10) * 0.01)
    again = est.run(gyr=gyr, acc=acc, mag=mag, t=np.arange(10) * 0.01)
    # 0.09 s back is less than max_gap_s: out-of-order samples, skipped
    assert np.all(again.flags == Flag.CLOCK)
    np.testing.assert_array_equal(again.quat, np.tile(first.quat[-1], (10, 1)))


def _window_restart(gyr, acc, mag, i0, i1, dt):
    """The restart's orientation at sample i1 after a gap at i0, written out
    (estimator/restart_kernel.py): samples i0..i1 carried into i0's frame by the gyroscope,
    the accelerations near g and the fields averaged there, TRIAD, carried to i1."""
    r = np.array([1.0, 0.0, 0.0, 0.0])
    a_sum, m_sum = np.zeros(3), np.zeros(3)
    for k in range(i0, i1 + 1):
        if k > i0:
            r = quat.integrate(r, gyr[k], dt)
        if abs(np.linalg.norm(acc[k]) - 9.81) < 0.981:
            a_sum += quat.rotate(r, acc[k])
        m_sum += quat.rotate(r, mag[k])
    q_first = initial_orientation(a_sum[None], m_sum[None], "ENU")[0]
    return quat.canonical(quat.multiply(q_first, r))


def test_a_clock_reset_restarts_from_a_window():
    gyr, acc, mag = _signals(70)
    t = np.r_[np.arange(10) * 0.01 + 100.0, np.arange(60) * 0.01]  # the device rebooted
    est = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, t=t)
    assert est.flags[10] == Flag.GAP | Flag.CLOCK | Flag.INITIALISING
    # the window: 0.4 s of samples, the output meanwhile the window's orientation so far
    i1 = 10 + int(np.argmin(est.flags[10:] & Flag.INITIALISING))
    assert 49 <= i1 <= 51 and not est.flags[i1:].any()
    np.testing.assert_allclose(est.quat[i1], _window_restart(gyr, acc, mag, 10, i1, 0.01),
                               atol=1e-12)
    np.testing.assert_allclose(est.quat[12], _window_restart(gyr, acc, mag, 10, 12, 0.01),
                               atol=1e-12)
    # and integrates normally from there
    np.testing.assert_allclose(est.quat[i1 + 1], quat.integrate(est.quat[i1], gyr[i1 + 1], 0.01),
                               atol=1e-14)


def test_a_repeated_timestamp_inside_a_run_is_skipped():
    gyr, acc, mag = _signals(4)
    est = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, t=[0.0, 0.1, 0.1, 0.2])
    assert list(est.flags) == [0, 0, Flag.CLOCK, 0]
    np.testing.assert_array_equal(est.quat[2], est.quat[1])
    np.testing.assert_allclose(est.quat[3], quat.integrate(est.quat[1], gyr[3], 0.1), atol=1e-14)


def test_a_gap_is_not_integrated_and_restarts_keeping_alignment():
    gyr, acc, mag = _signals(80)
    t = np.arange(80) * 0.01
    t[15:] += 2.0
    est = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, t=t)
    assert est.quat.shape == (80, 4)
    assert est.flags[15] == Flag.GAP | Flag.INITIALISING
    i1 = 15 + int(np.argmin(est.flags[15:] & Flag.INITIALISING))
    assert not est.flags[i1:].any()
    # the gap's sample alone: what a one-sample start gives
    np.testing.assert_allclose(
        est.quat[15], initial_orientation(acc[15:16], mag[15:16], "ENU")[0], atol=1e-15
    )
    np.testing.assert_allclose(est.quat[i1], _window_restart(gyr, acc, mag, 15, i1, 0.01),
                               atol=1e-12)


def test_a_nan_sample_is_flagged_and_the_rest_is_processed():
    gyr, acc, mag = _signals(20)
    est = GyroIntegration(rate_hz=100.0)
    bad = gyr.copy()
    bad[7, 1] = np.nan
    out = est.run(gyr=bad, acc=acc, mag=mag)
    assert out.flags[7] == Flag.INVALID | Flag.GYR_CLIPPED
    assert np.isfinite(out.quat).all()
    # the last good rate stands in for sample 7
    np.testing.assert_allclose(out.quat[7], quat.integrate(out.quat[6], gyr[6], 0.01), atol=1e-14)


def test_strict_mode_raises_naming_the_sample_and_keeps_the_state():
    gyr, acc, mag = _signals(20)
    est = GyroIntegration(rate_hz=100.0, strict=True)
    est.run(gyr=gyr[:10], acc=acc[:10], mag=mag[:10])
    before = est.state
    bad = gyr[10:].copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match=r"sample 7 is flagged INVALID\|GYR_CLIPPED.*strict=True"):
        est.run(gyr=bad, acc=acc[10:], mag=mag[10:])
    np.testing.assert_array_equal(est.state.quat, before.quat)
    assert est.state.t_last_s == before.t_last_s


def test_zero_first_samples_delay_the_initialisation():
    gyr, acc, mag = _signals(6)
    acc[:2] = 0.0
    out = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, rate_hz=10.0, check_units=False)
    assert list(out.flags[:3]) == [
        Flag.ACC_IGNORED | Flag.INITIALISING,
        Flag.ACC_IGNORED | Flag.INITIALISING,
        0,
    ]
    np.testing.assert_array_equal(out.quat[:2], [[1.0, 0, 0, 0]] * 2)
    np.testing.assert_allclose(out.quat[2], initial_orientation(acc[2:3], mag[2:3], "ENU")[0])


def test_a_parallel_field_waits_then_a_dead_magnetometer_starts_from_gravity():
    gyr, acc, mag = _signals(5)
    mag[0] = acc[0] * 3.0  # parallel: no heading
    mag[1:] = 0.0  # then no field at all
    out = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, rate_hz=10.0)
    assert out.flags[0] & Flag.INITIALISING
    # a magnetometer-optional method starts from the accelerometer alone at sample 1
    np.testing.assert_allclose(out.quat[1], initial_orientation(acc[1:2], None, "ENU")[0])
    assert not out.flags[1] & Flag.INITIALISING and out.flags[1] & Flag.MAG_IGNORED


def test_sensors_initialise_each_at_their_first_usable_sample():
    gyr, acc, mag = _signals(40)
    acc2 = np.stack([acc, acc.copy()])
    acc2[1, :5] = 0.0
    out = GyroIntegration().run(
        gyr=np.stack([gyr, gyr]), acc=acc2, mag=np.stack([mag, mag]), rate_hz=100.0
    )
    alone = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    np.testing.assert_allclose(out.quat[0], alone.quat, atol=1e-15)
    assert (out.flags[1, :5] & Flag.INITIALISING).all() and not out.flags[0].any()
    # each sensor starts at its own first usable sample, measured there
    q5 = initial_orientation(acc[5:6], mag[5:6], "ENU")[0]
    np.testing.assert_allclose(out.quat[1, 5], q5, atol=1e-14)
    np.testing.assert_allclose(out.quat[1, 6], quat.integrate(q5, gyr[6], 0.01), atol=1e-14)


def test_update_refuses_g_and_deg_s_after_its_first_samples():
    gyr, acc, mag = _signals(600)
    est = GyroIntegration(rate_hz=100.0)
    with pytest.raises(UnitError, match=r"about 1 g.*multiply g by 9.80665") as info:
        for i in range(30):
            est.update(gyr[i], acc[i] / 9.81, mag[i])
    assert info.value.signal == "acc"
    est = GyroIntegration(rate_hz=100.0)
    with pytest.raises(UnitError, match=r"probably deg/s; convert to rad/s before update"):
        for i in range(600):
            est.update(np.degrees(gyr[i]) * 5, acc[i], mag[i])


def test_update_exposes_flags_of_the_last_sample():
    gyr, acc, mag = _signals(3)
    est = GyroIntegration(rate_hz=100.0)
    est.update(gyr[0], acc[0], mag[0])
    assert est.flags is not None and est.flags.tolist() == [0]
    est.update([np.inf, 0, 0], acc[1], mag[1])
    assert est.flags.tolist() == [Flag.INVALID | Flag.GYR_CLIPPED]
    assert est.gyr_bias_rad_s is None  # plain integration estimates no bias


def test_run_arrays_in_deg_s_and_g_with_declared_units():
    gyr, acc, mag = _signals(50)
    si = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, rate_hz=50.0)
    declared = GyroIntegration().run(
        gyr=np.degrees(gyr), acc=acc / 9.80665, mag=mag, rate_hz=50.0,
        gyr_unit="deg/s", acc_unit="g",
    )
    np.testing.assert_allclose(declared.quat, si.quat, atol=1e-12)
    with pytest.raises(UnitError, match="pass gyr_unit='deg/s' to run"):
        GyroIntegration().run(gyr=np.degrees(gyr), acc=acc, mag=mag, rate_hz=50.0)


@pytest.mark.parametrize("name", ONLINE)
def test_update_n_times_equals_run_once(name):
    gyr, acc, mag = _signals()
    batch = methods.create(name).run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    live = methods.create(name, rate_hz=100.0)
    stepped = np.array([live.update(gyr[i], acc[i], mag[i]) for i in range(len(acc))])
    np.testing.assert_allclose(stepped, batch.quat, atol=1e-12)


@pytest.mark.parametrize("name", ONLINE)
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


def test_shape_errors_and_units_detection():
    gyr, acc, mag = _signals(20)
    with pytest.raises(ValueError, match=r"acc must have shape \(N, 3\) or \(S, N, 3\)"):
        GyroIntegration().run(gyr=gyr, acc=acc[:, :2], mag=mag, rate_hz=10.0)
    with pytest.raises(ValueError, match=r"gyr has shape \(1, 19, 3\) but acc has \(1, 20, 3\)"):
        GyroIntegration().run(gyr=gyr[:19], acc=acc, mag=mag, rate_hz=10.0)
    with pytest.raises(ValueError, match="probably in g"):
        GyroIntegration().run(gyr=gyr, acc=acc / 9.81, mag=mag, rate_hz=10.0)
    with pytest.raises(ValueError, match="probably in deg/s"):
        GyroIntegration().run(gyr=gyr * 57.3 * 30, acc=acc, mag=mag, rate_hz=10.0)


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
    valid = r"unknown parameter 'gain'; the parameters are acc_range_g, frame, gyr_range"
    with pytest.raises(ValueError, match=valid):
        methods.create("gyro", ["gain=3"])
    with pytest.raises(ValueError, match="frame must be 'NED' or 'ENU'"):
        methods.create("gyro", {"frame": "NWU"})
    with pytest.raises(ValueError, match="name=value"):
        methods.create("gyro", ["frame"])


def test_per_axis_tuple_parameters_parse_from_the_command_line():
    est = methods.create("ekf", ["tau_s=0.2,0.3,0.4", "gn_max_iterations=3"])
    assert est.params.tau_s == (0.2, 0.3, 0.4)
    assert est.params.gn_max_iterations == 3
    assert methods.create("ekf", ["tau_s=0.25"]).params.tau_s == 0.25
