"""Cross-validation by trial (bench/cv.py), the declared grids and `margtrack tune --cv`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from broad_slices import write_broad_slices
from typer.testing import CliRunner

from margtrack import io, methods
from margtrack.bench import cv, grids
from margtrack.bench.runner import Scores, TrialScore, evaluate_all
from margtrack.bench.tune import GridScores, evaluate_grid, tune
from margtrack.cli import app

GROUPS = (("all_trials", "undisturbed"),) * 2 + (("all_trials", "disturbed"),) * 2


def grid_of(total: list[list[float]], groups=GROUPS) -> GridScores:
    """A GridScores from a points x trials total matrix; heading 0.8x, inclination 0.5x."""
    results = []
    for p, row in enumerate(total):
        trials = tuple(
            TrialScore(f"t{j}", v, 0.8 * v, 0.5 * v, 100, groups[j]) for j, v in enumerate(row)
        )
        results.append(Scores("m", {"x": p}, trials, ("undisturbed", "disturbed")))
    return GridScores("m", tuple(f"x={p}" for p in range(len(total))), tuple(results))


def test_loto_by_hand_and_a_point_that_overfits_one_trial():
    # p0 is best in-sample (2.25) only because of t3; on the others it is worse than p1
    res = cv.cross_validate_grid(grid_of([[3, 3, 3, 0], [2.5, 2.5, 2.5, 2.5]]))
    # without t0/t1/t2: p0 = (3+3+0)/3 = 2 < 2.5, scored 3; without t3: p1 (2.5 < 3), scored 2.5
    assert [f.chosen for f in res.folds] == [0, 0, 0, 1]
    assert res.cross_validated.mean()["total_rmse_deg"] == pytest.approx((3 * 3 + 2.5) / 4)
    assert res.cross_validated.mean()["heading_rmse_deg"] == pytest.approx(0.8 * 11.5 / 4)
    assert res.cross_validated.mean("disturbed")["total_rmse_deg"] == pytest.approx(2.75)
    assert res.cross_validated.mean("undisturbed")["total_rmse_deg"] == pytest.approx(3.0)
    assert res.best_index == 0 and res.best_in_sample.mean()["total_rmse_deg"] == 2.25
    assert res.stability == pytest.approx(0.75) and res.n_distinct_choices == 2
    assert res.chosen_by_trial == {"t0": "x=0", "t1": "x=0", "t2": "x=0", "t3": "x=1"}
    assert res.folds[3].train_total_deg == pytest.approx(2.5)
    assert res.folds[3].held_out_total_deg == pytest.approx(2.5)
    assert res.leave_one_out and res.n_folds == 4


def test_k_folds_by_hand_with_a_tie():
    total = [[1, 1, 1, 5], [2, 1.5, 2, 1.5], [1.5, 1.5, 1.5, 1.5]]
    res = cv.cross_validate_grid(grid_of(total), folds=2)
    # folds: trial i in fold i mod 2 -> {t0, t2}, {t1, t3}
    assert [f.held_out for f in res.folds] == [("t0", "t2"), ("t1", "t3")]
    # fold 0 trains on t1, t3: p0 3, p1 1.5, p2 1.5: the tie goes to p1 (grid order)
    # fold 1 trains on t0, t2: p0 1, p1 2, p2 1.5: p0, which then scores 1 and 5
    assert [f.chosen for f in res.folds] == [1, 0]
    assert res.cross_validated.mean()["total_rmse_deg"] == pytest.approx((2 + 1 + 2 + 5) / 4)
    assert not res.leave_one_out and res.split_name() == "2 folds by trial"
    # in sample: p2 (1.5) beats p0 (2.0) and p1 (1.75)
    assert res.best_index == 2


def test_ties_go_to_the_first_point_and_nan_points_are_never_chosen():
    same = [[2.0, 1.0, 3.0, 4.0]] * 3
    assert [f.chosen for f in cv.cross_validate_grid(grid_of(same)).folds] == [0, 0, 0, 0]
    total = np.array([[np.nan, 0.1, 0.1, 0.1], [1.0, 1.0, 1.0, 1.0]])
    # p0 failed on t0: chosen only in the fold that holds t0 out
    assert cv.choose_point(total, np.array([False, True, True, True])) == 0
    assert cv.choose_point(total, np.array([True, True, False, False])) == 1
    with pytest.raises(ValueError, match="every grid point failed"):
        cv.choose_point(np.full((2, 3), np.nan), np.ones(3, dtype=bool))


def test_fold_split_is_deterministic_and_bad_folds_are_refused():
    assert cv.fold_of_trials(5).tolist() == [0, 1, 2, 3, 4]
    assert cv.fold_of_trials(5, 2).tolist() == [0, 1, 0, 1, 0]
    with pytest.raises(ValueError, match="--folds 6 is not possible with 5 trials: give 2 to 5"):
        cv.fold_of_trials(5, 6)
    with pytest.raises(ValueError, match="--folds 1 is not possible"):
        cv.fold_of_trials(5, 1)
    with pytest.raises(ValueError, match="at least 2 trials"):
        cv.fold_of_trials(1)
    with pytest.raises(ValueError, match="whole number"):
        cv.fold_of_trials(4, True)


def test_declared_grids_name_real_parameters_around_their_defaults():
    assert set(grids.GRIDS) >= {"robust", "gradient", "bachmann", "ekf", "bias-kf"}
    for method, grid in grids.GRIDS.items():
        defaults = methods.get(method).params_type()
        assert 1 <= len(grid) <= 4, method
        for name, p in grid.items():
            assert 3 <= len(p.values) <= 5 and p.reason, (method, name)
            assert getattr(defaults, name) in p.values, (method, name)  # the default is a point
            assert list(p.values) == sorted(p.values), (method, name)
    with pytest.raises(ValueError, match=r"no declared tuning grid.*-g name=v1"):
        grids.declared_grid("gyro")


@pytest.fixture(scope="module")
def slices(broad_folder, tmp_path_factory) -> Path:
    """Three 7 s BROAD slices (two undisturbed, one disturbed) with their trials.json."""
    return write_broad_slices(broad_folder, tmp_path_factory.mktemp("slices"),
                              ["01_undisturbed_slow_rotation_A", "06_undisturbed_fast_rotation_A",
                               "28_disturbed_stationary_magnet_A"])


def _recordings(folder: Path):
    return [(io.read(t.path), tuple(t.groups)) for t in io.broad_trials(folder)]


def test_cli_tune_cv_matches_a_hand_selection_from_direct_runs(slices, tmp_path):
    out = tmp_path / "cv.json"
    args = ["tune", str(slices), "-m", "gradient", "-g", "beta=0.005,0.1", "--cv",
            "--workers", "1", "--json", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "cross-validated" in result.output and "leave-one-trial-out" in result.output
    got = json.loads(out.read_text())
    # oracle: each point run directly on each slice, the LOTO choice made here by hand
    recs = _recordings(slices)
    direct = [evaluate_all(methods.create("gradient", {"beta": b}), recs) for b in (0.005, 0.1)]
    total = np.array([[t.total_rmse_deg for t in s.trials] for s in direct])
    expect = []
    for j in range(3):
        train = [k for k in range(3) if k != j]
        means = total[:, train].mean(axis=1)
        c = 0 if means[0] <= means[1] else 1
        expect.append(total[c, j])
        chosen = got["cross_validated"]["trials"][recs[j][0].name]["chosen"]
        assert chosen == f"beta={(0.005, 0.1)[c]}"
    cv_mean = got["cross_validated"]["mean"]["total_rmse_deg"]
    assert cv_mean == pytest.approx(np.mean(expect), 1e-12)
    best = total[int(np.argmin(total.mean(axis=1)))].mean()
    assert got["in_sample_best"]["mean"]["total_rmse_deg"] == pytest.approx(best, 1e-12)
    default = evaluate_all(methods.create("gradient"), recs).mean()["total_rmse_deg"]
    assert got["in_sample_default"]["mean"]["total_rmse_deg"] == pytest.approx(default, 1e-12)
    assert set(got["cross_validated"]["groups"]) >= {"undisturbed", "disturbed"}
    # the JSON is not replaced without --force
    again = CliRunner().invoke(app, args)
    assert again.exit_code != 0 and "--force" in again.output


def test_evaluate_grid_adds_the_defaults_once_and_tune_still_ranks(slices):
    recs = _recordings(slices)[:2]
    in_grid = evaluate_grid("gradient", {"beta": [0.025, 0.1]}, recs, with_default=True)
    assert in_grid.default_index == 0 and in_grid.default is in_grid.results[0]
    extra = evaluate_grid("gradient", {"beta": [0.005, 0.1]}, recs, with_default=True)
    assert extra.default_index is None and extra.labels == ("beta=0.005", "beta=0.1")
    assert extra.default.mean() == in_grid.results[0].mean()
    ranked = tune("gradient", {"beta": [0.005, 0.1]}, recs)
    assert [r.mean()["total_rmse_deg"] for r in ranked.results] == sorted(
        r.mean()["total_rmse_deg"] for r in extra.results
    )


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["-g", "beta=0.01,0.1", "--cv", "--folds", "4"], "--folds 4 is not possible with 3 tri"),
        (["-g", "nope=1,2", "--cv"], "unknown parameter"),
        (["-g", "beta=0.01,0.1", "--folds", "2"], "add --cv"),
        (["-m", "gyro", "--cv"], "no declared tuning grid"),
    ],
)
def test_cli_tune_cv_bad_input(slices, extra, message):
    args = ["tune", str(slices), *(["-m", "gradient"] if "-m" not in extra else []), *extra,
            "--workers", "1"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code != 0
    assert message in " ".join(result.output.split())


def test_cli_tune_cv_one_trial_is_refused(slices, tmp_path):
    one = tmp_path / "one.hdf5"
    one.write_bytes(next(slices.glob("01_*.hdf5")).read_bytes())
    result = CliRunner().invoke(
        app, ["tune", str(one), "-m", "gradient", "-g", "beta=0.01,0.1", "--cv", "--workers", "1"]
    )
    assert result.exit_code != 0 and "at least 2 trials" in " ".join(result.output.split())


def test_bench_broad_prints_the_cross_validated_figure(broad_folder, tmp_path, monkeypatch):
    index = json.loads((broad_folder / "trials.json").read_text())
    keep = ["02_undisturbed_slow_rotation_B", "30_disturbed_stationary_magnet_C"]
    index["trials"] = {n: index["trials"][n] for n in keep}
    folder = tmp_path / "broad"
    folder.mkdir()
    (folder / "trials.json").write_text(json.dumps(index))
    for name in keep:
        (folder / f"{name}.hdf5").symlink_to(broad_folder / f"{name}.hdf5")
    two_points = {"beta": grids.GridParam((0.005, 0.025), "test")}
    monkeypatch.setitem(grids.GRIDS, "gradient", two_points)  # a fast grid
    result = CliRunner().invoke(app, [
        "bench", "broad", str(folder), "-m", "gradient", "--external", "", "--workers", "1",
        "--out", str(tmp_path / "b.png"),
    ])
    assert result.exit_code == 0, result.output
    assert "cross-validation took" in result.output
    row = next(r for r in result.output.splitlines() if r.startswith("│ gradient") and
               len(r.split("│")) == 9)
    cells = [c.strip() for c in row.split("│")[1:-1]]
    recs = [(io.read_broad(folder / f"{n}.hdf5"), tuple(index["trials"][n]["groups"]))
            for n in keep]
    expect = cv.cross_validate("gradient", {"beta": [0.005, 0.025]}, recs)
    assert float(cells[3]) == pytest.approx(
        expect.cross_validated.mean()["total_rmse_deg"], abs=0.006
    )
    assert float(cells[1]) == pytest.approx(expect.default.mean()["total_rmse_deg"], abs=0.006)


def test_cross_validation_does_not_depend_on_the_order_jobs_finish(slices):
    # a mapper that finishes the jobs last-first, like workers might; the real Dask mapper
    # runs the same evaluate_grid path in tests/batch/test_batch_local.py
    def last_first(job, items, shared):
        for i in reversed(range(len(items))):
            yield i, job(shared, items[i])

    recs = _recordings(slices)
    grid = {"beta": [0.005, 0.1]}
    here = cv.cross_validate("gradient", grid, recs, folds=2)
    told: list[str] = []
    there = cv.cross_validate(
        "gradient", grid, recs, folds=2, mapper=last_first, progress=told.append
    )
    assert told == ["defaults", "beta=0.1", "beta=0.005"]
    assert there.to_json() == here.to_json()
