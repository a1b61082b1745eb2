"""gradient and gyro under the input policy: sentinels, method flags, restarts, live samples."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.accuracy import error_series
from margtrack.estimator import Flag, Params, initial_orientation, specs
from margtrack.estimator import skeleton as contract
from margtrack.methods.gradient import (
    _FROM_NWU,
    ACC_IGNORED,
    MAG_IGNORED,
    MAG_OBJECTIVES,
    MAG_REJECTED,
    Gradient,
    GradientParams,
    kernel,
)
from margtrack.methods.gyro import GyroIntegration, GyroParams
from margtrack.sim import simulate_default

pytestmark = pytest.mark.kernel

RATE_HZ = 100.0
DT = 1.0 / RATE_HZ


@pytest.fixture(scope="module")
def rec():
    return simulate_default(duration_s=12.0, rate_hz=RATE_HZ, seed=11)


def _arrays(rec, n=None):
    n = rec.n_samples if n is None else n
    return rec.gyr[:n].copy(), rec.acc[:n].copy(), rec.mag[:n].copy(), rec.t[:n].copy()


# -- gradient: screened samples --------------------------------------------------------------
@pytest.mark.parametrize("objective", list(MAG_OBJECTIVES))
def test_a_non_finite_accelerometer_sample_is_a_gyro_only_step(rec, objective):
    gyr, acc, mag, t = _arrays(rec, 400)
    bad, zero = acc.copy(), acc.copy()
    bad[200] = [np.nan, 1.0, np.inf]
    zero[200] = 0.0
    est = Gradient(mag_objective=objective).run(gyr=gyr, acc=bad, mag=mag, t=t)
    ref = Gradient(mag_objective=objective).run(gyr=gyr, acc=zero, mag=mag, t=t)
    assert np.isfinite(est.quat).all()
    # the NaN became the zero sentinel: the same step as a zero sample, a pure gyro step
    np.testing.assert_array_equal(est.quat, ref.quat)
    step = quat.integrate(est.quat[199], gyr[200], DT)
    assert quat.angle_between(est.quat[200], step) < 1e-12
    # flagged: invalid, accelerometer not used and (gyro-only) the field neither
    assert est.flags[200] == Flag.INVALID | Flag.ACC_IGNORED | Flag.MAG_IGNORED
    assert ref.flags[200] == Flag.ACC_IGNORED | Flag.MAG_IGNORED
    assert est.outputs["ignored"][200] == ACC_IGNORED | MAG_REJECTED
    assert not est.flags[201:].any() and not est.flags[:200].any()


def test_a_field_without_forward_component_is_flagged_by_the_filter_not_the_screening():
    # a field along gravity passes the screening (steady norm and dip) but has no
    # horizontal part: the forward objectives cannot use it, Madgwick's full vector can
    n = 50
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    mag = np.tile([0.0, 0.0, -45.0], (n, 1))
    gyr = np.zeros((n, 3))
    f = Gradient()
    f.reset([1.0, 0.0, 0.0, 0.0])
    est = f.run(gyr=gyr, acc=acc, mag=mag, rate_hz=RATE_HZ)
    assert np.all(est.outputs["ignored"] == MAG_IGNORED | MAG_REJECTED)
    assert np.all(est.flags == Flag.MAG_IGNORED)
    f = Gradient(mag_objective="madgwick")
    f.reset([1.0, 0.0, 0.0, 0.0])
    est = f.run(gyr=gyr, acc=acc, mag=mag, rate_hz=RATE_HZ)
    assert not est.flags.any() and not est.outputs["ignored"].any()


def test_a_disturbed_field_is_flagged_disturbed_only(rec):
    # the screening rejects it (MAG_DISTURBED) and zeroes it; the filter's MAG_IGNORED for a
    # zero field is not carried into the schema: the reason stays the screening's
    gyr, acc, mag, t = _arrays(rec, 600)
    mag[300:320] *= 3.0
    est = Gradient().run(gyr=gyr, acc=acc, mag=mag, t=t)
    assert np.all(est.flags[300:320] == Flag.MAG_DISTURBED)
    assert np.all(est.outputs["ignored"][300:320] == MAG_IGNORED)


@pytest.mark.parametrize("name", ["gradient", "gyro"])
def test_a_skipped_timestamp_is_a_no_op(rec, name):
    gyr, acc, mag, t = _arrays(rec, 100)
    t[50] = t[49]  # repeated: skipped, output held
    cls = Gradient if name == "gradient" else GyroIntegration
    est = cls().run(gyr=gyr, acc=acc, mag=mag, t=t)
    np.testing.assert_allclose(est.quat[50], est.quat[49], rtol=0, atol=1e-15)
    # the method adds nothing to the screening's CLOCK (it had nothing to use or ignore)
    assert est.flags[50] == Flag.CLOCK
    # the next sample integrates from the held one over both intervals; gradient adds its
    # normalised correction step, |Δq| <= β dt, an angle of at most 2 β dt
    bound = 2 * GradientParams().beta * 2 * DT if name == "gradient" else 0.0
    gyro_step = quat.integrate(est.quat[50], gyr[51], 2 * DT)
    assert quat.angle_between(est.quat[51], gyro_step) <= bound + 1e-12


@pytest.mark.parametrize("objective", list(MAG_OBJECTIVES))
@pytest.mark.parametrize("exact", [True, False])
def test_kernel_no_op_and_extreme_screened_samples_never_give_nan(objective, exact):
    rng = np.random.default_rng(5)
    n = 400
    gyr = rng.uniform(-30.0, 30.0, size=(1, n, 3))  # within the default 2000 deg/s range
    acc = rng.normal(size=(1, n, 3)) * rng.choice([1e-3, 1.0, 150.0], size=(1, n, 1))
    acc[0, ::7] = 0.0  # the screening's "no measurement"
    mag = rng.normal(size=(1, n, 3)) * rng.choice([1e-300, 1e-3, 50.0, 1e300], size=(1, n, 1))
    mag[0, ::5] = 0.0
    mag[0, 3::11] = acc[0, 3::11] * 4.0  # parallel to the accelerometer
    dt = rng.choice([0.0, DT, 0.25], size=n)
    # a no-op sample (dt = 0, no acc, no field) in the middle
    acc[0, 200], mag[0, 200], dt[200] = 0.0, 0.0, 0.0
    quats, flags, ref = _kernel(gyr, acc, mag, dt, objective, exact)
    assert np.isfinite(quats).all() and np.isfinite(ref).all()
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(quats[200], quats[199], rtol=0, atol=1e-15)
    assert flags[200] == 0
    # a non-zero field is never lost to over- or underflow: only a zero one is "no field"
    nonzero = np.any(mag[0] != 0.0, axis=1) & np.any(acc[0] != 0.0, axis=1)
    ignored = flags[nonzero]
    assert not np.any(((ignored & MAG_IGNORED) != 0) & ((ignored & MAG_REJECTED) == 0))
    if objective == "forward_measured":  # the fields along the accelerometer, at least
        assert np.count_nonzero(ignored & MAG_REJECTED) >= n // 11 - 5


def _kernel(gyr, acc, mag, dt, objective, exact, seed=5):
    """One sensor through the gradient step alone (no screening, no clock) from a random
    start, β = 0.5, ENU: quats, ``ignored`` bits, the fixed field reference."""
    n = gyr.shape[1]
    f = Gradient(beta=0.5, mag_objective=objective, integration="exact" if exact else "euler",
                 gravity_m_s2=9.81)
    f.reset(quat.normalize(np.random.default_rng(seed).normal(size=(1, 4))))
    row = f._state.rows[0]
    q, x, flags = np.empty((n, 4)), np.empty((n, kernel.N_X)), np.empty(n, dtype=np.uint16)
    coef = f._coefs[contract.N_SCOEF :]
    with np.errstate(over="ignore", under="ignore"):  # numpy scalars when the JIT is off
        for i in range(n):
            flags[i] = kernel._step(row, coef, dt[i], *gyr[0, i], *acc[0, i], *mag[0, i], True,
                                    q[i], x[i])
    ignored = x[:, kernel.L_IGNORED].astype(np.int8)
    # the step's flags are the ignored bits in the schema
    expected = np.where(ignored & ACC_IGNORED, Flag.ACC_IGNORED, 0) | np.where(
        ignored & MAG_REJECTED, Flag.MAG_IGNORED, 0
    )
    np.testing.assert_array_equal(flags, expected)
    return q, ignored, row[kernel.G_MAG_REF : kernel.G_MAG_REF + 2].copy()


@pytest.mark.parametrize("objective", list(MAG_OBJECTIVES))
def test_kernel_results_do_not_depend_on_the_field_unit_even_at_extremes(rec, objective):
    gyr, acc, mag = rec.gyr[None, :500], rec.acc[None, :500], rec.mag[None, :500]
    dt = np.full(500, DT)
    q_ut, f_ut, ref_ut = _kernel(gyr, acc, mag, dt, objective, True)
    for factor in (1e-200, 1e-3, 1e3, 1e200):  # squares under- and overflow at the ends
        q, f, ref = _kernel(gyr, acc, mag * factor, dt, objective, True)
        np.testing.assert_allclose(q, q_ut, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(f, f_ut)
        np.testing.assert_allclose(ref, ref_ut, rtol=0, atol=1e-12)


# -- restarts --------------------------------------------------------------------------------
def _gapped(rec, n=600, at=300, gap_s=1.0):
    gyr, acc, mag, t = _arrays(rec, n)
    t[at:] += gap_s
    return gyr, acc, mag, t


@pytest.mark.parametrize("with_mag", [True, False])
def test_gyro_restarts_from_the_measured_orientation_after_a_gap(rec, with_mag):
    gyr, acc, mag, t = _gapped(rec)
    mag = mag if with_mag else None
    f = GyroIntegration()
    q0 = quat.from_euler([2.0, 0.3, -0.4])  # far from the truth: only the first segment
    f.reset(q0)
    est = f.run(gyr=gyr, acc=acc, mag=mag, t=t)
    # before the gap: integration from q0
    expected = q0
    for i in range(1, 300):
        expected = quat.integrate(expected, gyr[i], DT)
    assert quat.angle_between(est.quat[299], expected) < 1e-9
    # at the gap: measured again over a window (estimator/restart_kernel.py), then
    # integrated from the window's last sample
    assert est.flags[300] == Flag.GAP | Flag.INITIALISING
    i1 = 300 + int(np.argmin(est.flags[300:] & Flag.INITIALISING))
    assert i1 > 300 and not est.flags[i1:].any()
    step = quat.integrate(est.quat[i1], gyr[i1 + 1], DT)
    assert quat.angle_between(est.quat[i1 + 1], step) < 1e-12
    err = error_series(est.quat, rec.quat_true[: len(est.quat)], est.frame, rec.frame)
    before = np.degrees(quat.angle_between(est.quat[299], rec.quat_true[299]))
    if with_mag:
        # so the error after the gap is the window's, not the q0 offset carried on
        assert np.degrees(err.total_rad[i1]) < 5.0 < before
    else:
        assert np.degrees(err.inclination_rad[i1]) < 5.0 < before


def test_gyro_restart_waits_for_a_usable_sample(rec):
    gyr, acc, mag, t = _gapped(rec)
    acc[300:303] = np.nan
    est = GyroIntegration().run(gyr=gyr, acc=acc, mag=mag, t=t)
    assert np.all(est.flags[300:303] & Flag.INITIALISING)
    # no usable acceleration yet in the window: the last orientation carried by the gyro
    np.testing.assert_allclose(est.quat[300], est.quat[299], atol=1e-15)
    assert quat.angle_between(est.quat[301], quat.integrate(est.quat[300], gyr[301], DT)) < 1e-12
    i1 = 300 + int(np.argmin(est.flags[300:] & Flag.INITIALISING))
    assert i1 > 303 and not est.flags[i1:].any()


def test_gradient_restart_keeps_the_fixed_reference_and_the_held_samples(rec):
    gyr, acc, mag, t = _gapped(rec)
    f = Gradient(mag_objective="fixed")
    f.run(gyr=gyr[:300], acc=acc[:300], mag=mag[:300], t=t[:300])
    ref = f.state.get("mag_ref")
    assert ref[0, 0] > 0.0
    est = f.run(gyr=gyr[300:], acc=acc[300:], mag=mag[300:], t=t[300:])
    restart = initial_orientation(acc[300:301], mag[300:301], "ENU")[0]
    np.testing.assert_allclose(est.quat[0], restart, atol=1e-15)
    # the field's reference is knowledge of the environment: kept, not measured again
    np.testing.assert_array_equal(f.state.get("mag_ref"), ref)
    # what a fresh reference at the restart would have been differs
    fresh = Gradient(mag_objective="fixed")
    fresh.run(gyr=gyr[300:], acc=acc[300:], mag=mag[300:], t=t[300:])
    assert np.max(np.abs(fresh.state.get("mag_ref") - ref)) > 1e-6
    # a restart (a start after the first) takes the new orientation and keeps the field
    # reference and the held samples: they belong to the sensors and the field
    rows = f.state.rows
    kept = slice(kernel.G_MAG_REF, kernel.N_ROW)
    assert np.all(rows[0, kernel.G_ACC_HELD : kernel.N_ROW] != 0.0)
    q0 = quat.from_euler([0.4, 0.1, -0.2])
    restarted = rows.copy()
    kernel.start(restarted, f._coefs, q0[None])
    np.testing.assert_array_equal(restarted[:, kept], rows[:, kept])
    np.testing.assert_allclose(restarted[0, contract.K_Q : contract.K_Q + 4], q0, atol=0)
    nwu = restarted[0, kernel.G_Q : kernel.G_Q + 4]
    assert quat.angle_between(quat.multiply(_FROM_NWU["ENU"], nwu), q0) < 1e-15


def test_gradient_after_a_gap_converges_like_the_clean_run(rec):
    gyr, acc, mag, t = _gapped(rec, n=rec.n_samples, at=500, gap_s=2.0)
    est = Gradient().run(gyr=gyr, acc=acc, mag=mag, t=t)
    clean = Gradient().run(rec)
    late = rec.t >= 10.0
    gap_err = quat.angle_between(est.quat[late], rec.quat_true[late])
    clean_err = quat.angle_between(clean.quat[late], rec.quat_true[late])
    # the same samples from 5 s after the gap: within 1.5x of the clean run
    assert np.sqrt(np.mean(gap_err**2)) <= 1.5 * np.sqrt(np.mean(clean_err**2))


# -- live samples (update_acc / update_mag / update_gyr) --------------------------------------
def _live(rec, n, acc, mag):
    """Acc every 4th gyro tick, mag every 10th; returns quats, per-tick flags, estimator."""
    f = Gradient()
    out, flags = [], []
    for i in range(n):
        if i % 4 == 0:
            f.update_acc(acc[i])
        if i % 10 == 0:
            f.update_mag(mag[i])
        out.append(f.update_gyr(rec.gyr[i], None if i == 0 else DT))
        flags.append(int(f.flags[0]))
    return np.array(out), np.array(flags), f


def test_live_non_finite_samples_are_held_flagged_and_skipped_like_run(rec):
    n = 300
    acc, mag = rec.acc[:n].copy(), rec.mag[:n].copy()
    acc[100] = np.nan  # held for ticks 100-103
    mag[200, 1] = np.inf  # held for ticks 200-209
    quats, flags, f = _live(rec, n, acc, mag)
    held_acc = acc[(np.arange(n) // 4) * 4]
    held_mag = mag[(np.arange(n) // 10) * 10]
    batch = Gradient().run(gyr=rec.gyr[:n], acc=held_acc, mag=held_mag, t=rec.t[:n])
    np.testing.assert_allclose(quats, batch.quat, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(flags, batch.flags)
    # every tick holding the NaN is flagged and is a gyro-only step, then the next sample
    # is used again
    bad_acc = Flag.INVALID | Flag.ACC_IGNORED | Flag.MAG_IGNORED
    assert np.all(flags[100:104] == bad_acc)
    for i in range(100, 104):
        assert quat.angle_between(quats[i], quat.integrate(quats[i - 1], rec.gyr[i], DT)) < 1e-12
    assert np.all(flags[200:210] == Flag.INVALID | Flag.MAG_IGNORED)
    assert flags[104] == 0 and flags[210] == 0
    assert np.count_nonzero(flags) == 14
    # the state holds the samples as received (not the screening's zero sentinel)
    assert f.state.get("acc_held")[0].tolist() == acc[296].tolist()


def test_live_unusable_first_sample_holds_the_output_until_a_usable_one(rec):
    f = Gradient(rate_hz=RATE_HZ)
    f.update_mag(rec.mag[0])
    f.update_acc([np.nan, 0.0, 9.8])
    q = f.update_gyr(rec.gyr[0])  # not refused: nothing usable to start from yet
    # the screening's flags and the hold (the field, usable, is not judged by the filter
    # before a start: nothing is used then)
    assert f.flags[0] == Flag.INVALID | Flag.ACC_IGNORED | Flag.INITIALISING
    np.testing.assert_array_equal(q, [1.0, 0.0, 0.0, 0.0])
    assert np.isnan(f.state.get("acc_held")[0, 0])
    f.update_gyr(rec.gyr[1])
    assert f.flags[0] & Flag.INITIALISING
    f.update_acc(rec.acc[2])
    q = f.update_gyr(rec.gyr[2])
    assert f.flags[0] == 0
    expected = initial_orientation(rec.acc[2:3], rec.mag[0:1], "ENU")[0]
    # started from the held samples at this tick (dt > 0: one interval from there)
    assert quat.angle_between(q, expected) < 2 * np.linalg.norm(rec.gyr[2]) * DT + 1e-9


# -- state and parameters --------------------------------------------------------------------
def test_gradient_state_is_complete_and_copies_are_independent(rec):
    f = Gradient(mag_objective="fixed")
    f.run(rec.slice(0, 50))
    state = f.state
    assert state is not None and state.rows is not f._state.rows
    assert state.get("mag_ref")[0, 0] > 0.0  # the fixed reference travels in the row
    np.testing.assert_array_equal(state.get("acc_held")[0], rec.acc[49])
    np.testing.assert_array_equal(state.get("mag_held")[0], rec.mag[49])
    nwu = state.get("quat_nwu")[0]
    assert quat.angle_between(quat.multiply(_FROM_NWU["ENU"], nwu), state.quat[0]) < 1e-15
    copied = state.copy()
    assert copied.rows is not state.rows and copied.clock is not state.clock
    np.testing.assert_array_equal(copied.rows, state.rows)
    # independence: changing the copy leaves the original as it was
    copied.rows[:] = -1.0
    copied.clock[:] = -1.0
    assert not np.any(state.rows == -1.0) and state.t_last_s == rec.t[49]
    # resuming from the state in another instance continues the same run
    other = Gradient(mag_objective="fixed")
    other.state = state
    rest = other.run(rec.slice(50, 120))
    whole = Gradient(mag_objective="fixed").run(rec.slice(0, 120))
    np.testing.assert_array_equal(rest.quat, whole.quat[50:])


def test_parameters_are_declared():
    base = {s.name for s in specs(Params)}
    own = {s.name: s for s in specs(GradientParams) if s.name not in base}
    assert set(own) == {"beta", "mag_objective", "use_mag", "integration", "gravity_m_s2"}
    assert all(s.help for s in own.values())
    assert (own["beta"].unit, own["beta"].ge) == ("rad/s", 0)
    assert own["mag_objective"].choices == tuple(MAG_OBJECTIVES)
    assert GradientParams(beta=0).beta == 0.0  # ge: the bound itself is allowed
    with pytest.raises(ValueError, match="parameter gravity_m_s2 must be a finite number, > 0"):
        GradientParams(gravity_m_s2=0.0)
    # plain integration has nothing of its own beyond the shared input policy
    assert [s.name for s in specs(GyroParams)] == [s.name for s in specs(Params)]
    assert GyroIntegration(max_gap_s=0.5).params.max_gap_s == 0.5


@pytest.mark.parametrize("objective", list(MAG_OBJECTIVES))
def test_gradient_does_not_depend_on_the_field_unit(rec, objective):
    micro = Gradient(mag_objective=objective).run(rec)
    for factor in (1000.0, 0.01):
        other = Gradient(mag_objective=objective).run(
            gyr=rec.gyr, acc=rec.acc, mag=rec.mag * factor, t=rec.t
        )
        np.testing.assert_allclose(other.quat, micro.quat, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(other.flags, micro.flags)
