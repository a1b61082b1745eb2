"""Sensors at different rates: offline interpolation onto gyro times, live zero-order hold."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.accuracy import error_series, summarize
from margtrack.methods.gradient import ACC_IGNORED, Gradient, align_to_gyro
from margtrack.sim import simulate_default


@pytest.fixture(scope="module")
def rec():
    """200 Hz gyro; the accelerometer will be kept at 50 Hz, the magnetometer at 20 Hz."""
    return simulate_default(duration_s=10.0, rate_hz=200.0, seed=6)


def test_align_to_gyro_interpolates_linearly_and_counts_held_samples(rec):
    ta, tm = rec.t[::4], rec.t[5::10]
    out = align_to_gyro(rec.t, rec.gyr, ta, rec.acc[::4], tm, rec.mag[5::10], name="x")
    for k in range(3):
        np.testing.assert_array_equal(out.acc[:, k], np.interp(rec.t, ta, rec.acc[::4, k]))
        np.testing.assert_array_equal(out.mag[:, k], np.interp(rec.t, tm, rec.mag[5::10, k]))
    assert out.name == "x"
    assert out.meta["acc_held_samples"] == np.sum(rec.t > ta[-1])
    assert out.meta["mag_held_samples"] == 5 + np.sum(rec.t > tm[-1])
    with pytest.raises(ValueError, match="give both t_mag and mag"):
        align_to_gyro(rec.t, rec.gyr, ta, rec.acc[::4], mag=rec.mag)


def test_interpolated_slow_sensors_track_almost_like_synchronous_ones(rec):
    slow = align_to_gyro(rec.t, rec.gyr, rec.t[::4], rec.acc[::4], rec.t[::10], rec.mag[::10],
                         quat_true=rec.quat_true)
    ref = summarize(error_series(Gradient().run(rec).quat, rec.quat_true))
    got = summarize(error_series(Gradient().run(slow).quat, slow.quat_true))
    # the sensors change slowly next to 20-50 Hz (2 Hz motion band): interpolation error is
    # tiny, and β = 0.025 rad/s averages it further
    assert got.total_rmse_deg < ref.total_rmse_deg + 0.1


def _events(rec):
    """Arrival order: acc every 4th gyro tick, mag every 10th, each just before its gyro."""
    for i in range(rec.n_samples):
        if i % 4 == 0:
            yield "acc", i
        if i % 10 == 0:
            yield "mag", i
        yield "gyr", i


def test_live_updates_equal_a_run_on_held_samples(rec):
    n = 400
    live = Gradient()
    out = []
    for kind, i in _events(rec.slice(0, n)):
        if kind == "acc":
            live.update_acc(rec.acc[i])
        elif kind == "mag":
            live.update_mag(rec.mag[i])
        else:
            dt = None if i == 0 else rec.t[i] - rec.t[i - 1]
            out.append(live.update_gyr(rec.gyr[i], dt))
    held_acc = rec.acc[:n][(np.arange(n) // 4) * 4]
    held_mag = rec.mag[:n][(np.arange(n) // 10) * 10]
    batch = Gradient().run(gyr=rec.gyr[:n], acc=held_acc, mag=held_mag, t=rec.t[:n])
    assert np.max(np.abs(np.array(out) - batch.quat)) < 1e-12
    np.testing.assert_array_equal(live.state.get("acc_held")[0], rec.acc[396])
    np.testing.assert_array_equal(live.state.get("mag_held")[0], rec.mag[390])


def test_live_needs_an_accelerometer_sample_or_q0_first(rec):
    f = Gradient(rate_hz=200.0)
    with pytest.raises(ValueError, match="call update_acc\\(\\) first"):
        f.update_gyr(rec.gyr[0])
    # from q0, gyro samples alone integrate the gyro and are flagged
    f.reset(rec.quat_true[0])
    assert quat.angle_between(f.update_gyr(rec.gyr[0]), rec.quat_true[0]) < 1e-12
    q = f.update_gyr(rec.gyr[1])
    assert quat.angle_between(q, quat.integrate(rec.quat_true[0], rec.gyr[1], 1 / 200)) < 1e-12
    assert f.state.get("acc_held").tolist() == [[0.0, 0.0, 0.0]]
    est = f.run(gyr=rec.gyr[2:3], acc=np.zeros((1, 3)), t=rec.t[2:3])
    assert est.outputs["ignored"][0] == ACC_IGNORED


def test_live_samples_are_validated_and_reset_forgets_them(rec):
    f = Gradient(rate_hz=200.0)
    f.update_acc(np.stack([rec.acc[0], rec.acc[0]]))  # two sensors
    with pytest.raises(ValueError, match="has 1 sensor\\(s\\) but the filter tracks 2"):
        f.update_mag(rec.mag[0])
    # a non-finite sample is held, not refused (the screening flags it at each step:
    # tests/methods/test_gradient_gyro_policy.py); a wrong type still is
    f.update_acc([[np.nan, 0.0, 9.8], [0.0, 0.0, 9.8]])
    with pytest.raises(ValueError, match="acc must be numeric"):
        f.update_acc("up")
    with pytest.raises(ValueError, match="must have shape \\(3,\\) or \\(S, 3\\)"):
        f.update_acc([1.0, 2.0])
    f.reset()
    with pytest.raises(ValueError, match="before any accelerometer sample"):
        f.update_gyr(rec.gyr[0])
    # held samples initialise the orientation at the first gyro sample (TRIAD with the mag)
    f.update_mag(rec.mag[0])
    f.update_acc(rec.acc[0])
    q0 = f.update_gyr(rec.gyr[0])
    assert quat.angle_between(q0, Gradient().run(rec.slice(0, 1)).quat[0]) < 1e-12
