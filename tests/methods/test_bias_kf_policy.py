"""BiasKalman under the input policy: sentinels, partial updates, restarts, units, flags."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from margtrack import frames, sim
from margtrack import quaternion as quat
from margtrack.accuracy import error_series, summarize
from margtrack.estimator import Flag, specs
from margtrack.methods.bias_kf import (
    BiasKalman,
    BiasKalmanParams,
    covariance,
    initial_covariance,
    kernel,
)

BIAS = np.radians([0.4, -0.3, 0.5])


def _moving(seconds=20.0, seed=2):
    traj = sim.random_motion(seconds, 100.0, seed=seed, max_rate_deg_s=150.0)
    return sim.simulate(
        traj, frame="ENU",
        gyr_errors=sim.SensorErrors(noise_density=np.radians(0.01), bias=tuple(BIAS)),
        acc_errors=sim.SensorErrors.mems_acc(), mag_errors=sim.SensorErrors.mems_mag(),
        seed=seed,
    )


# -- units ----------------------------------------------------------------------------------

def test_the_field_unit_does_not_change_the_estimate():
    # nT and G instead of µT, with a disturbance so the norm/dip terms act too
    rec = _moving()
    mag = rec.mag.copy()
    mag[800:1200] += np.array([30.0, -20.0, 10.0])
    ref = BiasKalman().run(gyr=rec.gyr, acc=rec.acc, mag=mag, t=rec.t)
    assert (ref.flags[800:1200] & Flag.MAG_DISTURBED).any()  # the disturbance terms did act
    for scale in (1000.0, 0.01):
        est = BiasKalman().run(gyr=rec.gyr, acc=rec.acc, mag=mag * scale, t=rec.t)
        np.testing.assert_allclose(est.quat, ref.quat, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(est.flags, ref.flags)


def test_field_noise_is_relative_only_their_ratio_counts():
    rec = _moving(5.0)
    a = BiasKalman(mag_noise_ut_sqrt_hz=0.1, mag_field_ut=50.0).run(rec)
    b = BiasKalman(mag_noise_ut_sqrt_hz=0.2, mag_field_ut=100.0).run(rec)
    c = BiasKalman(mag_noise_ut_sqrt_hz=0.2, mag_field_ut=50.0).run(rec)
    np.testing.assert_array_equal(a.quat, b.quat)
    assert np.max(np.abs(a.quat - c.quat)) > 1e-6


# -- sentinels: partial updates, no-op samples, never NaN ----------------------------------

def _static_with_bias_step(step_axis):
    """40 s at rest with a 2 deg/s bias step at 15 s about ``step_axis`` (earth frame)."""
    q0 = quat.from_euler([0.7, 0.2, -0.3])
    rec = sim.simulate(
        sim.static(40.0, 100.0, q0=q0), frame="ENU",
        gyr_errors=sim.SensorErrors(noise_density=np.radians(0.01)),
        acc_errors=sim.SensorErrors.mems_acc(), mag_errors=sim.SensorErrors.mems_mag(), seed=4,
    )
    gyr = rec.gyr.copy()
    gyr[1500:] += np.radians(2.0) * quat.rotate_inverse(q0, np.asarray(step_axis, float))
    return rec, gyr


def _stretch_errors(rec, gyr, zero_acc, zero_mag):
    part = slice(1500, 3500)
    acc, mag = rec.acc.copy(), rec.mag.copy()
    if zero_acc:
        acc[part] = 0.0
    if zero_mag:
        mag[part] = 0.0
    est = BiasKalman().run(gyr=gyr, acc=acc, mag=mag, t=rec.t)
    assert np.all(np.isfinite(est.quat))
    errors = summarize(error_series(est.quat[part], rec.quat_true[part], "ENU", "ENU"))
    return errors, est


def test_a_stretch_without_field_still_corrects_the_tilt():
    # a horizontal bias step tilts a filter that only predicts (measured: incl 22.5 deg);
    # without the field the accelerometer alone keeps the tilt as with both (5.8 deg: the
    # slow bias walk lets the step through for a while)
    rec, gyr = _static_with_bias_step([1.0, 0.0, 0.0])
    both, _ = _stretch_errors(rec, gyr, False, False)
    no_mag, est = _stretch_errors(rec, gyr, False, True)
    neither, _ = _stretch_errors(rec, gyr, True, True)
    assert np.all(est.outputs["degenerate"][1500:3500] == kernel.ZERO_MAG)
    assert np.all(est.flags[1500:3500] & Flag.MAG_IGNORED)  # the screening's flag
    assert no_mag.inclination_rmse_deg < 1.05 * both.inclination_rmse_deg
    assert no_mag.inclination_rmse_deg < 0.4 * neither.inclination_rmse_deg


def test_a_stretch_without_accelerometer_still_corrects_the_heading():
    # a bias step about up turns the heading of a filter that only predicts (27.5 deg);
    # the field levelled by the predicted up keeps it as with both sensors (11.2 deg)
    rec, gyr = _static_with_bias_step([0.0, 0.0, 1.0])
    both, _ = _stretch_errors(rec, gyr, False, False)
    no_acc, est = _stretch_errors(rec, gyr, True, False)
    neither, _ = _stretch_errors(rec, gyr, True, True)
    assert np.all(est.outputs["degenerate"][1500:3500] == kernel.ZERO_ACC)
    assert np.all(est.flags[1500:3500] & Flag.ACC_IGNORED)
    assert no_acc.heading_rmse_deg < 1.05 * both.heading_rmse_deg
    assert no_acc.heading_rmse_deg < 0.5 * neither.heading_rmse_deg


def test_reduced_update_equals_the_textbook_kalman_update():
    # oracle: K = P Hᵀ (H P Hᵀ + V)⁻¹, P⁺ = (I - KH) P with H = [Hq 0], m = 1 and 2 rows
    rng = np.random.default_rng(0)
    a = rng.normal(size=(7, 7))
    p0 = a @ a.T / 7.0 + 0.1 * np.eye(7)
    q = quat.normalize(rng.normal(size=4))
    qt = np.empty((4, 3))
    kernel.fill_qtilde(*q, qt)
    axes = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    for m in (1, 2):
        hq = np.zeros((3, 4))
        hq[:m] = (qt @ axes[:, :m]).T
        v = np.zeros((3, 3))
        v[:m, :m] = np.diag(rng.uniform(0.01, 0.1, m))
        innov = np.r_[rng.normal(size=m), np.zeros(4 - m)]
        p, dx = p0.copy(), np.empty(7)
        ok = kernel._reduced_update(p, hq, m, v, innov, np.zeros((4, 4)), np.empty((4, 7)),
                                    np.empty((7, 4)), np.empty((3, 7)), np.empty((7, 7)),
                                    np.empty((7, 3)), np.empty((7, 4)), dx)
        assert ok
        h = np.c_[hq[:m], np.zeros((m, 3))]
        gain = p0 @ h.T @ np.linalg.inv(h @ p0 @ h.T + v[:m, :m])
        np.testing.assert_allclose(dx, gain @ innov[:m], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(p, (np.eye(7) - gain @ h) @ p0, rtol=1e-10, atol=1e-13)
        assert np.all(p == p.T)


def test_a_no_op_sample_leaves_the_state_unchanged():
    # a repeated timestamp is skipped by the screening: dt = 0, acc = mag = 0
    rec = _moving(2.0)
    t = rec.t.copy()
    t[100] = t[99]
    est = BiasKalman().run(gyr=rec.gyr, acc=rec.acc, mag=rec.mag, t=t)
    assert est.flags[100] & Flag.CLOCK
    np.testing.assert_array_equal(est.quat[100], est.quat[99])
    np.testing.assert_array_equal(est.outputs["gyr_bias_rad_s"][100],
                                  est.outputs["gyr_bias_rad_s"][99])
    np.testing.assert_array_equal(est.outputs["cov_diag"][100], est.outputs["cov_diag"][99])
    # the kernel itself, given the sentinels directly (and a rate that must not be used)
    est2 = BiasKalman()
    est2.run(rec.slice(0, 50))
    s = est2.state
    q, cov = s.get("filter_quat"), covariance(s)
    out = [np.empty((1, 1, 4)), np.empty((1, 1, 3)), np.empty((1, 1, 7)),
           np.empty((1, 1), dtype=np.int8), np.empty((1, 1), dtype=np.bool_)]
    p = BiasKalmanParams()
    gyr_var, bias_var = p.axis_variances()
    cov_state = cov.copy()
    kernel.bias_kf_extended(
        q.copy(), s.get("gyr_bias_rad_s"), cov_state, s.get("field_reference"), np.ones((1, 1, 3)),
        np.zeros((1, 1, 3)), np.zeros((1, 1, 3)), np.zeros(1), frames.up("ENU"),
        frames.mag_reference("ENU", 0.0), gyr_var, bias_var, 1e-6, 0.04, 96.0, 4e-6,
        True, 1e-6, 0.5, 0.05, 0.5, 20.0, 1.5, 0.25, 0.35, *out,
    )
    np.testing.assert_array_equal(out[0][0, 0], q[0])
    np.testing.assert_array_equal(cov_state, cov)
    assert out[3][0, 0] == kernel.OK


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # norms of 1e300
def test_no_nan_and_no_exception_whatever_the_input():
    rng = np.random.default_rng(5)
    rec = _moving(10.0, seed=5)
    gyr, acc, mag = rec.gyr.copy(), rec.acc.copy(), rec.mag.copy()
    n = rec.n_samples
    for arr, values in ((gyr, (np.nan, np.inf, 1e300, 100.0)),
                        (acc, (np.nan, -np.inf, 0.0, 1e6, 1e-300)),
                        (mag, (np.nan, np.inf, 0.0, 1e-300, 1e300))):
        idx = rng.choice(n, 60, replace=False)
        arr[idx, rng.integers(0, 3, 60)] = rng.choice(values, 60)
    acc[500:520] = 0.0
    mag[600:700] = 0.0
    acc[800] = mag[800]  # parallel
    t = rec.t.copy()
    t[300] = np.nan
    t[301:] += 1.0  # a gap
    est = BiasKalman().run(gyr=gyr, acc=acc, mag=mag, t=t, check_units=False)
    assert np.all(np.isfinite(est.quat))
    assert np.all(np.isfinite(est.outputs["gyr_bias_rad_s"]))
    assert np.all(np.isfinite(est.outputs["cov_diag"]))
    np.testing.assert_allclose(np.linalg.norm(est.quat, axis=1), 1.0, atol=1e-12)
    # and still tracking at the end
    err = quat.angle_between(est.quat[-200:], rec.quat_true[-200:])
    assert np.degrees(np.sqrt(np.mean(err**2))) < 5.0


# -- restarts -------------------------------------------------------------------------------

def test_a_restart_keeps_the_bias_and_its_covariance_and_resets_the_attitude():
    rec = _moving(30.0)
    keep = np.r_[0:1500, 2000:rec.n_samples]  # a 5 s gap at 15 s
    gapped = dataclasses.replace(
        rec, t=rec.t[keep], gyr=rec.gyr[keep], acc=rec.acc[keep], mag=rec.mag[keep],
        quat_true=rec.quat_true[keep], movement=None,
    )
    est = BiasKalman()
    out = est.run(gapped)
    g = 1500  # the first sample after the gap: the restart's window opens
    assert out.flags[g] & Flag.GAP
    i = g + int(np.argmin(out.flags[g:] & Flag.INITIALISING))  # the restart: its last
    assert i > g
    b = out.outputs["gyr_bias_rad_s"]
    c = out.outputs["cov_diag"]
    np.testing.assert_array_equal(b[i], b[g - 1])  # kept, and learned before the gap:
    assert np.all(np.abs(b[g - 1] - BIAS) < 4.0 * np.sqrt(c[g - 1, 4:]))
    assert np.all(np.sqrt(c[g - 1, 4:]) < 0.25 * est.params.init_bias_std_rad_s)
    np.testing.assert_array_equal(c[i, 4:], c[g - 1, 4:])
    fresh = initial_covariance(out.quat[i : i + 1], est.params.init_angle_std_rad, 1.0)[0]
    np.testing.assert_allclose(c[i, :4], np.diag(fresh)[:4], rtol=1e-12)


def test_restart_drops_the_attitude_bias_correlation_of_the_restarted_sensor_only():
    est = BiasKalman()
    rec = _moving(5.0)
    est.run(gyr=np.stack([rec.gyr] * 2), acc=np.stack([rec.acc] * 2),
            mag=np.stack([rec.mag] * 2), t=rec.t)
    state = est.state
    before, bias = covariance(state), state.get("gyr_bias_rad_s")
    field_ref = state.get("field_reference")
    assert np.max(np.abs(before[1, :4, 4:])) > 0.0
    q0 = np.array([[1.0, 0.0, 0.0, 0.0]])
    kernel.start(state.rows[1:], est._coefs, q0)  # what a restart after a gap does
    after = covariance(state)
    np.testing.assert_array_equal(after[0], before[0])  # the other sensor untouched
    np.testing.assert_array_equal(after[1, 4:, 4:], before[1, 4:, 4:])
    assert np.all(after[1, :4, 4:] == 0.0) and np.all(after[1, 4:, :4] == 0.0)
    np.testing.assert_array_equal(
        after[1, :4, :4], initial_covariance(q0, est.params.init_angle_std_rad, 0.0)[0, :4, :4]
    )
    np.testing.assert_array_equal(state.get("gyr_bias_rad_s"), bias)
    np.testing.assert_array_equal(state.get("field_reference"), field_ref)
    np.testing.assert_array_equal(state.get("filter_quat")[1], q0[0])
    np.testing.assert_array_equal(state.quat[1], q0[0])


def test_after_a_gap_the_error_returns_to_the_no_gap_figure():
    rec = _moving(40.0, seed=3)
    keep = np.r_[0:2000, 2500:rec.n_samples]
    gapped = dataclasses.replace(
        rec, t=rec.t[keep], gyr=rec.gyr[keep], acc=rec.acc[keep], mag=rec.mag[keep],
        quat_true=rec.quat_true[keep], movement=None,
    )
    whole = BiasKalman().run(rec)
    after = BiasKalman().run(gapped)
    i, j = np.searchsorted(gapped.t, 30.0), np.searchsorted(rec.t, 30.0)

    def rms(q, truth):
        return np.sqrt(np.mean(quat.angle_between(q, truth) ** 2))

    assert rms(after.quat[i:], gapped.quat_true[i:]) < 1.5 * rms(whole.quat[j:], rec.quat_true[j:])


# -- state accessors, flags, parameters ---------------------------------------------------

def test_bias_accessors_read_the_state_and_its_covariance():
    rec = _moving(10.0)
    est = BiasKalman()
    assert est.gyr_bias_rad_s is None
    out = est.run(rec)
    np.testing.assert_array_equal(est.gyr_bias_rad_s[0], out.outputs["gyr_bias_rad_s"][-1])
    np.testing.assert_array_equal(est.gyr_bias_sd_rad_s[0],
                                  np.sqrt(out.outputs["cov_diag"][-1, 4:]))
    assert np.all(np.abs(est.gyr_bias_rad_s[0] - BIAS) < 4.0 * est.gyr_bias_sd_rad_s[0])


def test_the_method_flags_a_magnetic_disturbance_and_the_screening_does_not_gate():
    rec = _moving(20.0)
    mag = rec.mag.copy()
    mag[800:1200] += np.array([30.0, -20.0, 10.0])  # body-fixed: norm 13-79 µT while turning
    est = BiasKalman().run(gyr=rec.gyr, acc=rec.acc, mag=mag, t=rec.t)
    disturbed = (est.flags & Flag.MAG_DISTURBED) != 0
    norm_off = np.abs(np.linalg.norm(mag, axis=1) / sim.DEFAULT_FIELD_UT - 1.0)
    assert np.all(disturbed[norm_off > 0.3])  # beyond mag_norm_tol = 0.25 with a margin
    assert np.count_nonzero(norm_off > 0.3) > 200
    assert not disturbed[:800].any() and not disturbed[1200:].any()
    assert not (est.flags & Flag.MAG_IGNORED).any()  # still used, with a large variance
    assert BiasKalman.rejects_mag_disturbance
    # the tolerances are the shared parameters: a wider one flags nothing here
    wide = BiasKalman(mag_norm_tol=0.9, mag_dip_tol_deg=90.0).run(
        gyr=rec.gyr, acc=rec.acc, mag=mag, t=rec.t)
    assert not (wide.flags & Flag.MAG_DISTURBED).any()
    np.testing.assert_array_equal(wide.quat, est.quat)  # flags only


def test_the_codes_map_onto_the_flags():
    codes = (kernel.OK, kernel.ZERO_ACC, kernel.ZERO_MAG, kernel.PARALLEL, kernel.NOT_PD)
    # ZERO_ACC and ZERO_MAG are the screening's (ACC_IGNORED, MAG_IGNORED are set there)
    expected = (0, 0, 0, Flag.MAG_IGNORED, Flag.ACC_IGNORED | Flag.MAG_IGNORED)
    for code, bits in zip(codes, expected, strict=True):
        assert kernel.code_flags(code, False) == bits
        assert kernel.code_flags(code, True) == bits | Flag.MAG_DISTURBED


def test_parameters_are_declared_and_tilt_gate_none_is_off():
    declared = {s.name: s for s in specs(BiasKalmanParams)}
    for name in ("mag_noise_ut_sqrt_hz", "mag_field_ut", "tilt_gate", "gyr_noise_rad_s_sqrt_hz"):
        assert declared[name].help and declared[name].bounds_text() != "any"
    assert declared["tilt_gate"].none_ok and not declared["tilt_gate_exponent"].none_ok
    assert BiasKalmanParams.as_printed().tilt_gate is None
    rec = _moving(5.0)
    off = BiasKalman(tilt_gate=None).run(rec).quat
    never = BiasKalman(tilt_gate=1e300).run(rec).quat  # computed, never fires
    np.testing.assert_array_equal(off, never)


@pytest.mark.parametrize("value", [(1e-3, 2e-3), (1e-3, 2e-3, 3e-3, 4e-3)])
def test_per_axis_densities_need_three_values(value):
    with pytest.raises(ValueError, match="parameter gyr_bias_walk_rad_s_sqrt_s must be one"):
        BiasKalmanParams(gyr_bias_walk_rad_s_sqrt_s=value)
