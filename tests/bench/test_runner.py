"""The one runner: methods and adapters to one Estimate type, scores from hand derivations."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from margtrack import frames, sim
from margtrack import quaternion as quat
from margtrack.accuracy import error_series, summarize
from margtrack.bench import runner
from margtrack.bench.runner import (
    Adapter,
    ErrorAccumulator,
    Method,
    Scores,
    evaluate,
    evaluate_all,
    run_method,
    score,
)
from margtrack.methods.robust import Robust
from margtrack.run import chunked


def _still(n: int = 200, name: str = "still"):
    rec = sim.simulate_motion("static", duration_s=(n - 1) / 100, rate_hz=100, seed=0,
                              noise=False)
    truth = np.tile([1.0, 0.0, 0.0, 0.0], (rec.n_samples, 1))
    return dataclasses.replace(rec, quat_true=truth, name=name)


def _about(axis, deg, n):
    return np.tile(quat.from_axis_angle(np.asarray(axis, float), np.radians(deg)), (n, 1))


def test_score_matches_the_hand_derivation():
    rec = _still()
    n = rec.n_samples
    # a rotation about the vertical is all heading; about a horizontal axis all inclination
    s = score(rec, _about([0, 0, 1], 10.0, n), "ENU")
    assert (s.total_rmse_deg, s.heading_rmse_deg) == pytest.approx((10.0, 10.0), abs=1e-9)
    assert s.inclination_rmse_deg == pytest.approx(0.0, abs=1e-9)
    s = score(rec, _about([1, 0, 0], 5.0, n), "ENU")
    assert (s.total_rmse_deg, s.inclination_rmse_deg) == pytest.approx((5.0, 5.0), abs=1e-9)
    # half the samples 6 deg off, half exact: RMSE = 6 / sqrt(2)
    q = _about([0, 0, 1], 6.0, n)
    q[n // 2:] = [1.0, 0.0, 0.0, 0.0]
    assert score(rec, q).total_rmse_deg == pytest.approx(6.0 / np.sqrt(2), abs=1e-9)
    # only the movement samples count
    moving = np.zeros(n, dtype=bool)
    moving[n // 2:] = True
    assert score(dataclasses.replace(rec, movement=moving), q).total_rmse_deg < 1e-12


def test_adapters_return_the_estimate_type_and_check_their_shape():
    rec = _still()
    truth = Adapter(lambda r: r.quat_true, "truth", {"k": 1})
    assert isinstance(truth, Method) and isinstance(Robust(), Method)
    est, seconds = run_method(truth, rec)
    assert est.quat.shape == (rec.n_samples, 4) and est.frame == "ENU" and seconds >= 0
    assert est.method == "truth" and est.params == {"k": 1}
    np.testing.assert_array_equal(truth(rec), rec.quat_true)
    assert evaluate(truth, rec).total_rmse_deg == 0.0
    broken = Adapter(lambda r: r.quat_true[:-1], "short")
    with pytest.raises(ValueError, match=r"short returned an array of shape \(199, 4\)"):
        evaluate(broken, rec)


def test_no_truth_is_refused_before_running():
    calls = []
    rec = dataclasses.replace(_still(), quat_true=None)
    with pytest.raises(ValueError, match="'still' has no ground truth"):
        evaluate(Adapter(lambda r: calls.append(1), "x"), rec)
    assert calls == []


def test_run_method_starts_fresh_every_time():
    rec = sim.simulate_motion("random", duration_s=5, rate_hz=100, seed=4)
    method = Robust()
    first, _ = run_method(method, rec)
    second, _ = run_method(method, rec)  # not continued from the first run's state
    np.testing.assert_array_equal(first.quat, second.quat)


def test_scores_means_groups_and_json(tmp_path):
    a, b = _still(name="a"), _still(name="b")
    n = a.n_samples
    off = Adapter(lambda r: _about([0, 0, 1], 2.0 if r.name == "a" else 4.0, n), "off")
    result = evaluate_all(off, [(a, ("g1", "all")), (b, ("g2", "all"))], group_order=("g2",))
    assert isinstance(result, Scores) and result.method == "off"
    assert result.mean()["heading_rmse_deg"] == pytest.approx(3.0, abs=1e-9)
    assert result.mean("g2")["total_rmse_deg"] == pytest.approx(4.0, abs=1e-9)
    assert result.trial("a").total_rmse_deg == pytest.approx(2.0, abs=1e-9)
    assert result.groups() == ["g2", "all", "g1"]
    assert result.n_samples == 2 * n
    with pytest.raises(KeyError, match="no trial 'c'"):
        result.trial("c")
    with pytest.raises(ValueError, match="no recording to evaluate"):
        evaluate_all(off, [])
    result.write_json(tmp_path / "r.json")
    data = json.loads((tmp_path / "r.json").read_text())
    assert data["trials"]["b"]["total_rmse_deg"] == pytest.approx(4.0, abs=1e-9)
    assert set(data["groups"]) == {"g1", "g2", "all"}


def test_accumulated_chunks_equal_the_whole_score_and_the_metrics_oracle():
    rec = sim.simulate_motion("random", duration_s=10, rate_hz=100, seed=7)
    rng = np.random.default_rng(7)
    noise = quat.from_rotvec(rng.normal(scale=0.05, size=(rec.n_samples, 3)))
    est = quat.multiply(noise, rec.quat_true)  # errors of a few degrees, in ENU
    truth = rec.quat_true.copy()
    truth[rng.random(rec.n_samples) < 0.1] = np.nan
    truth[300:420] = np.nan  # a long hole, as where optical markers were lost
    rec = dataclasses.replace(rec, quat_true=truth, movement=rng.random(rec.n_samples) < 0.7)
    whole = score(rec, est, "ENU")
    oracle = summarize(error_series(est, truth, "ENU", "ENU"), rec.movement)  # another path
    assert whole.n_scored == oracle.n_samples == np.count_nonzero(
        rec.movement & ~np.isnan(truth[:, 0]))
    for key in ("total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg"):
        assert getattr(whole, key) == pytest.approx(getattr(oracle, key), rel=1e-12)
    assert 1.0 < whole.total_rmse_deg < 10.0  # 0.05 rad per axis: about 5 deg
    # the same figures chunk by chunk (uneven chunks, one inside the long hole), in NED too
    acc = ErrorAccumulator()
    for a, b in [(0, 1), (1, 333), (333, 400), (400, 1001)]:
        acc.add(rec.slice(a, b), frames.convert(est[a:b], "ENU", "NED"), "NED")
    got = acc.summary()
    assert got.n_samples == whole.n_scored
    for key in ("total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg"):
        assert getattr(got, key) == pytest.approx(getattr(whole, key), rel=1e-12)
    assert acc.rmse_deg() == (got.total_rmse_deg, got.heading_rmse_deg,
                              got.inclination_rmse_deg)


def test_the_chunked_runner_scores_through_the_accumulator():
    # one accumulation code: run_file has no error sums of its own
    assert chunked.ErrorAccumulator is runner.ErrorAccumulator
    assert not hasattr(chunked, "_ErrorSums")


def test_accumulator_without_scored_samples_says_why():
    rec = _still()
    empty = ErrorAccumulator()
    empty.add(dataclasses.replace(rec, quat_true=None), rec.quat_true)
    assert not empty.has_truth and empty.rmse_deg() == (None, None, None)
    with pytest.raises(ValueError, match="no ground truth"):
        empty.summary()
    none_moving = dataclasses.replace(rec, movement=np.zeros(rec.n_samples, bool))
    with pytest.raises(ValueError, match="'still': no sample to evaluate: the mask selects"):
        score(none_moving, rec.quat_true)
    holes = dataclasses.replace(rec, quat_true=np.full((rec.n_samples, 4), np.nan))
    with pytest.raises(ValueError, match="truth is missing \\(NaN\\) on every one"):
        score(holes, rec.quat_true)
    with pytest.raises(ValueError, match=r"estimate has shape \(3, 4\)"):
        ErrorAccumulator().add(rec, rec.quat_true[:3])
