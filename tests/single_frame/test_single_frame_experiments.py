"""The single-frame experiments run quickly and reproduce what 001 and 002 report."""

from __future__ import annotations

import pytest

from margtrack.bench.experiments.single_frame import EXPERIMENTS


def test_the_four_experiments_are_registered_by_name():
    assert set(EXPERIMENTS) == {
        "decoupling", "singularity", "gauss-newton-convergence", "single-frame-speed"}


def test_decoupling_fqa_and_triad_keep_pitch_and_roll_quest_does_not(tmp_path):
    result = EXPERIMENTS["decoupling"](tmp_path, True)
    f = result.figures
    for name in ("fqa", "triad"):
        assert f[f"{name} max_pitch_error_deg"] < 1e-6
        assert f[f"{name} max_roll_error_deg"] < 1e-6
        assert f[f"{name} max_yaw_error_deg"] > 10.0  # the disturbance went to the heading
    for name in ("quest", "davenport"):
        assert max(f[f"{name} max_pitch_error_deg"], f[f"{name} max_roll_error_deg"]) > 5.0
    assert all(p.is_file() for p in result.plots)


def test_singularity_flag_matches_cos_pitch_and_no_jumps(tmp_path):
    f = EXPERIMENTS["singularity"](tmp_path, True).figures
    keys = {k.rsplit(" ", 1)[0] for k in f}
    assert len(keys) == 8
    for key in keys:
        assert f[f"{key} flag_mismatches"] == 0
        assert f[f"{key} switched_samples"] > 0
        assert f[f"{key} max_diff_to_triad_deg"] < 1e-9
        if " ideal " in key:
            assert f[f"{key} max_step_switched_deg"] == pytest.approx(
                f[f"{key} max_true_step_deg"], abs=1e-9)
            assert f[f"{key} max_error_deg"] < 1e-9
        else:  # with noise the steps while switched are like those elsewhere
            assert f[f"{key} max_step_switched_deg"] < 2.0 * f[f"{key} max_step_elsewhere_deg"]


def test_gauss_newton_converges_within_four_iterations_and_one_suffices_when_tracking(tmp_path):
    f = EXPERIMENTS["gauss-newton-convergence"](tmp_path, True).figures
    assert f["gauss-newton fraction_converged"] == 1.0
    assert f["gauss-newton fraction_within_4_iterations"] >= 0.95
    assert sum(f["gauss-newton iterations_histogram"].values()) == f["cases"]
    # 001's "3 or 4 steps" holds for guesses around the truth, for both methods
    for label in ("gauss-newton", "newton"):
        for low_high in ("0_30", "30_60"):
            assert f[f"{label} within_4_iterations_guess_{low_high}_deg"] >= 0.99
    # far off, Newton's indefinite Hessian costs it steps that Gauss-Newton does not need
    assert f["newton within_4_iterations_guess_60_90_deg"] < 0.5
    assert f["gauss-newton within_4_iterations_guess_60_90_deg"] > 0.8
    assert f["tracking one_iteration_vs_converged_rms_deg"] < (
        0.25 * f["tracking converged_vs_truth_rms_deg"])


def test_speed_experiment_reports_rates_and_ratios(tmp_path):
    result = EXPERIMENTS["single-frame-speed"](tmp_path, True)
    rates = {k: v for k, v in result.figures.items() if k.endswith("samples_per_s")}
    assert {"triad", "fqa", "quest", "davenport", "gauss-newton", "newton"} <= {
        k.split(" ")[0] for k in rates}
    assert all(v > 0 for v in rates.values())
    # both of 002's comparisons are reported: against the closed form and the paper's QUEST
    for key in ("fqa / quest, kernels alone", "fqa / quest-newton, kernels alone",
                "fqa / quest-newton (002: 1.25 in MATLAB)"):
        assert result.figures[key] > 0
    assert result.plots[0].is_file()
