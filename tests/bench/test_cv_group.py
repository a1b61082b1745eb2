"""Cross-validation by group: each kind of trial held out in turn (bench/cv.py, --cv group)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from broad_slices import write_broad_slices
from typer.testing import CliRunner

from margtrack import io, methods
from margtrack.bench import broad, cv
from margtrack.bench.runner import Scores, TrialScore, evaluate_all
from margtrack.bench.tune import GridScores
from margtrack.cli import app

KINDS = {"t0": "slow", "t1": "slow", "t2": "magnet", "t3": "magnet", "t4": "tapping"}


def grid_of(total: list[list[float]]) -> GridScores:
    """A GridScores from a points x trials total matrix; heading 0.8x, inclination 0.5x."""
    results = []
    for p, row in enumerate(total):
        trials = tuple(
            TrialScore(f"t{j}", v, 0.8 * v, 0.5 * v, 100, ("all_trials",))
            for j, v in enumerate(row)
        )
        results.append(Scores("m", {"x": p}, trials, ()))
    return GridScores("m", tuple(f"x={p}" for p in range(len(total))), tuple(results))


def test_leave_one_group_out_by_hand():
    # p0 is excellent on the magnet trials only, p1 steady everywhere
    total = [[2.5, 2.5, 0, 0, 2.5], [2, 2, 2, 2, 2]]
    res = cv.cross_validate_grid(grid_of(total), kinds=KINDS)
    assert [f.kind for f in res.folds] == ["slow", "magnet", "tapping"]
    assert [f.held_out for f in res.folds] == [("t0", "t1"), ("t2", "t3"), ("t4",)]
    # without slow: p0 (0+0+2.5)/3 = 0.83 < 2: chosen, scores 2.5 on slow
    # without magnet: p0 2.5 > p1 2: p1, scores 2 on magnet
    # without tapping: p0 (2.5+2.5+0+0)/4 = 1.25 < 2: p0, scores 2.5 on tapping
    assert [f.chosen for f in res.folds] == [0, 1, 0]
    assert res.cross_validated.mean()["total_rmse_deg"] == pytest.approx((2.5 * 3 + 2 * 2) / 5)
    assert res.folds[1].held_out_figures == pytest.approx((2.0, 1.6, 1.0))
    assert res.by_kind and res.n_folds == 3
    assert res.split_name() == "leave-one-group-out (3 groups)"
    # leave-one-trial-out of the same grid: t2's fold still sees t3, the magnet's twin:
    # p0 (2.5+2.5+0+2.5)/4 = 1.875 < 2 is chosen for t2 and scores 0 there
    loto = cv.cross_validate_grid(grid_of(total))
    assert loto.chosen_by_trial["t2"] == "x=0" and res.chosen_by_trial["t2"] == "x=1"
    data = res.to_json()
    assert [f["group"] for f in data["folds"]] == ["slow", "magnet", "tapping"]
    assert data["split"] == "leave-one-group-out (3 groups)"


@pytest.mark.parametrize("seed", range(5))
def test_the_held_out_group_never_influences_its_own_choice(seed):
    # any change to a group's own scores leaves the point chosen for it unchanged
    rng = np.random.default_rng(seed)
    total = rng.uniform(1, 5, size=(4, 5))
    base = cv.cross_validate_grid(grid_of(total.tolist()), kinds=KINDS)
    for fold in base.folds:
        cols = [int(n[1:]) for n in fold.held_out]
        changed = total.copy()
        changed[:, cols] = rng.uniform(0, 10, size=(4, len(cols)))  # any other figures
        changed[base.folds[0].chosen if fold is not base.folds[0] else 0, cols] = 0.0
        again = cv.cross_validate_grid(grid_of(changed.tolist()), kinds=KINDS)
        same = next(f for f in again.folds if f.kind == fold.kind)
        assert same.chosen == fold.chosen and same.train_total_deg == fold.train_total_deg


def test_group_split_is_refused_when_it_cannot_choose():
    with pytest.raises(ValueError, match="at least 2 kinds"):
        cv.fold_of_kinds(["a", "a", "a"])
    with pytest.raises(ValueError, match="no kind"):
        cv.cross_validate_grid(grid_of([[1, 2, 3, 4, 5]]), kinds={"t0": "a"})
    with pytest.raises(ValueError, match="leave it out with --cv group"):
        cv.cross_validate_grid(grid_of([[1, 2, 3, 4, 5]]), folds=2, kinds=KINDS)
    assert cv.fold_of_kinds(["b", "a", "b", "c"]).tolist() == [0, 1, 0, 2]


def test_broad_kinds_of_the_shared_trials(broad_folder):
    kinds = broad.trial_kinds(broad_folder)
    assert kinds["04_undisturbed_slow_rotation_with_breaks_A"] == "slow_rotation"
    assert kinds["21_undisturbed_fast_combined"] == "fast_combined"
    assert kinds["34_disturbed_attached_magnet_3cm"] == "attached_magnet"
    assert kinds["26_disturbed_phone_vibration_A"] == "vibration"
    assert len(set(kinds.values())) == 9


def test_trial_kind_fallbacks():
    cats = {"disturbed": "", "tapping": "disturbance", "slow": "speed", "rotation": "motion"}
    assert broad.trial_kind(("all_trials", "disturbed", "tapping"), cats) == "tapping"
    assert broad.trial_kind(("all_trials", "rotation", "slow"), cats) == "slow_rotation"
    assert broad.trial_kind(("all_trials", "outdoor"), cats) == "outdoor"
    assert broad.trial_kind(("all_trials",), cats) == "ungrouped"


@pytest.fixture(scope="module")
def slices(broad_folder, tmp_path_factory) -> Path:
    """Three 7 s BROAD slices of three kinds with their trials.json."""
    return write_broad_slices(broad_folder, tmp_path_factory.mktemp("group_slices"),
                              ["01_undisturbed_slow_rotation_A", "06_undisturbed_fast_rotation_A",
                               "32_disturbed_attached_magnet_1cm"])


@pytest.mark.parametrize("spelling", [["--cv", "group"], ["--cv=group"], ["--cv-by", "group"]])
def test_cli_tune_cv_group_matches_a_hand_selection(slices, tmp_path, spelling):
    out = tmp_path / "cv.json"
    args = ["tune", str(slices), "-m", "gradient", "-g", "beta=0.005,0.1", *spelling,
            "--workers", "1", "--json", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "leave-one-group-out (3 groups)" in " ".join(result.output.split())
    got = json.loads(out.read_text())
    recs = [(io.read(t.path), tuple(t.groups)) for t in io.broad_trials(slices)]
    direct = [evaluate_all(methods.create("gradient", {"beta": b}), recs) for b in (0.005, 0.1)]
    total = np.array([[t.total_rmse_deg for t in s.trials] for s in direct])
    # three trials of three kinds: leave-one-group-out is leave-one-trial-out here
    for j in range(3):
        means = total[:, [k for k in range(3) if k != j]].mean(axis=1)
        c = 0 if means[0] <= means[1] else 1
        assert got["cross_validated"]["trials"][recs[j][0].name]["chosen"] == (
            f"beta={(0.005, 0.1)[c]}"
        )
    assert [f["group"] for f in got["folds"]] == ["slow_rotation", "fast_rotation",
                                                  "attached_magnet"]
    assert got["leave_one_trial_out"]["mean"] == got["cross_validated"]["mean"]


def test_cli_cv_alone_stays_by_trial_and_bad_splits_are_refused(slices):
    base = ["tune", str(slices), "-m", "gradient", "-g", "beta=0.005,0.1", "--workers", "1"]
    result = CliRunner().invoke(app, [*base, "--cv"])
    assert result.exit_code == 0, result.output
    assert "leave-one-trial-out" in result.output and "leave-one-group-out" not in result.output
    bad = CliRunner().invoke(app, [*base, "--cv-by", "kind"])
    assert bad.exit_code != 0 and "--cv takes trial or group" in " ".join(bad.output.split())
    folds = CliRunner().invoke(app, [*base, "--cv", "group", "--folds", "2"])
    assert folds.exit_code != 0 and "--folds splits by trial" in " ".join(folds.output.split())


def test_cli_cv_group_needs_the_trials_groups(slices, tmp_path):
    plain = tmp_path / "plain"
    plain.mkdir()
    for f in slices.glob("*.hdf5"):
        (plain / f.name).symlink_to(f)
    args = ["tune", str(plain), "-m", "gradient", "-g", "beta=0.005,0.1", "--cv", "group",
            "--workers", "1"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code != 0
    assert "needs a folder of trials with trials.json" in " ".join(result.output.split())


def test_bench_broad_cv_group_prints_each_kind(broad_folder, tmp_path, monkeypatch):
    from margtrack.bench import grids

    index = json.loads((broad_folder / "trials.json").read_text())
    keep = ["02_undisturbed_slow_rotation_B", "28_disturbed_stationary_magnet_A",
            "30_disturbed_stationary_magnet_C"]
    index["trials"] = {n: index["trials"][n] for n in keep}
    folder = tmp_path / "broad"
    folder.mkdir()
    (folder / "trials.json").write_text(json.dumps(index))
    for name in keep:
        (folder / f"{name}.hdf5").symlink_to(broad_folder / f"{name}.hdf5")
    monkeypatch.setitem(grids.GRIDS, "gradient", {"beta": grids.GridParam((0.005, 0.025), "t")})
    result = CliRunner().invoke(app, [
        "bench", "broad", str(folder), "-m", "gradient", "--external", "", "--workers", "1",
        "--out", str(tmp_path / "b.png"), "--cv", "group",
    ])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "leave-one-group-out (2 groups)" in text and "leave-one-trial-out" in text
    recs = [(io.read_broad(folder / f"{n}.hdf5"), tuple(index["trials"][n]["groups"]))
            for n in keep]
    kinds = {r.name: k for (r, _), k in zip(recs, ["slow_rotation", "stationary_magnet",
                                                  "stationary_magnet"], strict=True)}
    expect = cv.cross_validate("gradient", {"beta": [0.005, 0.025]}, recs, kinds=kinds)
    for fold in expect.folds:  # one row per held-out kind, with its held-out total
        row = next(r for r in result.output.splitlines() if f"{fold.kind} ({len(fold.held_out)})"
                   in r)
        cells = [c.strip() for c in row.split("│")[1:-1]]
        assert float(cells[1]) == pytest.approx(fold.train_total_deg, abs=0.006)
        assert float(cells[2]) == pytest.approx(fold.held_out_total_deg, abs=0.006)
        assert f"without {fold.kind}: chose {fold.label}" in text
