"""The robust filter's online hard-iron estimate (``methods/robust/hard_iron.py``).

A magnet carried by the sensor is a constant body-frame offset: simulated attached dipoles
(``sim.attached_dipole``) under random motion, a clean field, a rotation about one axis
and a clipping magnetometer, each against what the fit must (not) accept.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.accuracy import error_series
from margtrack.estimator import compiled
from margtrack.estimator.flags import Flag
from margtrack.methods.robust import Robust, RobustParams, hard_iron, kernel

RATE_HZ = 100.0
#: a magnetometer with white noise only (0.5 µT rms at 100 Hz): its offset is the magnet's
CLEAN_MAG = sim.SensorErrors(noise_density=0.05)


def _recording(distance_cm, seed=0, duration_s=40.0, mag_errors=CLEAN_MAG, trajectory=None):
    motion = trajectory or sim.random_motion(
        duration_s, RATE_HZ, seed, max_rate_deg_s=200.0, bandwidth_hz=2.0, translation_m=0.02
    )
    magnet = [] if distance_cm is None else [sim.attached_dipole(distance_cm / 100, 0.1)]
    return sim.simulate(motion, frame="ENU", mag_errors=mag_errors, mag_disturbances=magnet,
                        seed=seed, name=f"magnet-{distance_cm}")


def _heading_rmse_deg(est, rec, after_s=0.0):
    err = error_series(est.quat, rec.quat_true, est.frame, rec.frame).heading_rad
    keep = rec.t >= rec.t[0] + after_s
    return math.degrees(float(np.sqrt(np.mean(err[keep] ** 2))))


# -- the fit's arithmetic --------------------------------------------------------------------
def test_eigenvalues_are_numpys():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a = rng.normal(size=(3, 3))
        c = a @ a.T
        got = hard_iron.eigenvalues(c[0, 0], c[0, 1], c[0, 2], c[1, 1], c[1, 2], c[2, 2])
        np.testing.assert_allclose(got, np.linalg.eigvalsh(c), rtol=1e-9, atol=1e-12)
    # a multiple of the identity (the closed form's p = 0 branch)
    assert hard_iron.eigenvalues(2.0, 0.0, 0.0, 2.0, 0.0, 2.0) == (2.0, 2.0, 2.0)


def _fit_rows(samples, coef, dt=0.01):
    """A fresh row with these field samples in its sums, then one solve."""
    row = np.zeros(kernel.N_ROW)
    kernel._sensor_at(row, 0, 1, coef)
    for m in samples:
        hard_iron.accumulate_at(row, 0, 1, coef, dt, m[0], m[1], m[2], True, False)
    moved = hard_iron.solve_at(row, 0, 1, coef)
    return row, moved


def test_points_on_a_sphere_give_its_centre_and_radius():
    # directions spread over the whole sphere: the algebraic fit is exact on exact data
    rng = np.random.default_rng(0)
    u = rng.normal(size=(2000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    centre, radius = np.array([120.0, -35.0, 60.0]), 48.0
    coef = RobustParams().coefficients()
    row, moved = _fit_rows(centre + radius * u, coef)
    assert moved  # from none to this offset
    np.testing.assert_allclose(row[kernel.R_HI_OFFSET : kernel.R_HI_OFFSET + 3], centre,
                               atol=1e-6)
    assert row[kernel.R_HI_RADIUS] == pytest.approx(radius, abs=1e-6)
    assert row[kernel.R_HI_MOVING] == 0.0


def test_a_circle_is_never_accepted_but_its_moving_norm_rejects_the_field():
    # rotation about one axis: the field directions on a circle, which lies on a whole
    # family of spheres; the norm moves with the angle (the offset is off the axis)
    angle = np.linspace(0.0, 4.0 * np.pi, 4000)
    earth = np.stack([30.0 * np.cos(angle), 30.0 * np.sin(angle), np.full_like(angle, 40.0)], 1)
    coef = RobustParams().coefficients()
    row, moved = _fit_rows(earth + np.array([40.0, 0.0, 10.0]), coef)
    assert not moved and row[kernel.R_HI_RADIUS] == 0.0
    assert row[kernel.R_HI_MOVING] == 1.0
    # the same circle without the offset: the norm is steady, nothing is rejected
    row, _ = _fit_rows(earth, coef)
    assert row[kernel.R_HI_RADIUS] == 0.0 and row[kernel.R_HI_MOVING] == 0.0


def test_a_norm_changing_without_rotation_is_no_magnet_moving_with_the_sensor():
    # a fixed direction, the norm stepping between two values (a room disturbance)
    m = np.tile([20.0, 0.0, -45.0], (3000, 1))
    m[1500:] *= 1.3
    coef = RobustParams().coefficients()
    row, _ = _fit_rows(m, coef)
    assert row[kernel.R_HI_RADIUS] == 0.0 and row[kernel.R_HI_MOVING] == 0.0


# -- simulated magnets -----------------------------------------------------------------------
@pytest.mark.parametrize("distance_cm", [4.0, 10.0])
def test_an_attached_dipole_is_recovered_and_the_heading_follows(distance_cm):
    rec = _recording(distance_cm)
    true = sim.attached_dipole(distance_cm / 100, 0.1).offset_ut
    est = Robust(frame="ENU").run(rec)
    offset = est.outputs["mag_offset_ut"]
    accepted = np.isfinite(offset).all(axis=1)
    # accepted within the first 10 s of motion, then within 2 µT of the magnet's field
    assert accepted[int(10 * RATE_HZ) :].all()
    assert np.abs(offset[accepted] - true).max() < 2.0
    # the heading after acceptance is good; without the estimate it is not
    off = Robust(frame="ENU", hard_iron_tau_s=0.0).run(rec)
    assert _heading_rmse_deg(est, rec, after_s=15.0) < 0.5
    assert _heading_rmse_deg(off, rec, after_s=15.0) > 3.0


def test_a_clean_field_never_takes_an_offset():
    # the consumer MEMS preset: 1.3 µT residual bias, 1 % scale errors, misalignment
    for seed in range(3):
        rec = _recording(None, seed, mag_errors=sim.SensorErrors.mems_mag())
        est = Robust(frame="ENU").run(rec)
        offset = est.outputs["mag_offset_ut"]
        accepted = np.isfinite(offset).all(axis=1)
        assert accepted.any()  # the fit was accepted ...
        np.testing.assert_array_equal(offset[accepted], 0.0)  # ... as no magnet
        # and so the filter is the one without the estimate, bit for bit
        off = Robust(frame="ENU", hard_iron_tau_s=0.0).run(rec)
        np.testing.assert_array_equal(est.quat, off.quat)


def test_rotation_about_one_axis_never_accepts_and_holds_the_heading():
    # a tilt table turning about the vertical with a magnet on the body x axis
    q0 = quat.from_rotvec(np.radians([10.0, 0.0, 0.0]))
    traj = sim.constant_rotation((0.0, 0.0, 1.0), 30.0, 40.0, RATE_HZ, q0=q0)
    rec = _recording(10.0, trajectory=traj)
    est = Robust(frame="ENU").run(rec)
    assert np.isnan(est.outputs["mag_offset_ut"]).all()
    # the field, whose norm moves with the turn, is rejected after the first solves
    disturbed = (est.flags & Flag.MAG_DISTURBED) != 0
    assert disturbed[int(10 * RATE_HZ) :].mean() > 0.95


def test_clipped_samples_never_enter_the_fit():
    # 1 cm: 20 mT on the x axis, beyond a ±4900 µT magnetometer: that axis sits at its
    # clip level, which the screening learns and ignores
    mag_errors = sim.SensorErrors(noise_density=0.05, saturation=4900.0)
    rec = _recording(1.0, mag_errors=mag_errors)
    f = Robust(frame="ENU")
    est = f.run(rec)
    assert ((est.flags & Flag.MAG_IGNORED) != 0).mean() > 0.95
    assert np.isnan(est.outputs["mag_offset_ut"]).all()
    # the sums hold only the few samples before the clip level was learned
    weight = f.state.get("hard_iron_sums")[0, 0]
    assert weight < 0.01


def test_the_magnet_appearing_later_is_found_and_its_removal_drops_it():
    motion = sim.random_motion(120.0, RATE_HZ, 1, max_rate_deg_s=200.0, bandwidth_hz=2.0)
    clean = sim.simulate(motion, frame="ENU", mag_errors=CLEAN_MAG, seed=1)
    true = sim.attached_dipole(0.05, 0.1).offset_ut  # 5 cm: 160 µT
    mag = clean.mag.copy()
    on = (clean.t >= 20.0) & (clean.t < 70.0)
    mag[on] += true
    est = Robust(frame="ENU").run(gyr=clean.gyr, acc=clean.acc, mag=mag, t=clean.t)
    offset = est.outputs["mag_offset_ut"]
    found = (clean.t > 50.0) & (clean.t < 70.0)
    assert np.abs(offset[found] - true).max() < 2.0
    gone = clean.t > 110.0
    np.testing.assert_array_equal(offset[gone], 0.0)


# -- lockstep ------------------------------------------------------------------------------
def test_lockstep_equals_sensor_by_sensor_with_magnets(monkeypatch):
    n = compiled.LANES_MIN_SENSORS + 3
    recs = [_recording([None, 3.0, 5.0, 10.0][s % 4], seed=s, duration_s=20.0)
            for s in range(n)]
    gyr, acc, mag = (np.stack([getattr(r, k) for r in recs]) for k in ("gyr", "acc", "mag"))
    mag[1, :250] = np.nan  # a sensor that starts late: its solves at other samples
    t = recs[0].t.copy()
    t[1200:] += 1.0  # a gap: every sensor restarts, keeping its fit
    together = Robust(frame="ENU").run(gyr=gyr, acc=acc, mag=mag, t=t)
    offset = together.outputs["mag_offset_ut"]
    assert np.isfinite(offset[3, -1]).all() and np.abs(offset[3, -1]).max() > 10.0
    monkeypatch.setattr(compiled, "LANES_MIN_SENSORS", 10**9)
    one_by_one = Robust(frame="ENU").run(gyr=gyr, acc=acc, mag=mag, t=t)
    np.testing.assert_array_equal(one_by_one.quat, together.quat)
    np.testing.assert_array_equal(one_by_one.flags, together.flags)
    for key, value in one_by_one.outputs.items():
        np.testing.assert_array_equal(together.outputs[key], value, err_msg=key)


def test_a_sample_without_a_usable_field_only_ages_the_sums():
    # a zero field (the screening's "no measurement": stuck, clipped, non-finite) through
    # the whole filter: the sums decay by one interval's forgetting and take nothing in
    rec = _recording(10.0, duration_s=12.0)
    f = Robust(frame="ENU")
    f.run(rec)
    before = f.state.get("hard_iron_sums")[0].copy()
    assert before[0] > hard_iron.MIN_WEIGHT
    dt = 1.0 / RATE_HZ
    f.update(rec.gyr[-1], rec.acc[-1], np.zeros(3), dt=dt)
    assert f.flags[0] & Flag.MAG_IGNORED
    decay = 1.0 - dt / RobustParams().hard_iron_tau_s
    np.testing.assert_allclose(f.state.get("hard_iron_sums")[0], decay * before, rtol=1e-15)
    f.update(rec.gyr[-1], rec.acc[-1], np.full(3, np.nan), dt=dt)
    np.testing.assert_allclose(f.state.get("hard_iron_sums")[0], decay**2 * before, rtol=1e-14)


# -- a restart after a gap (estimator/restart_kernel.py) sees the field as robust does -----
def _cut(rec, t0_s, t1_s):
    """``rec`` without its samples in [t0_s, t1_s): a gap robust restarts after."""
    from dataclasses import replace

    keep = (rec.t < t0_s) | (rec.t >= t1_s)
    return replace(rec, t=rec.t[keep], gyr=rec.gyr[keep], acc=rec.acc[keep],
                   mag=rec.mag[keep], quat_true=rec.quat_true[keep],
                   movement=None if rec.movement is None else rec.movement[keep])


def _restart_sample(est):
    i_gap = int(np.flatnonzero(est.flags & Flag.GAP)[0])
    return i_gap, i_gap + int(np.argmin((est.flags[i_gap:] & Flag.INITIALISING) != 0))


def test_a_restart_takes_the_accepted_offset_off_the_windows_field():
    """A magnet carried at 4 cm (313 µT, six earth fields), its offset accepted before a
    2 s gap in random motion: the restart's window measures the heading from the field less
    the offset (the raw field's heading, one sample's TRIAD, is tens of degrees off; a
    carried one is off by the gap's turn)."""
    rec = _recording(4.0, seed=2, duration_s=40.0)
    cut = _cut(rec, 30.0, 32.0)
    est = Robust(frame="ENU").run(cut)
    i_gap, i_start = _restart_sample(est)
    true = sim.attached_dipole(0.04, 0.1).offset_ut
    np.testing.assert_allclose(est.outputs["mag_offset_ut"][i_gap - 1], true, atol=0.05 * 313)
    err = error_series(est.quat, cut.quat_true, est.frame, cut.frame)
    assert math.degrees(err.heading_rad[i_start]) < 5.0
    assert not est.flags[i_start] & Flag.HEADING_CARRIED
    # the oracles: the raw field's heading and the heading carried across the gap
    from margtrack.estimator.initial import initial_orientation

    raw = initial_orientation(cut.acc[i_gap:i_gap + 1], cut.mag[i_gap:i_gap + 1], "ENU")
    raw_err = error_series(raw, cut.quat_true[i_gap:i_gap + 1], "ENU", cut.frame)
    assert math.degrees(raw_err.heading_rad[0]) > 20.0
    turned = error_series(cut.quat_true[i_gap - 1:i_gap], cut.quat_true[i_start:i_start + 1],
                          "ENU", cut.frame)
    assert math.degrees(turned.heading_rad[0]) > 20.0


def test_a_restart_while_a_carried_magnet_is_rejected_carries_the_heading():
    """A turn about the vertical with a magnet on the body: no fit is accepted (a circle)
    and the field, whose norm moves with the turn, is rejected; after a gap the window
    takes no heading from that field: carried, flagged HEADING_CARRIED."""
    q0 = quat.from_rotvec(np.radians([10.0, 0.0, 0.0]))
    traj = sim.constant_rotation((0.0, 0.0, 1.0), 30.0, 40.0, RATE_HZ, q0=q0)
    cut = _cut(_recording(10.0, trajectory=traj), 25.0, 27.0)
    est = Robust(frame="ENU").run(cut)
    i_gap, i_start = _restart_sample(est)
    assert est.flags[i_gap - 1] & Flag.MAG_DISTURBED
    assert est.flags[i_start] & Flag.HEADING_CARRIED
