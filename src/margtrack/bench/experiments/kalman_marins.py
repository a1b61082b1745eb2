"""001's experiments: convergence of Marins' EKF from a wrong initial state, and the cost of
its two measurement models.

- ``ekf-convergence`` (001 5.2, Figs. 7-8): ideal (noise-free) data of a body at rest,
  turned 120 deg about ``[1, 1, 1]`` from the earth frame, so the true quaternion is
  ``[0.5, 0.5, 0.5, 0.5]`` and the true rate 0. The filter (approach 2, default parameters)
  starts from 001's initial state, all seven components 1, and must reach the steady state
  ``[0, 0, 0, 0.5, 0.5, 0.5, 0.5]`` within 0.5 s at 100 Hz. Reading of 001: the data hold
  the body after the turn (001 gives no rate or duration for the turn itself, and a
  filter started from all ones converging "in less than half a second" fits a step).
  The initial quaternion ``[1, 1, 1, 1]`` has the true direction and twice the norm, so the
  orientation error comes from the initial rate of 1 rad/s per axis, which turns the
  prediction until the gyroscope measurement brings the rate to 0, and from the norm.
- ``ekf-approach-cost``: approach 1 (nine nonlinear outputs, 001 4.1) against approach 2
  (gyro + Gauss-Newton quaternion, ``H = I``, 4.3) on the same simulated motion in the same
  run: samples/s of each (001's argument for approach 2 is its lower cost) and accuracy.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.accuracy import error_series, summarize
from margtrack.bench.experiments import ExperimentResult
from margtrack.bench.speed import measure
from margtrack.methods.ekf import MarinsEkf, MarinsEkfParams

__all__ = ["EXPERIMENTS", "approach_cost", "convergence", "convergence_run"]

#: 001 5.2: the steady state [p, q, r, w, x, y, z] after 120 deg about [1, 1, 1]
STEADY_STATE = np.array([0.0, 0.0, 0.0, 0.5, 0.5, 0.5, 0.5])
#: 001 5.2: the initial state, all ones
INITIAL_STATE = np.ones(7)
#: initial rate (rad/s) and quaternion standard deviations of the covariance sweep
INIT_STDS = (1.0, 0.1, 0.03, 0.01)


def convergence_run(
    frame: str = "NED", rate_hz: float = 100.0, duration_s: float = 1.0,
    params: MarinsEkfParams | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """001 5.2's test: times (N,) s and the state (N, 7) ``[ω, q]`` after each sample.

    Row 0 is the initial state (all ones, as 001), later rows the state after each
    update (quaternion normalised). Ideal data in ``frame``; ``params`` default to the
    documented defaults (with ``frame``).
    """
    q_true = quat.from_axis_angle([1.0, 1.0, 1.0], np.radians(120.0))
    rec = sim.simulate(sim.static(duration_s, rate_hz, q0=q_true), frame=frame, seed=0)
    p = dataclasses.replace(params or MarinsEkfParams(), frame=frame)
    est = MarinsEkf(p)
    est.reset(INITIAL_STATE[3:])  # the initial covariance (init_*), then the state as 001's
    state = est.state
    for name, value in (("quat", INITIAL_STATE[3:]), ("gyr_est_rad_s", INITIAL_STATE[:3])):
        offset, width = MarinsEkf.state_layout[name]
        state.rows[:, offset : offset + width] = value
    est.state = state
    out = est.run(rec)
    state = np.concatenate([out.outputs["gyr_est_rad_s"], out.quat], axis=1)
    state[0] = INITIAL_STATE  # the first sample (dt = 0) outputs the initial state
    return rec.t, state


def _time_within(t: np.ndarray, err: np.ndarray, bound: float) -> float:
    """First time after which ``err`` stays <= bound (inf if it never does)."""
    outside = np.flatnonzero(err > bound)
    if outside.size == 0:
        return float(t[0])
    if outside[-1] == err.size - 1:
        return float("inf")
    return float(t[outside[-1] + 1])


def convergence(out_dir: Path, quick: bool) -> ExperimentResult:
    """001 5.2: from all ones to [0, 0, 0, 0.5, 0.5, 0.5, 0.5] within 0.5 s at 100 Hz."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    duration = 1.0 if quick else 2.0
    figures: dict[str, object] = {"rate_hz": 100.0, "tolerance": 1e-3}
    runs = {}
    for frame in ("NED", "ENU"):
        t, state = convergence_run(frame, 100.0, duration)
        runs[frame] = (t, state)
        err = np.abs(state - STEADY_STATE)
        key = frame.lower()
        figures[f"{key}_time_to_converge_s"] = _time_within(t, err.max(axis=1), 1e-3)
        figures[f"{key}_rate_time_to_converge_s"] = _time_within(t, err[:, :3].max(axis=1), 1e-3)
        figures[f"{key}_quat_time_to_converge_s"] = _time_within(t, err[:, 3:].max(axis=1), 1e-3)
        figures[f"{key}_max_error_after_0_5_s"] = float(err[t >= 0.5].max())
        figures[f"{key}_final_state"] = state[-1].round(6).tolist()
        angle = quat.angle_between(state[:, 3:] / np.linalg.norm(state[:, 3:], axis=1)[:, None],
                                   STEADY_STATE[3:])
        figures[f"{key}_max_orientation_error_deg"] = float(np.degrees(angle.max()))
    figures["converged_within_0_5_s"] = bool(
        max(figures["ned_time_to_converge_s"], figures["enu_time_to_converge_s"]) <= 0.5
    )
    # 001 gives no initial covariance: how the convergence time depends on it
    sweep = {}
    for std in INIT_STDS:
        p = MarinsEkfParams(init_rate_std_rad_s=std, init_quat_std=std)
        ts, st = convergence_run("NED", 100.0, 3.0, p)
        sweep[std] = (ts, np.abs(st - STEADY_STATE).max(axis=1))
    figures["time_to_converge_s_by_init_std"] = {
        std: _time_within(ts, err, 1e-3) for std, (ts, err) in sweep.items()
    }

    t, state = runs["NED"]
    fig, axes = plt.subplots(3, 1, figsize=(8, 9))
    for k, label in enumerate(("p", "q", "r")):
        axes[0].plot(t, state[:, k], label=label)
    axes[0].set_ylabel("angular rate (rad/s)")
    axes[0].set_title("001 Fig. 7: angular rates, ideal data, initial state all ones")
    axes[0].legend()
    for k, label in enumerate(("w (001's d)", "x (a)", "y (b)", "z (c)")):
        axes[1].plot(t, state[:, 3 + k], label=label)
    axes[1].axhline(0.5, color="k", lw=0.5, ls="--")
    axes[1].set_ylabel("quaternion component")
    axes[1].set_title("001 Fig. 8: quaternion components (steady state 0.5)")
    axes[1].legend()
    for std, (ts, err) in sweep.items():
        axes[2].semilogy(ts, err + 1e-12, label=f"initial std {std:g}")
    axes[2].axhline(1e-3, color="k", lw=0.5, ls="--")
    axes[2].set_ylabel("max |state - steady state|")
    axes[2].set_xlabel("time (s)")
    axes[2].set_title("the same run for several initial covariances (001 gives none)")
    axes[2].legend(fontsize=8)
    path = out_dir / "ekf_convergence.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    notes = (
        "the rates converge in one sample (the gyroscope measures them); the quaternion "
        "components converge as fast as the initial covariance lets the first updates "
        "follow the Gauss-Newton quaternion, then with the steady-state gain",
        "ideal data: body at rest after a 120 deg turn about [1, 1, 1] (quaternion "
        "[0.5, 0.5, 0.5, 0.5]), 100 Hz, no noise; the EKF (approach 2, default parameters) "
        "starts at 001's all-ones state with the default initial covariance",
        "time to converge: first time after which every state component stays within "
        "1e-3 of the steady state",
    )
    return ExperimentResult("ekf-convergence", figures, (path,), notes)


def approach_cost(out_dir: Path, quick: bool) -> ExperimentResult:
    """Approach 1 against approach 2 on one simulated motion: samples/s and accuracy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seconds = 20.0 if quick else 300.0
    rate_hz = 285.714  # BROAD's rate, where the defaults were tuned
    rec = sim.simulate(
        sim.random_motion(seconds, rate_hz, seed=5, max_rate_deg_s=200.0, bandwidth_hz=2.0,
                          translation_m=0.02),
        frame="ENU", gyr_errors=sim.SensorErrors.mems_gyr(),
        acc_errors=sim.SensorErrors.mems_acc(), mag_errors=sim.SensorErrors.mems_mag(), seed=5,
    )
    n = rec.n_samples
    figures: dict[str, object] = {"duration_s": seconds, "rate_hz": rate_hz, "n_samples": n}
    errors = {}
    speeds = {}
    for approach in (2, 1):
        p = MarinsEkfParams(approach=approach)
        est = MarinsEkf(p).run(rec)
        s = summarize(error_series(est.quat, rec.quat_true, "ENU", rec.frame))
        speed = measure(f"approach {approach}", lambda p=p: MarinsEkf(p).run(rec), n,
                        repeats=1 if quick else 3)
        key = f"approach{approach}"
        figures[f"{key}_samples_per_s"] = speed.samples_per_s
        figures[f"{key}_total_rmse_deg"] = s.total_rmse_deg
        figures[f"{key}_heading_rmse_deg"] = s.heading_rmse_deg
        figures[f"{key}_inclination_rmse_deg"] = s.inclination_rmse_deg
        figures[f"{key}_mean_gn_iterations"] = float(est.outputs["iterations"].mean())
        errors[approach] = np.degrees(quat.angle_between(est.quat, rec.quat_true))
        speeds[approach] = speed.samples_per_s
    figures["approach1_cost_relative_to_approach2"] = speeds[2] / speeds[1]

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), gridspec_kw={"width_ratios": [3, 1]})
    for approach, err in errors.items():
        axes[0].plot(rec.t, err, lw=0.6, label=f"approach {approach}")
    axes[0].set_xlabel("time (s)")
    axes[0].set_ylabel("orientation error (deg)")
    axes[0].set_title("simulated motion, MEMS sensor errors, 2 cm translation")
    axes[0].legend()
    axes[1].bar(["approach 2", "approach 1"], [speeds[2], speeds[1]])
    axes[1].set_ylabel("samples/s (1 sensor)")
    path = out_dir / "ekf_approach_cost.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    notes = (
        "both approaches share the prediction and the default parameters; approach 2 runs "
        "Gauss-Newton (capped iterations, from the prediction) and a 7-output update with "
        "H = I, approach 1 evaluates the nine outputs, their 9x7 Jacobian and a 9-output "
        "update",
        "cost relative to approach 2 = samples/s of approach 2 / samples/s of approach 1, "
        "measured in the same run on the same data",
    )
    return ExperimentResult("ekf-approach-cost", figures, (path,), notes)


EXPERIMENTS = {"ekf-convergence": convergence, "ekf-approach-cost": approach_cost}
