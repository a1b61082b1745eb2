"""The input policy of the single-frame estimators: screened input, flags, prefilter, units.

The screening zeroes what cannot be used. A zero accelerometer holds the previous
orientation; a field that cannot give a heading (zeroed, or parallel to the
accelerometer) levels the previous orientation onto the measured gravity: inclination
from the accelerometer, heading kept. The low-pass prefilter never filters a zeroed
sample in, restarts after an interval too long for it and after a gap.
"""

from __future__ import annotations

import numpy as np
import pytest

import margtrack as mt
from margtrack import frames
from margtrack import quaternion as quat
from margtrack.estimator import Flag
from margtrack.estimator.lowpass import lowpass
from margtrack.estimator.triad_kernel import level
from margtrack.single_frame.davenport import Davenport
from margtrack.single_frame.fqa import Fqa
from margtrack.single_frame.gauss_newton import GaussNewton, Newton
from margtrack.single_frame.quest import Quest
from margtrack.single_frame.triad import Triad

pytestmark = pytest.mark.kernel

CLASSES = [Triad, Fqa, Quest, Davenport, GaussNewton, Newton]
FILTER = {"acc_lowpass_hz": 4.0, "mag_lowpass_hz": 2.0}


def _after_event_tol(cls):
    """How far an estimate may differ once the same samples follow other earlier ones: the
    fits start from the previous estimate and stop at a criterion of 1e-10 (~1e-5 rad)."""
    return 1e-5 if cls in (GaussNewton, Newton) else 1e-12


@pytest.fixture(scope="module")
def rec():
    return mt.sim.simulate_motion("random", duration_s=12.0, rate_hz=100.0, seed=3)


@pytest.fixture(scope="module")
def rec_ned():
    return mt.sim.simulate_motion("random", duration_s=12.0, rate_hz=100.0, seed=3, frame="NED")


def _inclination(q, r):
    return mt.error_series(q, r.quat_true, r.frame, r.frame).inclination_rad


def _twist_about_up(q_after, q_before, frame):
    """Component along earth up of the rotation taking q_before to q_after (sin of half)."""
    e = quat.multiply(q_after, quat.conjugate(q_before))
    return e[..., 1:] @ frames.up(frame)


# -- the level kernel --------------------------------------------------------------------


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_level_is_the_shortest_arc_putting_the_measured_gravity_up(frame):
    rng = np.random.default_rng(0)
    up = frames.up(frame)
    p = quat.normalize(rng.normal(size=(200, 4)))
    acc = rng.normal(size=(200, 3)) * [1.0, 2.0, 5.0]
    got = np.array([level(*p[i], *acc[i], *up) for i in range(200)])
    arc = quat.shortest_arc(quat.rotate(p, acc), np.broadcast_to(up, acc.shape))
    expected = quat.multiply(arc, p)
    np.testing.assert_allclose(np.abs(np.sum(got * expected, axis=1)), 1.0, atol=1e-13)
    assert np.all(got[:, 0] >= 0.0)
    # the measured gravity now points up, and nothing turned about the vertical
    measured = quat.rotate(got, acc / np.linalg.norm(acc, axis=1)[:, None])
    np.testing.assert_allclose(measured, np.broadcast_to(up, measured.shape), atol=1e-13)
    np.testing.assert_allclose(_twist_about_up(got, p, frame), 0.0, atol=1e-14)


def test_level_turns_an_upside_down_estimate_by_a_half_turn_about_a_horizontal_axis():
    up = frames.up("ENU")
    p = quat.from_euler([0.7, 0.0, 0.0])
    for acc in (-up, quat.rotate_inverse(p, -up), quat.rotate_inverse(p, -up + [1e-9, 0, 0])):
        got = np.array(level(*p, *acc, *up))
        assert np.all(np.isfinite(got))
        np.testing.assert_allclose(quat.rotate(got, acc / np.linalg.norm(acc)), up, atol=1e-8)
        assert abs(_twist_about_up(got, p, "ENU")) < 1e-8
    # a zero accelerometer leaves p as it is
    np.testing.assert_array_equal(level(*p, 0.0, 0.0, 0.0, *up), p)


# -- the policy inside every estimator ------------------------------------------------------


@pytest.mark.parametrize("frame", ["ENU", "NED"])
@pytest.mark.parametrize("cls", CLASSES)
def test_a_stuck_field_keeps_the_inclination_and_the_last_heading(cls, frame, rec, rec_ned):
    r = rec if frame == "ENU" else rec_ned
    mag = r.mag.copy()
    mag[300:] = mag[300]
    est = cls(frame=frame).run(acc=r.acc, mag=mag, t=r.t)
    ignored = (est.flags & Flag.MAG_IGNORED) != 0
    assert ignored[400:].all() and not ignored[:300].any()
    # before this policy every such sample repeated the orientation of sample 350 (frozen)
    assert np.ptp(quat.to_euler(est.quat[400:])[:, 1]) > 0.5
    # on every ignored sample the inclination is TRIAD's (from the accelerometer alone) ...
    triad = Triad(frame=frame).run(acc=r.acc, mag=r.mag, t=r.t)
    np.testing.assert_allclose(_inclination(est.quat, r)[ignored],
                               _inclination(triad.quat, r)[ignored], atol=1e-9)
    # ... and from one ignored sample to the next nothing turns about the vertical
    both = np.flatnonzero(ignored[1:] & ignored[:-1]) + 1
    np.testing.assert_allclose(_twist_about_up(est.quat[both], est.quat[both - 1], frame),
                               0.0, atol=1e-12)
    assert not est.outputs["degenerate"][:300].any()
    assert np.all(est.outputs["degenerate"][ignored] == 2)


@pytest.mark.parametrize("cls", CLASSES)
def test_a_disturbed_field_is_flagged_disturbed_not_relabelled_and_levels(cls, rec):
    mag = rec.mag.copy()
    mag[500:600] *= 1.6  # a norm 60 % off: the screening's gate drops it
    est = cls().run(acc=rec.acc, mag=mag, t=rec.t)
    disturbed = (est.flags & Flag.MAG_DISTURBED) != 0
    assert disturbed[500:600].all() and not disturbed[:500].any() and not disturbed[600:].any()
    assert not (est.flags & Flag.MAG_IGNORED).any()
    triad = Triad().run(acc=rec.acc, mag=rec.mag, t=rec.t)
    np.testing.assert_allclose(_inclination(est.quat, rec)[500:600],
                               _inclination(triad.quat, rec)[500:600], atol=1e-9)
    clean = cls().run(acc=rec.acc, mag=rec.mag, t=rec.t)
    np.testing.assert_allclose(est.quat[600:], clean.quat[600:], atol=_after_event_tol(cls))


@pytest.mark.parametrize("cls", CLASSES)
def test_an_unusable_accelerometer_holds_the_previous_orientation(cls, rec):
    acc = rec.acc.copy()
    acc[200:203] = np.nan
    acc[203:206] *= 20.0  # beyond acc_range_g = 16 g
    est = cls().run(acc=acc, mag=rec.mag, t=rec.t)
    np.testing.assert_array_equal(est.quat[200:206], np.tile(est.quat[199], (6, 1)))
    assert np.all(est.flags[200:206] & Flag.ACC_IGNORED)
    np.testing.assert_array_equal(est.outputs["degenerate"][200:206], 1)
    clean = cls().run(rec)
    np.testing.assert_allclose(est.quat[206:], clean.quat[206:], atol=_after_event_tol(cls))


def test_degenerate_codes_map_onto_the_flags():
    codes = np.array([[0, 1, 2, 3, 4]], dtype=np.int8)
    for cls in CLASSES:
        flags = cls()._method_flags({"degenerate": codes})
        # code 2 (zeroed field) keeps the screening's own reason; 3 and 4 give no heading
        np.testing.assert_array_equal(
            flags, [[0, Flag.ACC_IGNORED, 0, Flag.MAG_IGNORED, Flag.MAG_IGNORED]])


# -- units (SPEC point 6) --------------------------------------------------------------------


@pytest.mark.parametrize("kwargs", [{}, FILTER])
@pytest.mark.parametrize("cls", CLASSES)
def test_the_field_unit_changes_nothing(cls, kwargs, rec):
    mag = rec.mag.copy()
    mag[300:400] *= 1.6  # disturbed
    mag[800:] = mag[800]  # stuck
    micro = cls(**kwargs).run(acc=rec.acc, mag=mag, t=rec.t)
    assert (micro.flags & Flag.MAG_DISTURBED).any() and (micro.flags & Flag.MAG_IGNORED).any()
    for factor in (1000.0, 0.01):  # nT, gauss
        other = cls(**kwargs).run(acc=rec.acc, mag=mag * factor, t=rec.t)
        np.testing.assert_allclose(other.quat, micro.quat, atol=1e-9)
        np.testing.assert_array_equal(other.flags, micro.flags)


# -- the prefilter on screened input ---------------------------------------------------------


def _filter(x, dt, cutoff, order=2):
    out = np.empty_like(x)
    lowpass(x, dt, cutoff, order, np.zeros((x.shape[0], 4, 3)), np.zeros(x.shape[0], bool), out)
    return out


def test_a_zeroed_sample_passes_through_and_the_filter_holds_its_input():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(1, 200, 3)) + [20.0, -5.0, 40.0]
    dt = np.r_[0.0, np.full(199, 0.01)]
    gaps = [50, 51, 52, 120]
    x[0, gaps] = 0.0
    out = _filter(x, dt, 5.0)
    held = x.copy()
    for i in gaps:
        held[0, i] = held[0, i - 1]
    expected = _filter(held, dt, 5.0)
    expected[0, gaps] = 0.0
    np.testing.assert_allclose(out, expected, atol=1e-12)
    # filtering the zeros in would have pulled the output far towards 0
    assert np.min(np.linalg.norm(out[0, 53:60], axis=1)) > 40.0


def test_an_interval_too_long_for_the_cutoff_restarts_the_filter():
    rng = np.random.default_rng(5)
    x = rng.normal(size=(1, 100, 3)) + [1.0, 2.0, 9.0]
    dt = np.r_[0.0, np.full(99, 0.01)]
    dt[40] = 0.2  # dropped samples: 5 Hz x 0.2 s >= 1/2
    out = _filter(x, dt, 5.0)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out[0, 40:], _filter(x[:, 40:], dt[40:], 5.0)[0], atol=1e-15)


@pytest.mark.parametrize("cls", CLASSES)
def test_dropped_samples_below_the_gap_threshold_do_not_refuse_the_cutoff(cls, rec):
    keep = np.ones(rec.t.shape[0], bool)
    keep[300:320] = False  # 0.21 s between samples 299 and 320: no gap (max_gap_s 0.25)
    t, acc, mag = rec.t[keep], rec.acc[keep], rec.mag[keep]
    est = cls(acc_lowpass_hz=5.0).run(acc=acc, mag=mag, t=t)  # the old dt.max() check raised
    assert np.all(np.isfinite(est.quat)) and not (est.flags & Flag.GAP).any()
    # the accelerometer filter restarted at the sample after the dropout
    raw = cls().run(acc=acc, mag=mag, t=t)
    assert quat.angle_between(est.quat[300], raw.quat[300]) < _after_event_tol(cls)
    assert quat.angle_between(est.quat[305], raw.quat[305]) > 1e-6


def test_a_cutoff_above_the_update_rate_is_refused_too():
    with pytest.raises(ValueError, match=r"acc_lowpass_hz = 60.0 Hz is not below half.*rate_hz"):
        Fqa(acc_lowpass_hz=60.0, rate_hz=100.0).update(None, [0.0, 0.0, 9.8], [0.0, 20.0, -40.0])


@pytest.mark.parametrize("cls", CLASSES)
def test_a_restart_after_a_gap_starts_the_filters_afresh_and_keeps_the_dip(cls, rec):
    keep = np.ones(rec.t.shape[0], bool)
    keep[400:500] = False  # 1 s gap
    t, acc, mag = rec.t[keep], rec.acc[keep], rec.mag[keep]
    kwargs = FILTER | {"mag_dip_ref_deg": 60.0}
    est = cls(**kwargs).run(acc=acc, mag=mag, t=t)
    assert est.flags[400] & Flag.GAP
    fresh = cls(**kwargs).run(acc=acc[400:], mag=mag[400:], t=t[400:])
    np.testing.assert_allclose(est.quat[400:], fresh.quat, atol=1e-12)
    # a measured dip is a property of the place: the restart keeps it
    if cls not in (Triad, Fqa):
        measuring = cls()
        measuring.run(acc=acc, mag=mag, t=t)
        first = cls()
        first.run(acc=acc[:5], mag=mag[:5], t=t[:5])
        assert measuring.state.dip_rad[0] == first.state.dip_rad[0]


@pytest.mark.parametrize("cls", CLASSES)
def test_a_skipped_timestamp_is_a_no_op_with_the_filter_on(cls, rec):
    n = 300
    t = rec.t[:n].copy()
    t[150] = t[149]  # repeated: skipped (CLOCK), dt = 0, acc and mag zeroed
    est = cls(**FILTER).run(acc=rec.acc[:n], mag=rec.mag[:n], t=t)
    assert est.flags[150] & Flag.CLOCK
    np.testing.assert_array_equal(est.quat[150], est.quat[149])
    keep = np.arange(n) != 150
    without = cls(**FILTER).run(acc=rec.acc[:n][keep], mag=rec.mag[:n][keep], t=t[keep])
    np.testing.assert_allclose(est.quat[keep], without.quat, atol=1e-12)


@pytest.mark.parametrize("cls", CLASSES)
def test_update_equals_run_through_bad_samples_with_the_filter_on(cls, rec):
    n = 400
    keep = np.ones(n, bool)
    keep[200:215] = False  # a dropout of 0.16 s: restarts the 4 Hz filter
    t, acc, mag = rec.t[:n][keep], rec.acc[:n].copy()[keep], rec.mag[:n].copy()[keep]
    acc[50] = np.nan
    mag[80:83] = np.inf
    mag[250:] = mag[250]
    mag[120:150] *= 1.6
    batch = cls(**FILTER).run(acc=acc, mag=mag, t=t)
    live = cls(**FILTER)
    dts = np.r_[0.0, np.diff(t)]
    stepped = np.array([live.update(None, acc[i], mag[i], dt=dts[i]) for i in range(len(t))])
    np.testing.assert_allclose(stepped, batch.quat, atol=1e-12)
    assert np.all(np.isfinite(batch.quat))
