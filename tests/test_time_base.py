"""The common time base of sensors on their own clocks, and their flags carried onto it."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack.estimator.flags import Flag
from margtrack.recording import Recording
from margtrack.time_base import common_rate_hz, common_time_base, flags_on_time_base


def _rec(t: np.ndarray, name: str = "") -> Recording:
    n = t.size
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    return Recording.from_arrays(t=t, gyr=np.zeros((n, 3)), acc=acc, name=name)


def test_span_every_sensor_covers_at_the_slowest_rate_rounded_to_whole_hz():
    a = _rec(1.0 + np.arange(500) / 99.7)  # 1.0 .. 6.005 s at 99.7 Hz
    b = _rec(0.2 + np.arange(1200) / 200.0)  # 0.2 .. 6.195 s at 200 Hz
    recs = {"a": a, "b": b}
    assert common_rate_hz(recs) == 100.0  # 99.7 is within 1 % of 100
    t, notes = common_time_base(recs)
    assert t[0] == 1.0  # the latest first sample
    np.testing.assert_allclose(np.diff(t), 0.01, atol=1e-12)
    assert t[-1] <= a.t[-1] and a.t[-1] - t[-1] < 0.01  # the earliest last sample
    # b lost 0.8 s at the start (> 0.5 s): noted, and the rates merged (200 vs 99.7 Hz)
    assert any("set by a (start)" in n and "b 0.99 s" in n for n in notes)
    assert any("merged onto 100 Hz" in n for n in notes)


def test_a_rate_far_from_a_whole_hz_is_kept():
    recs = {"a": _rec(np.arange(100) / 45.5)}  # 0.5 Hz off 46: beyond 1 %
    assert common_rate_hz(recs) == pytest.approx(45.5)


def test_no_common_span_names_each_span_and_the_fix():
    recs = {"pelvis": _rec(1000.0 + np.arange(50) / 50), "thigh": _rec(np.arange(50) / 50)}
    with pytest.raises(ValueError, match=r"no common time span \(pelvis 1000.000-.*--align-start"):
        common_time_base(recs)
    with pytest.raises(ValueError, match="rate_hz must be a finite number > 0"):
        common_time_base({"a": _rec(np.arange(50) / 50)}, rate_hz=0.0)
    with pytest.raises(ValueError, match="sensor a has 1 sample"):
        common_time_base({"a": _rec(np.zeros(1))})


def test_flags_of_the_two_samples_around_each_frame_and_gap_across_a_long_interval():
    rec_t = np.array([0.0, 0.1, 0.2, 0.6, 0.7])  # a 0.4 s gap between 0.2 and 0.6
    flags = np.array([0, int(Flag.INVALID), 0, 0, int(Flag.ACC_IGNORED)], dtype=np.uint16)
    t = np.array([0.05, 0.15, 0.25, 0.65, 0.7])
    out = flags_on_time_base(rec_t, flags, t, max_gap_s=0.25)
    expected = [int(Flag.INVALID), int(Flag.INVALID), int(Flag.GAP), int(Flag.ACC_IGNORED),
                int(Flag.ACC_IGNORED)]
    assert out.tolist() == expected
    assert flags_on_time_base(rec_t, None, t, 0.25).tolist() == [0, 0, int(Flag.GAP), 0, 0]
