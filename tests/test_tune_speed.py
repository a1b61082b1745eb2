"""margtrack tune (grid search) and the speed helper."""

from __future__ import annotations

import time

import numpy as np
import pytest

from margtrack import sim
from margtrack.bench import experiments
from margtrack.bench.speed import measure
from margtrack.bench.tune import parse_grid, tune


def test_parse_grid():
    assert parse_grid(["gain=0.1, 0.2", "mag-weight=1"]) == {
        "gain": ["0.1", "0.2"],
        "mag_weight": ["1"],
    }
    with pytest.raises(ValueError, match="name=v1,v2"):
        parse_grid(["gain"])


def test_tune_orders_results_best_first_and_equals_direct_evaluation():
    noisy = sim.simulate_motion("random", duration_s=10, seed=2)
    rec = [(noisy, ("all_trials",))]
    result = tune("gyro", {"frame": ["NED", "ENU"]}, rec)
    totals = [r.mean()["total_rmse_deg"] for r in result.results]
    assert totals == sorted(totals)
    assert result.best.mean()["total_rmse_deg"] == totals[0]
    # both frames describe the same orientations: the error cannot depend on the frame
    assert totals[0] == pytest.approx(totals[1], abs=1e-9)
    with pytest.raises(ValueError, match="grid is empty"):
        tune("gyro", {}, rec)


def test_measure_reports_the_best_of_repeats():
    calls = []

    def work():
        calls.append(1)
        time.sleep(0.002)

    t = measure("sleep", work, 1000, repeats=3)
    assert len(calls) == 4  # one warm-up and three timed runs
    assert 0.002 <= t.seconds < 0.05
    assert t.samples_per_s == pytest.approx(1000 / t.seconds)
    assert t.ratio_to(measure("twice", lambda: time.sleep(0.004), 1000, repeats=1)) > 1.0


def test_unknown_experiment_names_the_available_ones(tmp_path):
    with pytest.raises(ValueError, match="unknown experiment 'nope'; available:"):
        experiments.run("nope", tmp_path)
    assert np.all([isinstance(n, str) for n in experiments.available()])


def test_speed_input_truncates_and_repeats(tmp_path):
    from margtrack.bench.speed import speed_input

    # no BROAD folder here: the simulated fallback, 10 s at 100 Hz = 1001 samples
    short = speed_input(500, folder=tmp_path, rate_hz=100.0, fallback_duration_s=10.0)
    assert short.gyr.shape == (500, 3) and short.source == "a simulated random motion"
    long = speed_input(2500, folder=tmp_path, rate_hz=100.0, fallback_duration_s=10.0)
    assert long.source.endswith("repeated")
    np.testing.assert_array_equal(long.acc[1001:1501], short.acc)  # the data again, end to end
    assert long.mag.flags.c_contiguous
