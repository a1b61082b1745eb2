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
    assert summary(flags[0]) == "faults: 0 of 10 samples"
    flags[1, 4] = Flag.INVALID | Flag.GYR_CLIPPED
    flags[0, 7] = Flag.GYR_CLIPPED
    text = summary(flags)
    assert text.startswith("faults: 2 of 20 samples (10 %)")
    assert "INVALID 1 (first at sensor 1, sample 4)" in text
    assert "GYR_CLIPPED 2 (first at sensor 0, sample 7)" in text


def test_summary_counts_rest_and_initialising_as_states_not_faults():
    # issue 40: a clean recording with rest read "flags: 19973 of 56940 samples (35 %)"
    flags = np.zeros(200, dtype=np.uint16)
    flags[:3] = Flag.INITIALISING
    flags[50:120] = Flag.REST
    assert summary(flags) == (
        "faults: 0 of 200 samples; states: REST 70 (35 %, first at sample 50), "
        "INITIALISING 3 (1.5 %, first at sample 0)"
    )
    flags[60] |= Flag.MAG_DISTURBED
    from margtrack.estimator.flags import FAULT_FLAGS, STATE_FLAGS

    assert summary(flags).startswith(
        "faults: 1 of 200 samples (0.5 %): MAG_DISTURBED 1 (first at sample 60); states: REST 70"
    )
    assert Flag.MAG_DISTURBED & FAULT_FLAGS and not (STATE_FLAGS & FAULT_FLAGS)


def test_summary_share_reads_100_not_1e2():
    # issue 40: "3000 of 3001 samples (1e+02 %)"
    flags = np.full(3001, Flag.GAP, dtype=np.uint16)
    flags[0] = 0
    assert summary(flags) == "faults: 3000 of 3001 samples (100 %): GAP 3000 (first at sample 1)"
    from margtrack.estimator.flags import percent

    assert [percent(x) for x in (99.97, 35.08, 0.19, 0.004)] == ["100", "35", "0.19", "<0.01"]


def test_first_problem_ignores_method_flags():
    flags = np.array([Flag.REST, Flag.REST | Flag.CLOCK], dtype=np.uint16)
    assert not (Flag.REST & DATA_FLAGS)
    text = first_problem(flags)
    assert text is not None and text.startswith("sample 1 is flagged CLOCK")
    assert first_problem(np.array([Flag.REST], dtype=np.uint16)) is None
