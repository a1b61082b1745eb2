"""The live sensors' reference field norms (live/field_norm.py)."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack.live.field_norm import REF_SAMPLES, REF_SPAN_S, FieldNormReference


def _feed(ref: FieldNormReference, t: np.ndarray, mag: np.ndarray, sizes: list[int]) -> None:
    """Feed (S, N, 3) fields on times t (N,) in batches of the given sizes, cycled."""
    i, k = 0, 0
    while i < t.size:
        j = min(t.size, i + sizes[k % len(sizes)])
        ref.feed(t[i:j], mag[:, i:j])
        i, k = j, k + 1


@pytest.mark.kernel
def test_reference_is_the_median_of_the_spaced_norms_of_the_first_second() -> None:
    rng = np.random.default_rng(3)
    n = 300
    t = np.arange(n) / 100.0
    norms = 48.0 + rng.normal(0.0, 2.0, (2, n))
    norms[0, 7] = 4800.0  # a glitch among the picked norms (t = 0.07 s): the median ignores it
    directions = rng.normal(size=(2, n, 3))
    directions /= np.linalg.norm(directions, axis=2, keepdims=True)
    mag = directions * norms[..., None]
    for sizes in ([1], [4], [3, 7, 1], [40]):
        ref = FieldNormReference(2)
        _feed(ref, t, mag, sizes)
        # the expected samples by hand: every frame due, REF_SPAN_S / REF_SAMPLES apart
        due, picked = -np.inf, []
        for i in range(n):
            if t[i] >= due and len(picked) < REF_SAMPLES:
                picked.append(i)
                due = t[i] + REF_SPAN_S / REF_SAMPLES
        if sizes == [40]:  # one batch holds a whole second: its frames are picked in turn
            assert picked[-1] < 100
        assert ref.complete
        np.testing.assert_allclose(ref.norm, np.median(norms[:, picked], axis=1), rtol=1e-14)
        assert ref.norm[0] < 100.0


@pytest.mark.kernel
def test_missing_fields_are_skipped_and_a_dead_sensor_stays_unknown() -> None:
    n = 200
    t = np.arange(n) / 100.0
    mag = np.tile(np.array([30.0, 0.0, -40.0]), (3, n, 1))  # norm 50
    mag[0, :50] = np.nan  # sensor 0: no field for its first half second
    mag[1, ::2] = 0.0  # sensor 1: every other sample zero (no measurement)
    mag[2] = np.nan  # sensor 2: a dead magnetometer
    ref = FieldNormReference(3)
    _feed(ref, t, mag, [4])
    np.testing.assert_array_equal(ref.norm[:2], [50.0, 50.0])
    assert np.isnan(ref.norm[2]) and not ref.complete
    # the reference waits for the field: sensor 0's has no sample before t = 0.5 s
    late = FieldNormReference(1)
    _feed(late, t[:140], mag[:1, :140], [4])
    assert np.isnan(late.norm[0])  # 0.9 s of field, 14 norms at most: not yet
    _feed(late, t[140:], mag[:1, 140:], [4])
    assert late.norm[0] == 50.0


def test_engine_health_uses_the_reference() -> None:
    from margtrack.live.stats import StatsMeter

    meter = StatsMeter(("a", "b"))
    t = np.arange(150) / 100.0
    mag = np.tile(np.array([0.0, 30.0, -40.0]), (2, 150, 1))
    mag[1, 120:] *= 1.5  # sensor b's field grows by half after its first second
    for i in range(0, 150, 5):
        meter.batch(t[i:i + 5], np.zeros((2, 5), bool), mag[:, i:i + 5], 0.001, 0)
    health = meter.health(np.zeros(2, dtype=np.int64))
    np.testing.assert_allclose(health.mag_norm_ratio, [1.0, 1.5], rtol=1e-14)
    assert health.mag_ok.tolist() == [True, False]
