"""bachmann, bachmann-accmag and ekf under the input policy: screened sentinels, restarts,
flags, kernel safety and the field's unit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from margtrack import frames, sim
from margtrack import quaternion as quat
from margtrack.accuracy import error_series
from margtrack.estimator import Flag
from margtrack.estimator import skeleton as kc
from margtrack.methods.bachmann import Bachmann, BachmannAccMag
from margtrack.methods.bachmann import kernel as bachmann_kernel
from margtrack.methods.ekf import MarinsEkf
from margtrack.methods.ekf import kernel as ekf_kernel
from margtrack.methods.rest_null import RestNullState, subtract_rest_null

pytestmark = pytest.mark.kernel

Q0 = quat.from_euler([0.5, 0.2, -0.3])
DIP = 62.0
METHODS = [Bachmann, BachmannAccMag, MarinsEkf, lambda: MarinsEkf(approach=1),
           lambda: MarinsEkf(bias_states=True)]


def _mems(seconds=6.0, rate=100.0, seed=3, **motion):
    traj = sim.random_motion(seconds, rate, seed=seed, max_rate_deg_s=150.0, **motion)
    return sim.simulate(traj, gyr_errors=sim.SensorErrors.mems_gyr(),
                        acc_errors=sim.SensorErrors.mems_acc(),
                        mag_errors=sim.SensorErrors.mems_mag(), seed=seed)


def _cut(rec, start, stop):
    """The recording without samples [start, stop): a gap of (stop - start) samples."""
    keep = np.ones(rec.n_samples, dtype=bool)
    keep[start:stop] = False
    return dataclasses.replace(
        rec, t=rec.t[keep], gyr=rec.gyr[keep], acc=rec.acc[keep], mag=rec.mag[keep],
        quat_true=rec.quat_true[keep], movement=None,
    )


# -- the start: the first usable sample of each sensor, vectorised --------------------------
@pytest.mark.parametrize("make", [Bachmann, MarinsEkf, lambda: MarinsEkf(bias_states=True)])
def test_each_sensor_starts_at_its_first_usable_sample_and_measures_its_dip_there(make):
    rec = sim.simulate(sim.static(1.0, 100.0, q0=Q0), dip_deg=DIP)
    zeros = (0, 4, 9)  # leading samples the screening turns into "no measurement"
    acc = np.stack([rec.acc] * 3)
    mag = np.stack([rec.mag] * 3)
    for s, k in enumerate(zeros):
        acc[s, :k] = 0.0
        mag[s, :k] = np.nan if s == 2 else 0.0
    est = make()
    out = est.run(gyr=np.stack([rec.gyr] * 3), acc=acc, mag=mag, t=rec.t)
    np.testing.assert_allclose(np.degrees(est.state.get("dip_rad")[:, 0]), DIP, atol=1e-9)
    for s, k in enumerate(zeros):
        initialising = (out.flags[s] & Flag.INITIALISING) != 0
        np.testing.assert_array_equal(np.flatnonzero(initialising), np.arange(k))
        # exact data: the orientation from the first usable sample on is the truth
        assert np.max(quat.angle_between(out.quat[s, k:], Q0)) < 1e-9
        alone = make().run(gyr=rec.gyr, acc=acc[s], mag=mag[s], t=rec.t)
        np.testing.assert_allclose(out.quat[s], alone.quat, atol=1e-15)


def test_a_start_from_the_accelerometer_alone_takes_its_heading_from_the_first_field():
    # the field unusable for the first samples: bachmann (magnetometer optional) starts
    # from the accelerometer with an arbitrary heading, then the first field sets it
    q_true = quat.from_euler([2.6, 0.1, -0.2])  # heading 149 deg
    rec = sim.simulate(sim.static(1.0, 100.0, q0=q_true), dip_deg=DIP)
    mag = rec.mag.copy()
    mag[:5] = 0.0
    out = Bachmann().run(gyr=rec.gyr, acc=rec.acc, mag=mag, t=rec.t)
    assert not np.any(out.flags & Flag.INITIALISING)  # started at sample 0
    err = error_series(out.quat, rec.quat_true, out.frame, rec.frame)
    assert np.all(np.abs(err.inclination_rad) < 1e-9)
    assert np.all(np.degrees(np.abs(err.heading_rad[:5])) > 90.0)
    assert np.max(quat.angle_between(out.quat[5:], q_true)) < 1e-9


def test_a_sensor_without_a_usable_field_yet_gets_gravity_only_steps():
    # the field along gravity (a sample the contract cannot start from with it) is no
    # reference: the dip stays unmeasured and nothing becomes NaN
    rec = sim.simulate(sim.static(0.3, 100.0, q0=Q0), dip_deg=DIP)
    mag = rec.acc.copy()  # parallel to the accelerometer everywhere
    est = Bachmann()
    est.reset(Q0)
    out = est.run(gyr=rec.gyr, acc=rec.acc, mag=mag, t=rec.t)
    assert np.isnan(est.state.get("dip_rad")[0, 0])
    assert np.all(out.outputs["degenerate"] == bachmann_kernel.NO_FIELD_REFERENCE)
    assert np.all(out.flags & Flag.MAG_IGNORED)
    assert np.max(quat.angle_between(out.quat, Q0)) < 1e-12


# -- sentinels in the middle of a run -----------------------------------------------------------
@pytest.mark.parametrize("make", METHODS)
def test_a_no_op_sample_leaves_the_orientation_unchanged(make):
    rec = _mems(2.0)
    t = rec.t.copy()
    t[100] = t[99]  # a repeated timestamp: dt = 0, acc and mag zero after screening
    out = make().run(gyr=rec.gyr, acc=rec.acc, mag=rec.mag, t=t)
    assert out.flags[100] & Flag.CLOCK
    np.testing.assert_array_equal(out.quat[100], out.quat[99])


@pytest.mark.parametrize("approach", [1, 2])
def test_ekf_without_a_field_updates_from_the_gyroscope_and_the_gravity_direction(approach):
    rec = _mems(1.0, seed=2, translation_m=0.02)
    mag = rec.mag.copy()
    mag[50] = 0.0
    est = MarinsEkf(approach=approach).run(gyr=rec.gyr, acc=rec.acc, mag=mag, t=rec.t)
    assert est.outputs["degenerate"][50] == ekf_kernel.ZERO_MAG
    assert est.flags[50] & Flag.MAG_IGNORED and not est.flags[50] & Flag.ACC_IGNORED
    # sample 50 again from the state before it: z = [gyro, â], h = [ω, R(q)ᵀ up / |q|²]
    part = MarinsEkf(approach=approach)
    part.run(gyr=rec.gyr[:50], acc=rec.acc[:50], mag=mag[:50], t=rec.t[:50])
    s, p = part.state, part.params
    h = rec.t[50] - rec.t[49]
    x0 = np.r_[s.get("gyr_est_rad_s")[0], s.get("quat")[0]]
    xp, f, g, d, qn = np.empty(7), np.empty((7, 7)), np.empty((4, 3)), np.empty((4, 3)), \
        np.empty((7, 7))
    tau = p.axis_values("tau_s")
    ekf_kernel.transition(x0, h, tau, xp, f, g, d)
    ekf_kernel.process_noise(g, h, tau, p.axis_values("rate_noise_rad_s_sqrt_hz") ** 2, qn)
    pp = f @ s.get("cov")[0].reshape(7, 7) @ f.T + qn
    up = frames.up("ENU")

    def reading(q):
        return quat.rotate_inverse(q / np.linalg.norm(q), up)

    hm = np.zeros((6, 7))
    hm[:3, :3] = np.eye(3)
    for j in range(4):  # by central differences, independent of the kernel's Jacobian
        dq = np.zeros(4)
        dq[j] = 1e-7
        hm[3:, 3 + j] = (reading(xp[3:] + dq) - reading(xp[3:] - dq)) / 2e-7
    acc_var = (16 * p.quat_noise_per_sqrt_hz**2 if approach == 2
               else p.acc_noise_m_s2_sqrt_hz**2 / p.gravity_m_s2**2)
    r = np.diag(np.r_[p.axis_values("gyr_noise_rad_s_sqrt_hz") ** 2, np.full(3, acc_var)] / h)
    gain = pp @ hm.T @ np.linalg.inv(hm @ pp @ hm.T + r)
    innov = np.r_[rec.gyr[50] - xp[:3], rec.acc[50] / np.linalg.norm(rec.acc[50]) - reading(xp[3:])]
    x = xp + gain @ innov
    np.testing.assert_allclose(est.quat[50], x[3:] / np.linalg.norm(x[3:]), atol=1e-9)
    np.testing.assert_allclose(est.outputs["gyr_est_rad_s"][50], x[:3], atol=1e-9)


@pytest.mark.parametrize("approach", [1, 2])
def test_ekf_holds_the_inclination_while_the_field_is_ignored_for_long(approach):
    # 20 s of motion with an uncompensated 1 deg/s gyro bias, the field unusable after 2 s:
    # the gravity rows hold the inclination where it is with the field (the bias leaves a
    # steady error either way); without them (gyro alone) it drifts; the heading, seen by
    # the field only, drifts
    rec = sim.simulate(sim.random_motion(20.0, 100.0, seed=5, max_rate_deg_s=100.0),
                       gyr_errors=sim.SensorErrors(bias=tuple(np.radians([1.0, -1.0, 1.0]))),
                       seed=5)
    worst = {}
    for case in ("field", "no field", "gyro alone"):
        acc, mag = rec.acc.copy(), rec.mag.copy()
        if case != "field":
            mag[200:] = 0.0
        if case == "gyro alone":
            acc[200:] = 0.0
        est = MarinsEkf(approach=approach, gyr_null_rest_s=0.0).run(
            gyr=rec.gyr, acc=acc, mag=mag, t=rec.t
        )
        err = error_series(est.quat, rec.quat_true, est.frame, rec.frame)
        worst[case] = (np.abs(err.inclination_rad[-200:]).max(),
                       np.abs(err.heading_rad[-200:]).max())
    # the inclination without the field stays near that with it (approach 2: 9.4 against
    # 7.7 deg, approach 1: 2.9 against 1.9) and far from the gyro's alone (17 deg)
    field, no_field, gyro = worst["field"][0], worst["no field"][0], worst["gyro alone"][0]
    assert abs(no_field - field) < 0.25 * (gyro - no_field), worst
    assert worst["no field"][1] > 1.5 * worst["field"][1], worst


# -- restarts -------------------------------------------------------------------------------
def test_ekf_restart_starts_the_covariance_afresh_and_keeps_dip_and_gyro_null():
    rec = _mems(8.0, seed=4)
    gap = _cut(rec, 500, 600)
    est = MarinsEkf()
    first = est.run(gap.slice(0, 500))
    dip, null = est.state.get("dip_rad"), est.gyr_bias_rad_s.copy()
    second = est.run(gap.slice(500))
    p = est.params
    init = np.r_[np.full(3, p.init_rate_std_rad_s**2), np.full(4, p.init_quat_std**2)]
    assert second.flags[0] & Flag.GAP
    i = int(np.argmin(second.flags & Flag.INITIALISING))  # the restart: the window's last
    assert i > 0
    np.testing.assert_array_equal(second.outputs["cov_diag"][i], init)
    np.testing.assert_array_equal(second.outputs["gyr_est_rad_s"][i], 0.0)
    assert first.outputs["cov_diag"][-1, 3:].max() < 1e-2 * init[3:].max()
    np.testing.assert_array_equal(est.state.get("dip_rad"), dip)
    np.testing.assert_array_equal(est.gyr_bias_rad_s, null)
    np.testing.assert_array_equal(second.outputs["gyr_null_rad_s"][0], null[0])


def test_bachmann_restart_keeps_dip_and_null_and_raises_the_gain_as_one_over_t():
    rec = _mems(8.0, seed=4)
    gap = _cut(rec, 500, 600)
    # a new correction every 2nd sample: sample 501 applies the step computed at 500
    raised, plain = Bachmann(correction_interval=2), Bachmann(correction_interval=2,
                                                               restart_gain=0.0)
    a, b = raised.run(gap), plain.run(gap)
    # the first start is not raised: identical up to the gap
    np.testing.assert_array_equal(a.quat[:500], b.quat[:500])
    assert a.flags[500] & Flag.GAP
    # the restart: the window's last sample (estimator/restart_kernel.py)
    r = 500 + int(np.argmin(a.flags[500:] & Flag.INITIALISING))
    assert r > 500 and a.outputs["new_correction"][r]
    # the restart sample: the same start and step, k = 1/(0 + 1/restart_gain)
    k0, gain = raised.params.restart_gain, raised.params.gain
    corr_a, corr_b = a.outputs["correction_rad_s"], b.outputs["correction_rad_s"]
    np.testing.assert_allclose(corr_a[r], corr_b[r] * k0 / gain, rtol=1e-12)
    # one interval later, the same held step at k = 1/(t + 1/restart_gain)
    t = gap.t[r + 1] - gap.t[r]
    np.testing.assert_allclose(corr_a[r + 1], corr_a[r] * (1 / (t + 1 / k0)) / k0, rtol=1e-12)
    np.testing.assert_allclose(corr_b[r + 1], corr_b[r], rtol=1e-12)
    np.testing.assert_allclose(raised.state.get("restart_elapsed_s")[:, 0],
                               gap.t[-1] - gap.t[r])
    assert plain.state.get("restart_elapsed_s")[0, 0] == -1.0
    # the sensor's knowledge survives the gap: the dip and the gyro null
    dip = raised.state.get("dip_rad")[0, 0]
    np.testing.assert_array_equal(dip, plain.state.get("dip_rad")[0, 0])
    assert np.degrees(dip) == pytest.approx(sim.DEFAULT_DIP_DEG, abs=3.0)
    null = a.outputs["gyr_null_rad_s"]
    np.testing.assert_array_equal(null[500], null[499])
    np.testing.assert_array_equal(raised.gyr_bias_rad_s[0], null[-1])


def test_bachmann_recovers_from_a_gap_faster_with_the_raised_gain():
    rec = _mems(40.0, seed=3, translation_m=0.05)
    gap = _cut(rec, 2000, 2100)  # 1 s gap at 20 s
    window = (gap.t >= 21.0) & (gap.t < 31.0)
    rmse = {}
    for restart_gain in (10.0, 0.0):
        est = Bachmann(restart_gain=restart_gain).run(gap)
        err = quat.angle_between(est.quat, gap.quat_true)
        rmse[restart_gain] = np.sqrt(np.mean(err[window] ** 2))
    assert rmse[10.0] < 0.6 * rmse[0.0], rmse  # measured 2.9 against 6.8 deg


# -- flags --------------------------------------------------------------------------------------
def test_ekf_degenerate_codes_are_on_the_flag_schema():
    rec = _mems(1.0, seed=2)
    acc, mag = rec.acc.copy(), rec.mag.copy()
    acc[40] = 0.0
    acc[60] = mag[60]  # along the field: TRIAD/Gauss-Newton cannot use the pair
    out = MarinsEkf(mag_norm_tol=1e9, mag_dip_tol_deg=360.0).run(
        gyr=rec.gyr, acc=acc, mag=mag, t=rec.t
    )
    assert out.outputs["degenerate"][60] == ekf_kernel.PARALLEL
    assert out.flags[40] & Flag.ACC_IGNORED
    both = Flag.ACC_IGNORED | Flag.MAG_IGNORED
    assert out.flags[60] & both == both
    clean = np.ones(rec.n_samples, dtype=bool)
    clean[[40, 60]] = False
    assert not out.flags[clean].any()


# -- safety of the kernels on their own ---------------------------------------------------------
def _steps(kernel, coef, q0, gyr, acc, mag, dt, width):
    """The kernel's per-sample step over the samples from a start at q0 (no screening)."""
    row = np.zeros(kernel.N_ROW)
    kernel._start(row, coef, True, *q0)
    q, x = np.empty((len(dt), 4)), np.empty((len(dt), width))
    for i in range(len(dt)):
        kernel._step(row, coef, dt[i], *gyr[i], *acc[i], *mag[i], True, q[i], x[i])
    return row, q, x


def test_kernels_stay_finite_for_absurd_finite_input():
    n = 6
    gyr = np.zeros((n, 3))
    gyr[2] = [1e300, -1e300, 1e300]
    gyr[3] = [1e308, 0.0, 0.0]
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    acc[4] = [1e300, 1e-300, 0.0]
    mag = np.tile([0.0, 20.0, -40.0], (n, 1))
    mag[5] = [1e-320, 0.0, 1e300]
    dt = np.array([0.0, 0.01, 1e10, 0.01, 0.01, 0.01])
    own = kc.N_SCOEF  # the method's coefficients follow the screening's
    coef = Bachmann(gain=1e3, mag_weight=1.0, mag_dip_ref_deg=60.0)._coefs[own:]
    _, q, _ = _steps(bachmann_kernel, coef, Q0, gyr, acc, mag, dt, 9)
    assert np.all(np.isfinite(q)) and np.allclose(np.linalg.norm(q, axis=-1), 1.0)
    for approach in (1, 2):
        coef = MarinsEkf(approach=approach, init_quat_std=0.5)._coefs[own:]
        row, qe, x = _steps(ekf_kernel, coef, Q0, gyr, acc, mag, dt, 15)
        assert np.all(np.isfinite(qe)) and np.allclose(np.linalg.norm(qe, axis=-1), 1.0)
        assert np.all(np.isfinite(x)) and np.all(np.isfinite(row[ekf_kernel.E_P:][:49]))
    state = RestNullState.new(1)
    _, null = subtract_rest_null(state, gyr[None], acc[None], mag[None], dt, 0.5)
    assert np.all(np.isfinite(null)) and np.abs(null).max() < 1.0


# -- the field's unit ---------------------------------------------------------------------------
@pytest.mark.parametrize("make", METHODS)
def test_results_do_not_depend_on_the_field_unit(make):
    rec = _mems(5.0, seed=6, translation_m=0.05)
    reference = make().run(rec).quat
    for factor in (1000.0, 0.01):
        scaled = make().run(gyr=rec.gyr, acc=rec.acc, mag=rec.mag * factor, t=rec.t).quat
        np.testing.assert_allclose(scaled, reference, atol=1e-9)


def test_a_bad_state_set_by_hand_is_refused_and_leaves_the_estimator_as_it_was():
    rec = _mems(1.0)
    est = Bachmann()
    est.run(rec.slice(0, 50))
    state = est.state
    offset, _ = Bachmann.state_layout["quat"]
    state.rows[:, offset : offset + 4] = np.nan
    with pytest.raises(ValueError, match="quaternion must be finite and non-zero"):
        est.state = state
    assert np.all(np.isfinite(est.state.get("quat"))) and est.state.get("cycle")[0, 0] == 50
