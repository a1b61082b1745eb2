"""The health-flag schema: names, counts and the one-line summary."""

from __future__ import annotations

import numpy as np

from margtrack.estimator.flags import (
    DATA_FLAGS,
    Flag,
    count_flags,
    describe,
    first_problem,
    summary,
)


def test_bits_are_distinct_powers_of_two():
    values = [int(f) for f in Flag]
    assert len(set(values)) == len(values)
    assert all(v & (v - 1) == 0 for v in values)
    assert max(values) < 2**16  # stored as uint16


def test_describe_and_count():
    assert describe(0) == "OK"
    assert describe(Flag.GAP | Flag.ACC_IGNORED) == "GAP|ACC_IGNORED"
    flags = np.array([0, Flag.GAP, Flag.GAP | Flag.MAG_IGNORED, 0], dtype=np.uint16)
    assert count_flags(flags) == {"GAP": 2, "MAG_IGNORED": 1}


def test_summary_names_the_first_sample_and_sensor():
    flags = np.zeros((2, 10), dtype=np.uint16)
    assert summary(flags[0]) == "flags: none of 10 samples"
    flags[1, 4] = Flag.INVALID | Flag.GYR_CLIPPED
    flags[0, 7] = Flag.GYR_CLIPPED
    text = summary(flags)
    assert text.startswith("flags: 2 of 20 samples (10 %)")
    assert "INVALID 1 (first at sensor 1, sample 4)" in text
    assert "GYR_CLIPPED 2 (first at sensor 0, sample 7)" in text


def test_first_problem_ignores_method_flags():
    flags = np.array([Flag.REST, Flag.REST | Flag.CLOCK], dtype=np.uint16)
    assert not (Flag.REST & DATA_FLAGS)
    text = first_problem(flags)
    assert text is not None and text.startswith("sample 1 is flagged CLOCK")
    assert first_problem(np.array([Flag.REST], dtype=np.uint16)) is None
