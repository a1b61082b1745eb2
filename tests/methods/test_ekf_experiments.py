"""001's experiments (quick mode): ekf-convergence and ekf-approach-cost."""

from __future__ import annotations

import numpy as np

from margtrack.bench.experiments import kalman_marins


def test_convergence_experiment_quick(tmp_path):
    res = kalman_marins.EXPERIMENTS["ekf-convergence"](tmp_path, True)
    f = res.figures
    assert res.name == "ekf-convergence"
    assert all(p.is_file() and p.stat().st_size > 10_000 for p in res.plots)
    # 001 5.2: steady state within half a second at 100 Hz, the same in both frames
    assert f["converged_within_0_5_s"]
    for frame in ("ned", "enu"):
        assert 0.0 < f[f"{frame}_time_to_converge_s"] <= 0.5
        assert f[f"{frame}_max_error_after_0_5_s"] < 1e-3
        np.testing.assert_allclose(f[f"{frame}_final_state"], kalman_marins.STEADY_STATE,
                                   atol=1e-3)
    assert f["ned_time_to_converge_s"] == f["enu_time_to_converge_s"]
    # 001 gives no initial covariance: a more confident wrong start converges more slowly
    times = [f["time_to_converge_s_by_init_std"][s] for s in kalman_marins.INIT_STDS]
    assert times == sorted(times) and times[0] < times[-1]


def test_approach_cost_experiment_quick(tmp_path):
    res = kalman_marins.EXPERIMENTS["ekf-approach-cost"](tmp_path, True)
    f = res.figures
    assert all(p.is_file() and p.stat().st_size > 10_000 for p in res.plots)
    # both approaches beat their inputs alone on this motion (MEMS errors, 2 cm
    # translation): gyro integration 5.3 deg, the Gauss-Newton fit 3.8 deg (same data)
    for a in (1, 2):
        assert f[f"approach{a}_total_rmse_deg"] < 3.0
        assert f[f"approach{a}_samples_per_s"] > 0.0
    assert f["approach2_mean_gn_iterations"] >= 1.0
    assert f["approach1_mean_gn_iterations"] == 0.0
    ratio = f["approach2_samples_per_s"] / f["approach1_samples_per_s"]
    assert f["approach1_cost_relative_to_approach2"] == ratio
