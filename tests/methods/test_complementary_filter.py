"""Bachmann filter behaviour: contract (update/run/state), schedule, modes, frames, errors."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import frames, sim
from margtrack import quaternion as quat
from margtrack.accuracy import error_series
from margtrack.estimator import Flag
from margtrack.methods.bachmann import Bachmann, BachmannAccMag, BachmannParams

pytestmark = pytest.mark.kernel

Q_TRUE = quat.from_euler([0.5, 0.2, -0.3])


def _signals(n_sensors=3, n=240, seed=4):
    rng = np.random.default_rng(seed)
    gyr = rng.normal(scale=0.8, size=(n_sensors, n, 3))
    acc = rng.normal(scale=1.0, size=(n_sensors, n, 3)) + [0.0, 0.0, 9.81]
    mag = rng.normal(scale=2.0, size=(n_sensors, n, 3)) + [0.0, 25.0, -43.0]
    return gyr, acc, mag


def _all_outputs(est):
    return [est.quat, *(est.outputs[k] for k in sorted(est.outputs))]


def test_update_n_times_equals_one_run_for_many_sensors_and_round_robin():
    gyr, acc, mag = _signals()
    params = BachmannParams(gain=2.0, mag_weight=0.5, correction_interval=3, round_robin=True)
    batch = Bachmann(params).run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    live = Bachmann(params, rate_hz=100.0)
    stepped = np.stack([live.update(gyr[:, i], acc[:, i], mag[:, i]) for i in range(acc.shape[1])])
    np.testing.assert_allclose(stepped.transpose(1, 0, 2), batch.quat, atol=1e-12)


def test_two_half_runs_joined_through_state_equal_one_run_with_every_output():
    gyr, acc, mag = _signals()
    t = 2.0 + 0.01 * np.arange(acc.shape[1])
    params = BachmannParams(gain=3.0, correction_interval=4, round_robin=True)
    whole = Bachmann(params).run(gyr=gyr, acc=acc, mag=mag, t=t)
    first = Bachmann(params)
    cut = 101  # not a multiple of the interval: the schedule must carry over
    a = first.run(gyr=gyr[:, :cut], acc=acc[:, :cut], mag=mag[:, :cut], t=t[:cut])
    second = Bachmann(params)
    second.state = first.state
    b = second.run(gyr=gyr[:, cut:], acc=acc[:, cut:], mag=mag[:, cut:], t=t[cut:])
    for x, y, z in zip(_all_outputs(a), _all_outputs(b), _all_outputs(whole), strict=True):
        np.testing.assert_allclose(np.concatenate([x, y], axis=1), z, atol=1e-12)


def test_many_sensors_in_one_run_equal_each_sensor_alone():
    gyr, acc, mag = _signals(n_sensors=4)
    together = Bachmann(gain=2.0).run(gyr=gyr, acc=acc, mag=mag, rate_hz=50.0)
    for s in range(4):
        alone = Bachmann(gain=2.0).run(gyr=gyr[s], acc=acc[s], mag=mag[s], rate_hz=50.0)
        np.testing.assert_allclose(together.quat[s], alone.quat, atol=1e-15)


def test_round_robin_gives_exactly_one_new_correction_per_cycle_and_holds_it():
    n_sensors = 4
    gyr, acc, mag = _signals(n_sensors=n_sensors, n=40)
    params = BachmannParams(gain=2.0, correction_interval=n_sensors, round_robin=True)
    out = Bachmann(params).run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0).outputs
    new = out["new_correction"]
    cycles = np.arange(new.shape[1])
    for s in range(n_sensors):
        np.testing.assert_array_equal(new[s], (cycles - s) % n_sensors == 0)
    np.testing.assert_array_equal(new.sum(axis=0), 1)
    corr, phi = out["correction_rad_s"], out["phi"]
    for s in range(n_sensors):
        # before its first turn a filter has no correction; afterwards it reuses the latest
        np.testing.assert_array_equal(corr[s, :s], 0.0)
        assert np.all(np.isnan(phi[s, :s]))
        for i in range(s, new.shape[1]):
            last = s + (i - s) // n_sensors * n_sensors
            np.testing.assert_array_equal(corr[s, i], corr[s, last])
            assert phi[s, i] == phi[s, last]
    together = Bachmann(correction_interval=n_sensors).run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    np.testing.assert_array_equal(together.outputs["new_correction"].sum(axis=0)[::4], n_sensors)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_tracks_the_simulated_truth_in_both_frames_without_conjugation(frame):
    rate_hz = 200.0
    motion = sim.random_motion(20.0, rate_hz, seed=3, max_rate_deg_s=200.0)
    noise = sim.SensorErrors(noise_density=np.radians(0.005))
    rec = sim.simulate(motion, frame=frame, gyr_errors=noise, seed=1)
    est = Bachmann(gain=1.0, mag_dip_ref_deg=sim.DEFAULT_DIP_DEG, frame=frame).run(rec)
    assert est.frame == frame
    error_deg = np.degrees(quat.angle_between(est.quat, rec.quat_true))
    # exact acc/mag, a white-noise gyro: what is left is the lag of Fig. 5's order (q̂ of
    # sample i-1 corrected towards the measurement of sample i), at most ω·dt
    max_rate_deg_s = np.degrees(np.linalg.norm(rec.gyr, axis=1)).max()
    assert 0.1 < error_deg.max() < max_rate_deg_s / rate_hz
    other = "NED" if frame == "ENU" else "ENU"
    wrong = quat.angle_between(est.quat, frames.convert(rec.quat_true, frame, other))
    assert np.degrees(wrong).min() > 90


@pytest.mark.parametrize("gain", [2.0, 8.0])
def test_squared_error_falls_to_37_percent_at_one_over_2k(gain):
    rec = sim.simulate(sim.static(1.0, 1000.0, q0=Q_TRUE), dip_deg=60.0)
    est = Bachmann(gain=gain, mag_weight=1.0, mag_dip_ref_deg=60.0)  # ρ < 1 slows heading
    est.reset(quat.multiply(Q_TRUE, quat.from_axis_angle([1, 1, 1], np.radians(30.0))))
    out = est.run(rec)
    squared = quat.angle_between(out.quat, rec.quat_true) ** 2
    t37 = rec.t[np.argmax(squared < np.exp(-1) * squared[0])]
    # linear theory (000, eq. 12); a 30 deg start is slightly slower (sin, not angle): < 5 %
    assert t37 * 2 * gain == pytest.approx(1.0, rel=0.05)


def test_without_magnetometer_tilt_converges_and_heading_is_left_alone():
    rec = sim.simulate(sim.static(3.0, 200.0, q0=Q_TRUE), with_mag=False)
    est = Bachmann(gain=4.0)
    tilt, heading = quat.from_rotvec([0.2, -0.1, 0.0]), quat.from_rotvec([0.0, 0.0, 0.3])
    est.reset(quat.multiply(heading, quat.multiply(tilt, Q_TRUE)))  # earth-frame errors
    out = est.run(rec)
    errors = error_series(out.quat, rec.quat_true)
    assert np.degrees(errors.inclination_rad[-1]) < 1e-3  # exp(-12) of ~13 deg
    # the minimum-norm step turns about horizontal axes only: the 0.3 rad heading error
    # stays, up to the second-order coupling of the 0.22 rad tilt (< 0.22² / 2 rad)
    assert abs(errors.heading_rad[-1] - 0.3) < 0.22**2 / 2


def test_acc_mag_only_needs_no_gyro_and_follows_the_measurements():
    rec = sim.simulate(sim.static(2.0, 200.0, q0=Q_TRUE), dip_deg=60.0)
    est = BachmannAccMag(gain=5.0, mag_weight=1.0, mag_dip_ref_deg=60.0)
    est.reset(quat.identity())
    out = est.run(acc=rec.acc, mag=rec.mag, t=rec.t)  # no gyr at all
    assert np.degrees(quat.angle_between(out.quat[-1], Q_TRUE)) < 1e-2
    with pytest.raises(ValueError, match="needs a magnetometer"):
        BachmannAccMag(gain=5.0).run(acc=rec.acc, t=rec.t)
    with pytest.raises(ValueError, match="needs gyroscope data"):
        Bachmann().run(acc=rec.acc, mag=rec.mag, t=rec.t)


def test_degenerate_samples_are_flagged_not_turned_into_nan():
    gyr, acc, mag = (x[0] for x in _signals(1, 30))
    acc[10] = 0.0
    mag[20] = 0.0
    gate_open = {"mag_norm_tol": 1e9, "mag_dip_tol_deg": 360.0}  # noisy field: no other zeros
    out = Bachmann(gain=2.0, **gate_open).run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    flags = out.outputs["degenerate"]
    assert flags[10] == 1 and flags[20] == 2 and np.count_nonzero(flags) == 2
    assert out.flags[10] & Flag.ACC_IGNORED and out.flags[20] & Flag.MAG_IGNORED
    assert np.all(np.isfinite(out.quat))
    np.testing.assert_array_equal(out.outputs["correction_rad_s"][10], 0.0)
    assert np.isnan(out.outputs["phi"][10])
    # a zero magnetometer leaves a gravity-only step: no rotation about the measured up
    up_earth = quat.rotate(out.quat[19], acc[20] / np.linalg.norm(acc[20]))
    assert abs(out.outputs["correction_rad_s"][20] @ up_earth) < 1e-9


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"gain": -1.0}, r"parameter gain must be a finite number, >= 0 1/s"),
        ({"gain": float("nan")}, "parameter gain must be a finite number"),
        ({"mag_weight": -0.1}, "parameter mag_weight must be a finite number, >= 0"),
        ({"correction_interval": 0}, "parameter correction_interval must be .* >= 1"),
        ({"correction_interval": 2.5}, "parameter correction_interval must be a whole number"),
        ({"round_robin": "yes"}, "parameter round_robin must be"),
        ({"restart_gain": -1.0}, "parameter restart_gain must be a finite number, >= 0"),
        ({"mag_dip_ref_deg": 88.0}, "at least 5.0 deg away .* mag_dip_ref_deg"),
        ({"mag_reference": (0, 0.01, 1)}, "at least 5.0 deg away"),
        ({"gravity_reference": (0, 0, 0)}, "gravity_reference must be a finite, non-zero"),
        ({"mag_reference": (1.0, 2.0)}, "mag_reference must be a finite, non-zero 3-vector"),
        ({"frame": "NWU"}, "frame must be 'NED' or 'ENU'"),
    ],
)
def test_bad_parameters_are_refused_with_the_allowed_range(values, message):
    with pytest.raises(ValueError, match=message):
        BachmannParams(**values)
    with pytest.raises(ValueError, match=message):
        Bachmann().set_params(**values)


def test_the_dip_is_measured_at_the_first_usable_sample_and_never_refuses_a_sensor():
    rec = sim.simulate(sim.static(0.5, 100.0, q0=Q_TRUE), dip_deg=63.0)
    est = Bachmann()
    est.run(rec)
    assert np.degrees(est.state.get("dip_rad")[0, 0]) == pytest.approx(63.0, abs=1e-9)
    # a zero (screened) field at the start: the dip comes from the first usable sample
    mag = rec.mag.copy()
    mag[:7] = 0.0
    est = Bachmann()
    est.reset(Q_TRUE)
    out = est.run(gyr=rec.gyr, acc=rec.acc, mag=mag, t=rec.t)
    assert np.degrees(est.state.get("dip_rad")[0, 0]) == pytest.approx(63.0, abs=1e-9)
    assert np.all(out.outputs["degenerate"][:7] == 2) and not out.outputs["degenerate"][7:].any()
    assert np.max(quat.angle_between(out.quat, Q_TRUE)) < 1e-9
    # a field within 5 deg of vertical is taken at the limit, not refused
    steep = sim.simulate(sim.static(0.2, 100.0, q0=Q_TRUE), dip_deg=88.0)
    est = Bachmann()
    assert np.all(np.isfinite(est.run(steep).quat))
    assert np.degrees(est.state.get("dip_rad")[0, 0]) == pytest.approx(85.0, abs=1e-9)


def test_the_base_reference_dip_is_the_field_reference_and_mag_reference_wins():
    gyr, acc, mag = (x[0] for x in _signals(1, 60))
    gate_open = {"mag_norm_tol": 1e9, "mag_dip_tol_deg": 360.0}
    a = Bachmann(mag_dip_ref_deg=40.0, **gate_open).run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    b = Bachmann(mag_dip_ref_deg=70.0, **gate_open).run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    assert quat.angle_between(a.quat[-1], b.quat[-1]) > 1e-3  # the dip is used
    given = tuple(frames.mag_reference("ENU", 40.0))
    c = Bachmann(mag_dip_ref_deg=70.0, mag_reference=given, **gate_open).run(
        gyr=gyr, acc=acc, mag=mag, rate_hz=100.0
    )
    np.testing.assert_allclose(c.quat, a.quat, atol=1e-15)


def test_explicit_reference_vectors_equal_the_frame_and_dip_ones_and_state_copies_are_deep():
    gyr, acc, mag = (x[0] for x in _signals(1, 60))
    gate_open = {"mag_norm_tol": 1e9, "mag_dip_tol_deg": 360.0}  # the same screening
    by_dip = Bachmann(mag_dip_ref_deg=55.0, frame="NED", **gate_open)
    given = Bachmann(
        gravity_reference=(0.0, 0.0, -9.81),  # a level accelerometer reads up: -z in NED
        mag_reference=tuple(frames.mag_reference("NED", 55.0, 48.0)),
        frame="NED",
        **gate_open,
    )
    a = by_dip.run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    b = given.run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    np.testing.assert_allclose(a.quat, b.quat, atol=1e-15)
    tilted = Bachmann(
        mag_dip_ref_deg=55.0, frame="NED", gravity_reference=(0.1, 0.0, -1.0), **gate_open
    )
    c = tilted.run(gyr=gyr, acc=acc, mag=mag, rate_hz=100.0)
    assert quat.angle_between(a.quat[-1], c.quat[-1]) > 1e-3  # the reference is used
    saved = by_dip.state
    saved.rows[:] = 1.0
    assert np.all(by_dip.state.get("quat")[0] == a.quat[-1])
    assert not np.any(by_dip.state.get("correction_step") == 1.0)


def test_the_start_honours_explicit_reference_vectors():
    # an earth frame whose references are turned by r: the same static sensor then sits at
    # r ⊗ q in it, from the very first sample
    r = quat.from_euler([0.4, 0.1, -0.2])
    rec = sim.simulate(sim.static(0.2, 100.0, q0=Q_TRUE), dip_deg=60.0)
    refs = {
        "gravity_reference": tuple(quat.rotate(r, frames.up("ENU"))),
        "mag_reference": tuple(quat.rotate(r, frames.mag_reference("ENU", 60.0))),
    }
    expected = quat.multiply(r, Q_TRUE)
    out = Bachmann(**refs).run(rec)
    assert quat.angle_between(out.quat[0], expected) < 1e-9
    assert quat.angle_between(out.quat[-1], expected) < 1e-9
    # without a magnetometer only the tilt is defined: the reference up must be seen as
    # the accelerometer's direction
    tilt_only = Bachmann(gravity_reference=refs["gravity_reference"]).run(rec.without_mag())
    up_ref = np.asarray(refs["gravity_reference"])
    seen = quat.rotate(tilt_only.quat[0], rec.acc[0] / np.linalg.norm(rec.acc[0]))
    np.testing.assert_allclose(seen, up_ref, atol=1e-12)
