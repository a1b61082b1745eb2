"""The screening's reference gain computed once per sample (shared clock) changes nothing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from margtrack.estimator import screen_kernel as screen


def _coef() -> np.ndarray:
    coef = np.zeros(screen.N_COEF)
    coef[screen.C_GYR_RANGE] = 35.0
    coef[screen.C_ACC_RANGE] = 160.0
    coef[screen.C_MAX_GAP] = 0.5
    coef[screen.C_MAG_STUCK] = 1.0
    coef[screen.C_NORM_TOL] = 0.1
    coef[screen.C_DIP_TOL] = math.radians(10.0)
    coef[screen.C_CHECK_DISTURBANCE] = 1.0
    coef[screen.C_REF_DIP] = math.nan
    return coef


@pytest.mark.kernel
def test_ref_gain_is_the_first_order_gain_of_the_interval():
    # hand values: 1 - exp(-dt / 60 s); none for dt <= 0 (first sample, gap, skip)
    assert screen.ref_gain(0.01) == 1.0 - math.exp(-0.01 / 60.0)
    assert screen.ref_gain(60.0) == pytest.approx(1.0 - math.exp(-1.0), abs=1e-15)
    assert screen.ref_gain(0.0) == 0.0
    assert screen.ref_gain(-1.0) == 0.0


@pytest.mark.kernel
def test_screen_one_equals_screen_one_k_with_the_shared_gain_on_bad_input():
    rng = np.random.default_rng(3)
    n = 400
    dts = np.full(n, 0.01)
    dts[[0, 50, 51]] = 0.0  # first sample, a gap, a skipped timestamp
    gyr = rng.normal(0.0, 1.0, (n, 3))
    acc = rng.normal(0.0, 0.5, (n, 3)) + [0.0, 0.0, 9.81]
    mag = rng.normal(0.0, 1.0, (n, 3)) + [20.0, 0.0, -40.0]
    gyr[10] = np.nan
    acc[20] = 0.0
    acc[30] = 1e6
    mag[40] = np.inf
    mag[100:150] *= 1.6  # disturbed: the reference tracking and its candidate run
    mag[200:260] = mag[200]  # stuck while turning
    coef = _coef()
    sc_a = np.zeros((1, screen.N_SCREEN))
    sc_b = np.zeros((1, screen.N_SCREEN))
    screen.fresh(sc_a)
    screen.fresh(sc_b)
    disturbed = 0
    for i in range(n):
        args = (gyr[i, 0], gyr[i, 1], gyr[i, 2], acc[i, 0], acc[i, 1], acc[i, 2],
                mag[i, 0], mag[i, 1], mag[i, 2], True, True)
        a = screen.screen_one(coef, sc_a[0], dts[i], 0, *args)
        b = screen.screen_one_k(coef, sc_b[0], dts[i], screen.ref_gain(dts[i]), 0, *args)
        assert a == b or np.array_equal(np.array(a), np.array(b), equal_nan=True), i
        disturbed += bool(a[0] & screen.MAG_DISTURBED)
        np.testing.assert_array_equal(sc_a, sc_b)
    assert disturbed > 10  # the disturbed branch (which uses the gain) was exercised
    # the tracked reference moved by the gain: not its first value any more
    assert sc_a[0, screen.S_REF + screen.R_NORM] != pytest.approx(np.linalg.norm(mag[0]), rel=1e-9)


@pytest.mark.kernel
def test_screen_samples_equals_screen_one_per_sensor_and_sample():
    # two sensors, one faulty: the series kernel (gain once per sample, inlined) gives what
    # screen_one gives sample by sample, states included
    rng = np.random.default_rng(5)
    n = 300
    dts = np.full(n, 0.01)
    dts[[0, 70]] = 0.0
    tflags = np.zeros(n, dtype=np.uint16)
    tflags[70] = screen.GAP
    gyr = rng.normal(0.0, 1.0, (2, n, 3))
    acc = rng.normal(0.0, 0.5, (2, n, 3)) + [0.0, 0.0, 9.81]
    mag = rng.normal(0.0, 1.0, (2, n, 3)) + [20.0, 0.0, -40.0]
    gyr[1, 10] = np.nan
    acc[1, 20] = 1e6
    mag[1, 100:150] *= 1.6
    coef = _coef()
    sc = np.zeros((2, screen.N_SCREEN))
    screen.fresh(sc)
    outs = [np.empty((2, n, 3)) for _ in range(3)]
    flags = np.empty((2, n), dtype=np.uint16)
    screen.screen_samples(coef, dts, tflags, gyr, acc, mag, True, True, sc, *outs, flags)
    assert np.any(flags[1] & screen.MAG_DISTURBED) and np.any(flags[1] & screen.INVALID)
    for s in range(2):
        state = np.zeros((1, screen.N_SCREEN))
        screen.fresh(state)
        for i in range(n):
            f, *values = screen.screen_one(coef, state[0], dts[i], tflags[i], *gyr[s, i],
                                           *acc[s, i], *mag[s, i], True, True)
            assert flags[s, i] == f, (s, i)
            np.testing.assert_array_equal(np.concatenate([o[s, i] for o in outs]), values)
        np.testing.assert_array_equal(sc[s], state[0])
