"""The input screening kernel, sample by sample, against hand-worked cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from margtrack.estimator import screening
from margtrack.estimator.flags import Flag
from margtrack.estimator.params import Params

pytestmark = pytest.mark.kernel

G = np.array([0.0, 0.0, 9.81])
FIELD = np.array([0.0, 20.0, -40.0])


def _run(t, gyr, acc, mag=None, params=None, check_disturbance=True, state=None, t_last=math.nan):
    params = params or Params()
    coef = screening.coefficients(params, check_disturbance)
    state = state or screening.ScreenState.new(1)
    arr = lambda x: None if x is None else np.asarray(x, dtype=float)[None]  # noqa: E731
    return screening.screen(state, t_last, coef, np.asarray(t, float), arr(gyr), arr(acc), arr(mag))


def test_time_rules_gap_reset_repeat_nan():
    t = [0.0, 0.01, 0.02, 0.02, 0.015, 1.0, 1.01, np.nan, 1.02, 0.1, 0.11]
    n = len(t)
    out = _run(t, np.zeros((n, 3)), np.tile(G, (n, 1)))
    np.testing.assert_allclose(out.dt, [0, 0.01, 0.01, 0, 0, 0, 0.01, 0, 0.01, 0, 0.01], atol=1e-15)
    f = out.flags[0]
    assert f[3] == Flag.CLOCK and f[4] == Flag.CLOCK  # repeated, slightly back: skipped
    assert f[5] == Flag.GAP  # 0.98 s forward
    assert f[7] == Flag.CLOCK  # NaN time
    assert f[9] == Flag.GAP | Flag.CLOCK  # 0.92 s back: a clock reset
    assert out.t_last_s == pytest.approx(0.11)
    # a skipped sample is a no-op: no acceleration to correct with
    np.testing.assert_array_equal(out.acc[0, 3], 0.0)


def test_bad_rates_are_replaced_by_the_last_good_one():
    gyr = np.array(
        [[0.1, 0.2, 0.3], [1e300, 0, 0], [np.nan, 0, 0], [0.0, 35.0, 0], [0.4, 0.5, 0.6]]
    )
    out = _run(np.arange(5) * 0.01, gyr, np.tile(G, (5, 1)))
    np.testing.assert_array_equal(out.gyr[0, 1:4], np.tile([0.1, 0.2, 0.3], (3, 1)))
    np.testing.assert_array_equal(out.gyr[0, 4], [0.4, 0.5, 0.6])
    f = out.flags[0]
    assert f[1] == Flag.GYR_CLIPPED  # 1e300
    assert f[2] == Flag.GYR_CLIPPED | Flag.INVALID
    assert f[3] == Flag.GYR_CLIPPED  # 35 rad/s > 2000 deg/s = 34.9 rad/s
    assert f[0] == f[4] == 0


def test_acc_beyond_range_zero_or_nan_becomes_the_zero_sentinel():
    acc = np.array([G, [0, 0, 16 * 9.80665], [0, 0, 0], [np.inf, 0, 0], G * 1.5])
    out = _run(np.arange(5) * 0.01, np.zeros((5, 3)), acc)
    f = out.flags[0]
    assert [bool(x & Flag.ACC_IGNORED) for x in f] == [False, True, True, True, False]
    assert f[3] & Flag.INVALID
    np.testing.assert_array_equal(out.acc[0, 1:4], 0.0)
    np.testing.assert_array_equal(out.acc[0, 4], G * 1.5)


def test_a_stuck_field_is_ignored_only_while_turning_and_until_it_changes():
    n = 400
    gyr = np.zeros((n, 3))
    gyr[:, 0] = 1.0  # turning about x: y and z of the field change, x does not
    gyr[250:300, 0] = 0.0  # a still stretch
    ang = np.cumsum(gyr[:, 0]) * 0.01
    mag = np.stack([np.full(n, 5.0), 20 * np.cos(ang) - 40 * np.sin(ang),
                    20 * np.sin(ang) + 40 * np.cos(ang)], axis=1)
    mag[100:350] = mag[100]  # the sensor hangs for 2.5 s, then comes back
    out = _run(np.arange(n) * 0.01, gyr, np.tile(G, (n, 1)), mag, check_disturbance=False)
    ignored = (out.flags[0] & Flag.MAG_IGNORED) != 0
    assert not ignored[:149].any()
    # held from sample 100 while turning: samples 101..150 hold it 50 x 0.01 s = mag_stuck_s
    assert int(np.argmax(ignored)) == 150
    assert ignored[150:350].all()  # still ignored while still (and held)
    assert not ignored[350:].any()  # a stuck sensor teaches no clip level
    np.testing.assert_array_equal(out.mag[0, 150:350], 0.0)


def test_a_clip_level_is_learned_and_then_applied_at_once():
    n = 1500
    gyr = np.tile([0.0, 0.0, 1.0], (n, 1))  # turning about z: x and y change
    ang = np.arange(n) * 0.01
    mag = np.stack([20 * np.sin(ang), 20 * np.cos(ang), np.full(n, -40.0)], axis=1)
    mag[:, :2] = np.clip(mag[:, :2], -15.0, 15.0)
    out = _run(np.arange(n) * 0.01, gyr, np.tile(G, (n, 1)), mag, check_disturbance=False)
    ignored = (out.flags[0] & Flag.MAG_IGNORED) != 0
    at_limit = np.any(np.abs(mag[:, :2]) >= 15.0, axis=1)
    # samples away from the limit are never ignored
    assert not ignored[~at_limit].any()
    # after the first clipped stretch has taught the levels, every clipped sample is ignored
    assert ignored.any()
    later = np.arange(n) > 230  # both axes have held a limit for mag_stuck_s by then
    assert ignored[at_limit & later].all()


def test_norm_disturbance_is_gated_and_a_new_steady_field_adopted():
    n = 3500
    mag = np.tile(FIELD, (n, 1))
    mag[1000:] *= 1.5  # a new environment from 10 s on
    out = _run(np.arange(n) * 0.01, np.zeros((n, 3)), np.tile(G, (n, 1)), mag)
    disturbed = (out.flags[0] & Flag.MAG_DISTURBED) != 0
    assert not disturbed[:1000].any()
    assert disturbed[1000:2900].all()  # 20 s until the new field is trusted
    assert not disturbed[3100:].any()
    # without the gate (methods with their own rejection) nothing is flagged
    still = np.zeros((n, 3))
    out = _run(np.arange(n) * 0.01, still, np.tile(G, (n, 1)), mag, check_disturbance=False)
    assert not (out.flags & Flag.MAG_DISTURBED).any()


def test_dip_deviation_is_gated_with_a_given_reference():
    dip = math.radians(60.0)
    field = 50 * np.array([0.0, math.cos(dip), -math.sin(dip)])
    tilted = 50 * np.array([0.0, math.cos(dip + 0.6), -math.sin(dip + 0.6)])
    mag = np.array([field, tilted, field])
    params = Params(mag_dip_ref_deg=60.0, mag_norm_ref=50.0)
    out = _run([0, 0.01, 0.02], np.zeros((3, 3)), np.tile(G, (3, 1)), mag, params=params)
    assert [bool(f & Flag.MAG_DISTURBED) for f in out.flags[0]] == [False, True, False]


def test_field_unit_does_not_change_the_decisions():
    rng = np.random.default_rng(0)
    n = 500
    gyr = rng.normal(scale=1.0, size=(n, 3))
    acc = G + rng.normal(scale=0.3, size=(n, 3))
    mag = FIELD + rng.normal(scale=1.0, size=(n, 3))
    mag[200:260] *= 1.6
    mag[300:] = mag[300]
    a = _run(np.arange(n) * 0.01, gyr, acc, mag)
    b = _run(np.arange(n) * 0.01, gyr, acc, mag * 1000.0)
    np.testing.assert_array_equal(a.flags, b.flags)
    assert (a.flags & Flag.MAG_DISTURBED).any() and (a.flags & Flag.MAG_IGNORED).any()
