"""The input policy, registry-wide: every method, the same bad input, the same handling.

One 90 s random motion at 100 Hz with a MEMS error model (the simulator's truth as the
oracle); each case breaks it the way real recordings break and checks the flag, that no
NaN comes out, and the error after recovery against the same samples without the fault.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import margtrack as mt
from margtrack import methods
from margtrack.estimator import Flag

ALL = methods.available()
#: methods with update(); smoother refuses it (tests/methods/test_smoother.py)
ONLINE = [n for n in ALL if not getattr(methods.get(n), "offline", False)]
RECURSIVE = [m for m in ALL if methods.get(m).uses_gyr]
NINE_D = [m for m in RECURSIVE if m != "gyro"]


@pytest.fixture(scope="module")
def rec():
    return mt.sim.simulate_motion("random", duration_s=90, rate_hz=100, seed=1)


def _rmse(est, rec, start_s=0.0):
    keep = rec.t >= start_s
    err = mt.error_series(est.quat[keep], rec.quat_true[keep], est.frame, rec.frame)
    return mt.summarize(err).total_rmse_deg


def _run(name, rec, **arrays):
    data = {"gyr": rec.gyr, "acc": rec.acc, "mag": rec.mag, "t": rec.t} | arrays
    return methods.create(name).run(**data)


def _without(rec, start, stop):
    keep = np.ones(rec.t.shape[0], bool)
    keep[start:stop] = False
    return dataclasses.replace(
        rec,
        t=rec.t[keep],
        gyr=rec.gyr[keep],
        acc=rec.acc[keep],
        mag=rec.mag[keep],
        quat_true=rec.quat_true[keep],
        movement=None if rec.movement is None else rec.movement[keep],
    )


@pytest.mark.parametrize("gap_s", [5.0, 1.0])
@pytest.mark.parametrize("name", NINE_D)
def test_after_a_gap_every_filter_reconverges(name, gap_s, rec):
    start = 4500
    gapped = _without(rec, start, start + int(gap_s * 100))
    est = methods.create(name).run(gapped)
    assert est.flags[start] & Flag.GAP
    assert np.count_nonzero(est.flags & Flag.GAP) == 1
    clean = methods.create(name).run(rec)
    after = rec.t[start] + gap_s + (5.0 if gap_s >= 5.0 else 1.0)
    with_gap, without = _rmse(est, gapped, after), _rmse(clean, rec, after)
    assert with_gap <= 1.5 * without, f"{with_gap:.2f} vs {without:.2f} deg without the gap"


@pytest.mark.parametrize("name", RECURSIVE)
def test_one_absurd_rate_costs_nothing_lasting(name, rec):
    gyr = rec.gyr.copy()
    gyr[3000, 0] = 1e300
    est = _run(name, rec, gyr=gyr)
    assert np.isfinite(est.quat).all()
    assert est.flags[3000] == Flag.GYR_CLIPPED
    assert np.count_nonzero(est.flags & Flag.GYR_CLIPPED) == 1
    clean = _run(name, rec)
    assert _rmse(est, rec, 40.0) <= 2.0 * _rmse(clean, rec, 40.0) + 0.05


@pytest.mark.parametrize("name", ALL)
def test_non_finite_values_in_any_signal_are_flagged_and_skipped(name, rec):
    acc, mag = rec.acc.copy(), rec.mag.copy()
    acc[2000] = np.nan
    mag[2500, 2] = -np.inf
    gyr = rec.gyr.copy()
    gyr[2700] = np.nan
    est = _run(name, rec, gyr=gyr, acc=acc, mag=mag)
    assert np.isfinite(est.quat).all()
    assert est.flags[2000] & Flag.INVALID and est.flags[2000] & Flag.ACC_IGNORED
    assert est.flags[2500] & Flag.INVALID and est.flags[2500] & Flag.MAG_IGNORED
    if methods.get(name).uses_gyr:
        assert est.flags[2700] & Flag.INVALID
    clean = _run(name, rec)
    assert _rmse(est, rec, 35.0) <= 1.2 * _rmse(clean, rec, 35.0) + 0.05


@pytest.mark.parametrize("name", [m for m in ALL if m != "gyro"])
def test_a_stuck_magnetometer_is_noticed_by_every_method(name, rec):
    mag = rec.mag.copy()
    mag[1000:] = mag[1000]
    est = _run(name, rec, mag=mag)
    ignored = (est.flags[1000:] & Flag.MAG_IGNORED) != 0
    assert ignored.mean() > 0.95, f"only {ignored.mean():.0%} of the stuck samples flagged"
    assert np.isfinite(est.quat).all()


@pytest.mark.parametrize("name", ALL)
def test_results_do_not_depend_on_the_field_unit(name, rec):
    micro = _run(name, rec)
    for factor in (1000.0, 0.01):  # nT, gauss
        other = _run(name, rec, mag=rec.mag * factor)
        np.testing.assert_allclose(np.abs(other.quat[:, 0]), np.abs(micro.quat[:, 0]), atol=1e-9)
        np.testing.assert_array_equal(other.flags, micro.flags)


@pytest.mark.parametrize("name", ALL)
def test_unusable_first_samples_delay_the_start_instead_of_refusing(name, rec):
    acc = rec.acc.copy()
    acc[:5] = 0.0
    est = _run(name, rec, acc=acc)
    assert (est.flags[:5] & Flag.INITIALISING).all()
    assert not (est.flags[5:] & Flag.INITIALISING).any()
    clean = _run(name, rec)
    assert _rmse(est, rec, 10.0) <= 1.2 * _rmse(clean, rec, 10.0) + 0.05


@pytest.mark.parametrize("name", ONLINE)
def test_update_equals_run_through_bad_samples(name, rec):
    n = 600
    gyr, acc, mag = rec.gyr[:n].copy(), rec.acc[:n].copy(), rec.mag[:n].copy()
    t = rec.t[:n].copy()
    acc[:3] = 0.0
    gyr[100] = 1e300
    acc[150] = np.nan
    mag[200:260] = mag[200]
    t[300:] += 1.0  # a gap
    t[400] = t[399]  # a repeated stamp
    batch = methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=t, check_units=False)
    live = methods.create(name)
    steps, flags = [], []
    for i in range(n):
        dt = None if i == 0 else t[i] - t[i - 1]
        steps.append(live.update(gyr[i], acc[i], mag[i], dt=dt))
        flags.append(int(live.flags[0]))
    np.testing.assert_allclose(np.array(steps), batch.quat, atol=1e-12)
    np.testing.assert_array_equal(flags, batch.flags)
