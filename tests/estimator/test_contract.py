"""The estimator contract: timing rules, restarts, held outputs, accessors, strict mode."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.estimator import Flag
from margtrack.estimator.contract import initial_orientation
from margtrack.filters.gyro import GyroIntegration
from margtrack.recording import UnitError

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


def test_a_clock_reset_restarts_from_the_sample():
    gyr, acc, mag = _signals(20)
    t = np.r_[np.arange(10) * 0.01 + 100.0, np.arange(10) * 0.01]  # the device rebooted
    est = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, t=t)
    assert est.flags[10] == Flag.GAP | Flag.CLOCK
    q_restart = initial_orientation(acc[10:11], mag[10:11], "ENU")[0]
    np.testing.assert_allclose(est.quat[10], q_restart, atol=1e-15)
    # and integrates normally from there
    np.testing.assert_allclose(est.quat[11], quat.integrate(q_restart, gyr[11], 0.01), atol=1e-14)


def test_a_repeated_timestamp_inside_a_run_is_skipped():
    gyr, acc, mag = _signals(4)
    est = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, t=[0.0, 0.1, 0.1, 0.2])
    assert list(est.flags) == [0, 0, Flag.CLOCK, 0]
    np.testing.assert_array_equal(est.quat[2], est.quat[1])
    np.testing.assert_allclose(est.quat[3], quat.integrate(est.quat[1], gyr[3], 0.1), atol=1e-14)


def test_a_gap_is_not_integrated_and_restarts_keeping_alignment():
    gyr, acc, mag = _signals(30)
    t = np.arange(30) * 0.01
    t[15:] += 2.0
    est = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, t=t)
    assert est.quat.shape == (30, 4)
    assert est.flags[15] == Flag.GAP and not est.flags[16:].any()
    np.testing.assert_allclose(
        est.quat[15], initial_orientation(acc[15:16], mag[15:16], "ENU")[0], atol=1e-15
    )


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
    q5 = initial_orientation(acc[5:6], mag[5:6], "ENU")[0]
    np.testing.assert_allclose(out.quat[1, 5], quat.integrate(q5, gyr[5], 0.01), atol=1e-14)


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
