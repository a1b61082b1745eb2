"""The robust filter under the input policy: sentinels, its own disturbance rejection,
restarts that keep what it knows of the sensor, and the start-up mean of the heading."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.accuracy import error_series
from margtrack.estimator import Flag, Params, initial_orientation, specs
from margtrack.methods.robust import Robust, RobustParams, kernel

pytestmark = pytest.mark.kernel

RATE_HZ = 100.0
DT = 1.0 / RATE_HZ
FIELD_UT = 50.0  # the simulator's field strength, dip 60 deg


@pytest.fixture(scope="module")
def rec():
    return sim.simulate_motion("random", duration_s=10.0, rate_hz=RATE_HZ, seed=5)


def _static(duration_s, **kwargs):
    """A level sensor at rest facing north (ENU identity), perfect sensors unless given."""
    return sim.simulate(sim.static(duration_s, RATE_HZ), seed=3, **kwargs)


def _after_one_update(rec, n, *, acc=None, mag=None):
    """State after n samples, and after one more with the given acc/mag substitutes."""
    f = Robust()
    f.run(rec.slice(0, n))
    before = f.state
    f.update(rec.gyr[n], rec.acc[n] if acc is None else acc, rec.mag[n] if mag is None else mag,
             dt=rec.t[n] - rec.t[n - 1])  # fmt: skip
    return before, f.state, f.flags[0]


# -- screened samples ------------------------------------------------------------------------
def test_a_zero_accelerometer_sample_does_not_reach_the_low_pass(rec):
    before, after, flags = _after_one_update(rec, 300, acc=np.zeros(3))
    assert flags & Flag.ACC_IGNORED
    # no measurement: the low-pass (output and states), the inclination and the rest
    # detector's accelerometer mean are exactly as they were (feeding the zero would have
    # pulled the low-pass towards zero by its gain, about 1e-5 of it per sample)
    for name in ("acc_lp_m_s2", "acc_lp_bw", "q_acc", "acc_rest_m_s2", "gyr_bias_rad_s"):
        np.testing.assert_array_equal(after.get(name), before.get(name), err_msg=name)
    # the gyro still integrates: q_gyr moved by the (bias-corrected) rate
    w = rec.gyr[300] - before.get("gyr_bias_rad_s")[0]
    q_before, q_after = before.get("q_gyr")[0], after.get("q_gyr")[0]
    assert quat.angle_between(q_after, quat.integrate(q_before, w, DT)) < 1e-12
    assert quat.angle_between(q_after, q_before) > 1e-4


def test_a_zero_field_sample_does_not_reach_the_heading(rec):
    before, after, flags = _after_one_update(rec, 300, mag=np.zeros(3))
    assert flags & Flag.MAG_IGNORED
    for name in ("heading_rad", "heading_n", "mag_norm_ref", "mag_dip_ref_rad", "mag_cand_s"):
        np.testing.assert_array_equal(after.get(name), before.get(name), err_msg=name)
    # the inclination is still corrected
    assert not np.array_equal(after.get("acc_lp_m_s2"), before.get("acc_lp_m_s2"))


def test_a_skipped_sample_leaves_the_whole_state_as_it_was(rec):
    f = Robust()
    f.run(rec.slice(0, 300))
    before = f.state
    q = f.update(rec.gyr[300], rec.acc[300], rec.mag[300], dt=0.0)  # repeated timestamp
    assert f.flags[0] & Flag.CLOCK
    np.testing.assert_array_equal(q, before.quat[0])
    after = f.state
    for name in Robust.state_layout:
        np.testing.assert_array_equal(after.get(name), before.get(name), err_msg=name)
    # and the rest of the filter's row (its interval gains) too
    method = slice(kernel.R_Q_GYR, kernel.N_ROW)
    np.testing.assert_array_equal(after.rows[:, method], before.rows[:, method])


def test_kernel_extreme_screened_samples_never_give_nan():
    # the filter's own step, fed directly what the screening may pass on (no screening)
    rng = np.random.default_rng(7)
    n = 600
    gyr = rng.uniform(-30.0, 30.0, size=(n, 3))  # within the default 2000 deg/s range
    acc = rng.normal(size=(n, 3)) * rng.choice([1e-3, 1.0, 150.0], size=(n, 1))
    acc[::7] = 0.0  # the screening's "no measurement"
    mag = rng.normal(size=(n, 3)) * rng.choice([1e-300, 1e-3, 50.0, 1e300], size=(n, 1))
    mag[::5] = 0.0
    mag[3::11] = acc[3::11] * 4.0  # parallel to the accelerometer
    dt = rng.choice([0.0, DT, 0.25], size=n)
    acc[300], mag[300], dt[300] = 0.0, 0.0, 0.0  # a no-op sample
    coef = RobustParams().coefficients()
    row = np.zeros(kernel.N_ROW)
    kernel._start(row, coef, True, *quat.normalize(rng.normal(size=4)))
    q, x = np.zeros((n, 4)), np.zeros((n, kernel.N_OUT))
    with np.errstate(over="ignore", under="ignore"):  # numpy scalars when the JIT is off
        for i in range(n):
            kernel._step(row, coef, dt[i], *gyr[i], *acc[i], *mag[i], True, q[i], x[i])
            # nan: not known yet (the dip references, the hard-iron fit's origin until
            # the first usable field)
            unset = (kernel.R_MAG_DIP_REF, kernel.R_CAND_DIP, *range(kernel.R_HI_SHIFT,
                                                                     kernel.R_HI_SHIFT + 3))
            assert np.isfinite(np.delete(row, unset)).all(), i
    assert np.isfinite(q).all() and np.isfinite(x[:, : kernel.X_MAG_OFFSET]).all()
    # the hard-iron offset: nan until a fit is accepted, finite after
    offset = x[:, kernel.X_MAG_OFFSET :]
    assert np.all(np.isfinite(offset) | np.isnan(offset).all(axis=1, keepdims=True))
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(q[300], q[299])


def test_before_its_first_usable_sample_a_sensor_holds_and_knows_its_prior(rec):
    acc = rec.acc.copy()
    acc[:10] = 0.0  # nothing to start from
    f = Robust(bias_sigma_init_deg_s=0.3, mag_norm_ref=FIELD_UT, frame="NED")
    est = f.run(gyr=rec.gyr[:10], acc=acc[:10], mag=rec.mag[:10], t=rec.t[:10])
    assert np.all(est.flags & Flag.INITIALISING)
    # held: the identity, the 6-D output too; the bias as known before any sample
    np.testing.assert_array_equal(est.quat, np.tile([1.0, 0.0, 0.0, 0.0], (10, 1)))
    np.testing.assert_array_equal(est.outputs["quat6d"], est.quat)
    np.testing.assert_array_equal(est.outputs["gyr_bias_rad_s"], 0.0)
    np.testing.assert_allclose(est.outputs["gyr_bias_sd_rad_s"], math.radians(0.3), rtol=1e-15)
    np.testing.assert_allclose(f.gyr_bias_sd_rad_s, math.radians(0.3), rtol=1e-15)
    assert f.state.get("mag_norm_ref")[0, 0] == FIELD_UT
    # the first usable sample starts it (TRIAD), its 6-D output in the same frame
    est = f.run(gyr=rec.gyr[10:12], acc=acc[10:12], mag=rec.mag[10:12], t=rec.t[10:12])
    q0 = initial_orientation(acc[10][None], rec.mag[10][None], "NED")[0]
    assert not est.flags[0] & Flag.INITIALISING
    assert quat.angle_between(est.quat[0], q0) < 1e-12
    assert quat.angle_between(est.outputs["quat6d"][0], q0) < 1e-12  # heading still 0


# -- its own disturbance rejection -----------------------------------------------------------
def test_the_filter_rejects_disturbances_itself_with_its_tighter_tolerances():
    base = {s.name: s for s in specs(Params)}
    own = {s.name: s for s in specs(RobustParams)}
    assert (own["mag_norm_tol"].default, own["mag_dip_tol_deg"].default) == (0.1, 10.0)
    assert (base["mag_norm_tol"].default, base["mag_dip_tol_deg"].default) == (0.25, 20.0)
    assert Robust.rejects_mag_disturbance
    rec = _static(20.0, mag_errors=sim.SensorErrors(noise_density=0.05))
    mag = rec.mag.copy()
    mag[800:1000] *= 1.15  # beyond robust's 10 %, within the screening's 25 %
    mag[1200:1400] *= 3.0  # beyond both: still passed through to the filter
    est = Robust().run(gyr=rec.gyr, acc=rec.acc, mag=mag, t=rec.t)
    disturbed = (est.flags & Flag.MAG_DISTURBED) != 0
    assert disturbed[800:1000].all() and disturbed[1200:1400].all()
    assert not disturbed[:800].any() and not disturbed[1000:1200].any()
    # the filter's own flag: the screening ignored nothing
    assert not np.any(est.flags & Flag.MAG_IGNORED)


def _disturbed(est):
    return (est.flags & Flag.MAG_DISTURBED) != 0


def test_a_given_field_reference_is_the_initial_reference():
    rec = _static(12.0)
    mag = rec.mag.copy()
    mag[:500] *= 1.3  # starts in a disturbed field
    arrays = {"gyr": rec.gyr, "acc": rec.acc, "mag": mag, "t": rec.t}
    learned = _disturbed(Robust().run(**arrays))
    given = _disturbed(Robust(mag_norm_ref=FIELD_UT).run(**arrays))
    # learned from the first sample, the disturbed field is the reference and the true one
    # looks disturbed; given, it is the other way round
    assert not learned[:500].any() and learned[500:].all()
    assert given[:500].all() and not given[500:].any()
    # the same with a given dip: a field tilted 20 deg from the 60 deg dip
    tilted = mag.copy()
    tilt = quat.from_axis_angle([1.0, 0.0, 0.0], math.radians(20.0))
    tilted[:500] = quat.rotate(tilt, rec.mag[:500])
    arrays["mag"] = tilted
    given_dip = _disturbed(Robust(mag_dip_ref_deg=60.0).run(**arrays))
    assert given_dip[1:500].all() and not given_dip[500:].any()
    # the unit of the field is the data's: in nT the same reference is 1000 times larger
    arrays["mag"] = mag * 1000.0
    in_nt = Robust(mag_norm_ref=FIELD_UT * 1000.0).run(**arrays)
    np.testing.assert_array_equal(_disturbed(in_nt), given)


# -- restarts ------------------------------------------------------------------------------
def _cut(rec, start, stop):
    keep = np.ones(rec.n_samples, bool)
    keep[start:stop] = False
    return dataclasses.replace(
        rec, t=rec.t[keep], gyr=rec.gyr[keep], acc=rec.acc[keep], mag=rec.mag[keep],
        quat_true=rec.quat_true[keep], movement=None,
    )  # fmt: skip


def test_a_restart_keeps_the_bias_and_starts_the_orientation_afresh():
    bias = np.radians([0.4, -0.25, 0.3])
    # still for 10 s (the bias is learned at rest), then turning: the gap is in the turn
    steps = [
        sim.Hold(10.0),
        sim.Rotate((0.0, 0.0, 1.0), 90.0, 6.0),
        sim.Rotate((1.0, 0.0, 0.0), 40.0, 4.0),
    ]
    gyr_errors = sim.SensorErrors(noise_density=np.radians(0.01), bias=bias)
    rec = sim.simulate(sim.rotation_sequence(steps, rate_hz=RATE_HZ), gyr_errors=gyr_errors, seed=1)
    start = 1200
    gapped = _cut(rec, start, start + 100)
    f = Robust()
    est = f.run(gapped)
    assert est.flags[start] & Flag.GAP
    b, sd = est.outputs["gyr_bias_rad_s"], est.outputs["gyr_bias_sd_rad_s"]
    # learned before the gap ...
    assert np.all(np.abs(np.degrees(b[start - 1] - bias)) < 0.03)
    # ... and kept through it: the restart sample integrates nothing, so nothing changes
    np.testing.assert_array_equal(b[start], b[start - 1])
    np.testing.assert_array_equal(sd[start], sd[start - 1])
    # while the orientation restarts from that sample alone (TRIAD)
    q0 = initial_orientation(gapped.acc[start][None], gapped.mag[start][None], "ENU")[0]
    assert quat.angle_between(est.quat[start], q0) < 1e-12
    # the accessors read the same state
    np.testing.assert_array_equal(f.gyr_bias_rad_s[0], b[-1])
    np.testing.assert_allclose(f.gyr_bias_sd_rad_s[0], sd[-1], rtol=1e-15)


def test_a_restart_keeps_the_field_reference_and_a_disturbed_start_is_no_heading():
    rec = _static(40.0, mag_errors=sim.SensorErrors(noise_density=0.05))
    start = 1500
    gapped = _cut(rec, start, start + 100)
    mag = gapped.mag.copy()
    # a magnet to the east from the restart for 10 s: 40 µT more, 28 % over the norm
    mag[start : start + 1000] += [40.0, 0.0, 0.0]
    arrays = {"gyr": gapped.gyr, "acc": gapped.acc, "mag": mag, "t": gapped.t}
    est = Robust().run(**arrays)
    # the reference learned before the gap is kept: the new field is a disturbance from
    # the restart on (relearning it would have accepted it); the restart's window
    # (estimator/restart_kernel.py) sees the field off the reference and carries the
    # heading from before the gap instead of taking the magnet's (atan2(40, 25) = 58 deg
    # off, the one-sample restart's)
    restart = start + int(np.argmin(est.flags[start:] & Flag.INITIALISING))
    assert restart > start and est.flags[restart] & Flag.HEADING_CARRIED
    # (the restart's own sample steps without a field: its heading was carried)
    assert _disturbed(est)[restart + 1 : start + 1000].all()
    assert not _disturbed(est)[start + 1000 :].any()
    heading = np.degrees(np.abs(error_series(est.quat, gapped.quat_true).heading_rad))
    assert heading[start : start + 1000].max() < 1.0
    # and the first clean field after the magnet leaves it there
    end = start + 1000
    assert heading[end + 1] < 0.5 and heading[end + 100 :].max() < 0.5


# -- start-up ------------------------------------------------------------------------------
def test_the_heading_starts_as_the_mean_of_its_measurements():
    rec = _static(25.0)  # perfect sensors: every measurement is the true heading
    offset = 30.0
    f = Robust()
    f.reset(quat.from_axis_angle([0.0, 0.0, 1.0], math.radians(offset)))
    est = f.run(rec)
    err = np.degrees(error_series(est.quat, rec.quat_true).heading_rad)
    # the initial heading counts as one measurement and each sample adds one: after k
    # samples the heading is the mean (k * 0 + offset) / (k + 1), while 1 / (k + 1) is
    # larger than the nominal gain 1 - exp(-dt / tau_mag_s) (k < 2000, t < 20 s)
    k = np.array([1, 2, 10, 100, 500, 1999])
    np.testing.assert_allclose(np.abs(err[k]), offset / (k + 1), rtol=1e-9)
    # then the nominal time constant: one more sample multiplies it by exp(-dt / tau)
    gain = 1.0 - math.exp(-DT / 20.0)
    assert abs(abs(err[2001]) - abs(err[2000]) * (1.0 - gain)) < 1e-9
    # without the start-up the same offset decays with tau_mag_s = 20 s
    f = Robust(converge_s=0.0)
    f.reset(quat.from_axis_angle([0.0, 0.0, 1.0], math.radians(offset)))
    slow = np.degrees(error_series(f.run(rec).quat, rec.quat_true).heading_rad)
    np.testing.assert_allclose(np.abs(slow[100]), offset * (1.0 - gain) ** 100, rtol=1e-9)


def test_converge_s_is_declared_and_validated():
    spec = {s.name: s for s in specs(RobustParams)}["converge_s"]
    assert (spec.default, spec.unit, spec.ge) == (20.0, "s", 0)
    assert spec.help
    with pytest.raises(ValueError, match="converge_s"):
        RobustParams(converge_s=-1.0)
    # every parameter of the filter says its meaning in one line
    assert all(s.help for s in specs(RobustParams))
