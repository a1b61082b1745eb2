"""000's experiments with the Bachmann filter, on a simulated MEMS-grade MARG sensor.

Each function ``(out_dir, quick) -> ExperimentResult`` writes one PNG. The sensor is
:meth:`SensorErrors.mems_gyr` (bias and bias random walk uncompensated, as in 000) with an
accelerometer and magnetometer "after calibration" (000 eqs. 1-5): their noise,
quantization and range kept, bias, scale and misalignment removed. The filter's field
reference uses the simulated dip, as a calibration would measure it; the magnetometer
weight is 1 (000's equal weighting) except where ρ is the subject.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.bench.experiments import ExperimentResult
from margtrack.methods.bachmann import Bachmann, BachmannAccMag
from margtrack.recording import Recording

__all__ = ["EXPERIMENTS"]

DIP = sim.DEFAULT_DIP_DEG
Q_REST = quat.from_euler([0.6, 0.15, -0.25])  # an arbitrary resting orientation


def _calibrated(errors: sim.SensorErrors) -> sim.SensorErrors:
    return dataclasses.replace(
        errors, bias=(0.0, 0.0, 0.0), scale=(0.0, 0.0, 0.0), misalignment_deg=(0.0, 0.0, 0.0)
    )


def _simulate(trajectory: sim.Trajectory, seed: int = 0, **kwargs) -> Recording:
    return sim.simulate(
        trajectory,
        dip_deg=DIP,
        gyr_errors=sim.SensorErrors.mems_gyr(),
        acc_errors=_calibrated(sim.SensorErrors.mems_acc()),
        mag_errors=_calibrated(sim.SensorErrors.mems_mag()),
        seed=seed,
        **kwargs,
    )


def _bachmann(cls: type[Bachmann] = Bachmann, **params) -> Bachmann:
    return cls(**{"mag_dip_ref_deg": DIP, "mag_weight": 1.0, **params})


def _figure(out_dir: Path, name: str, draw: Callable) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    draw(axes)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    path = Path(out_dir) / f"{name}.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _angle_deg(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    return np.degrees(quat.angle_between(p, q))


def static_convergence(out_dir: Path, quick: bool) -> ExperimentResult:
    """000 eq. 12 / Fig. 7: a stable estimate turned by 30 deg re-converges; φ and e² reach
    37 % at t = 1/(2k). Measured against a twin filter that was not disturbed."""
    gains = (4.0, 32.0) if quick else (1.0, 4.0, 8.0, 16.0, 32.0)
    rate_hz, settle_s = 1000.0, 2.0
    rec = _simulate(sim.static(settle_s + 2.5, rate_hz, q0=Q_REST), seed=1)
    cut = int(settle_s * rate_hz)
    error = quat.from_axis_angle([1.0, -1.0, 0.5], np.radians(30.0))
    figures: dict[str, float] = {}
    curves = []
    for k in gains:
        twin, hit = _bachmann(gain=k), _bachmann(gain=k)
        twin.run(rec.slice(0, cut))
        hit.state = twin.state
        state = hit.state
        offset, _ = Bachmann.state_layout["quat"]  # rotate the stable estimate by 30 deg
        state.rows[:, offset : offset + 4] = quat.multiply(state.get("quat"), error)
        hit.state = state
        rest = rec.slice(cut, rec.n_samples)
        a, b = hit.run(rest), twin.run(rest)
        t = rest.t - rest.t[0] + 1.0 / rate_hz
        e2 = _angle_deg(a.quat, b.quat) ** 2
        phi = a.outputs["phi"] - np.median(b.outputs["phi"])
        t_e2 = float(t[np.argmax(e2 < np.exp(-1) * e2[0])])
        t_phi = float(t[np.argmax(phi < np.exp(-1) * phi[0])])
        predicted = 1.0 / (2.0 * k)
        figures[f"k={k:g} predicted_s"] = predicted
        figures[f"k={k:g} measured_e2_s"] = t_e2
        figures[f"k={k:g} measured_phi_s"] = t_phi
        figures[f"k={k:g} ratio_e2"] = t_e2 / predicted
        curves.append((k, t, a.outputs["phi"], e2))

    def draw(axes):
        for k, t, phi, e2 in curves:
            axes[0].semilogy(t, phi, label=f"k = {k:g}")
            axes[1].plot(t * 2 * k, e2 / e2[0], label=f"k = {k:g}")
        axes[0].set(
            xlabel="time after the 30° error (s)",
            ylabel="criterion φ (eq. 19)",
            xlim=(0, 2.5),
            title="Fig. 7: convergence after a 30° error",
        )
        axes[1].axhline(np.exp(-1), color="k", lw=0.8, ls=":")
        axes[1].axvline(1.0, color="k", lw=0.8, ls=":")
        axes[1].set(
            xlabel="t · 2k",
            ylabel="squared error / initial",
            xlim=(0, 3),
            title="37 % at t = 1/(2k) (eq. 12)",
        )
        axes[0].legend()

    plot = _figure(out_dir, "static-convergence", draw)
    notes = ("ratio = measured / predicted time to 37 % of the squared error; 000 expects 1.",)
    return ExperimentResult("static-convergence", figures, (plot,), notes)


def magnetic_disturbance(out_dir: Path, quick: bool) -> ExperimentResult:
    """000 Fig. 9: a magnet passes a static sensor (k = 4); the rms change of the estimate
    during the exposure shrinks with the magnetometer weight ρ."""
    rate_hz = 100.0
    rec = _simulate(
        sim.static(8.0, rate_hz, q0=Q_REST),
        seed=2,
        mag_disturbances=[sim.magnet_pass(4.0, 1.0, 60.0, (1.0, 0.6, -0.4))],
    )
    exposed = (rec.t > 3.5) & (rec.t < 4.5)
    before = np.flatnonzero(rec.t <= 3.5)[-1]
    figures, series = {}, []
    for rho in (1.0, 0.5, 0.25):
        q = _bachmann(gain=4.0, mag_weight=rho).run(rec).quat
        change = _angle_deg(q, q[before])
        figures[f"rho={rho:g} rms_change_deg"] = float(np.sqrt(np.mean(change[exposed] ** 2)))
        figures[f"rho={rho:g} max_change_deg"] = float(change[exposed].max())
        series.append((rho, change))

    def draw(axes):
        for rho, change in series:
            axes[0].plot(rec.t, change, label=f"ρ = {rho:g}")
        axes[0].axvspan(3.5, 4.5, color="0.9")
        axes[0].set(
            xlabel="time (s)",
            ylabel="change of estimate (deg)",
            title="a 60 µT magnet passing in 1 s, k = 4",
        )
        axes[0].legend()
        rhos = [r for r, _ in series]
        axes[1].bar([str(r) for r in rhos], [figures[f"rho={r:g} rms_change_deg"] for r in rhos])
        axes[1].set(xlabel="ρ", ylabel="rms change during exposure (deg)", title="Fig. 9")

    plot = _figure(out_dir, "magnetic-disturbance", draw)
    return ExperimentResult("magnetic-disturbance", figures, (plot,))


def dynamic_accuracy(out_dir: Path, quick: bool) -> ExperimentResult:
    """000 Fig. 8: 0-45 deg roll excursions at 10 deg/s with 15 s holds, tracked within 1 deg."""
    roll = (1.0, 0.0, 0.0)
    cycle = [
        sim.Rotate(roll, 45.0, 10.0),
        sim.Hold(15.0),
        sim.Rotate(roll, -45.0, 10.0),
        sim.Hold(15.0),
    ]
    steps = [sim.Hold(5.0)] + cycle * (1 if quick else 3)
    rec = _simulate(sim.rotation_sequence(steps, 100.0), seed=3, frame="NED")
    est = _bachmann(gain=1.0, frame="NED").run(rec)
    roll_est, roll_true = quat.to_euler(est.quat)[:, 2], quat.to_euler(rec.quat_true)[:, 2]
    roll_error = np.degrees(roll_est - roll_true)
    total = _angle_deg(est.quat, rec.quat_true)
    after = rec.t >= 5.0  # after the initial settling
    figures = {
        "roll_error_max_deg": float(np.abs(roll_error[after]).max()),
        "roll_error_rms_deg": float(np.sqrt(np.mean(roll_error[after] ** 2))),
        "total_error_max_deg": float(total[after].max()),
        "total_error_rms_deg": float(np.sqrt(np.mean(total[after] ** 2))),
    }

    def draw(axes):
        axes[0].plot(rec.t, np.degrees(roll_true), "k", lw=2, label="table")
        axes[0].plot(rec.t, np.degrees(roll_est), "C1", label="estimate (k = 1)")
        axes[0].set(xlabel="time (s)", ylabel="roll (deg)", title="Fig. 8: 45° roll excursions")
        axes[0].legend()
        axes[1].plot(rec.t, roll_error, label="roll")
        axes[1].plot(rec.t, total, label="total")
        axes[1].set(xlabel="time (s)", ylabel="error (deg)", title="tracking error")
        axes[1].legend()

    plot = _figure(out_dir, "dynamic-accuracy", draw)
    return ExperimentResult("dynamic-accuracy", figures, (plot,), ("000: within one degree.",))


def static_stability(out_dir: Path, quick: bool) -> ExperimentResult:
    """000 Fig. 6: an hour at rest with gyro bias and bias random walk, k = 1 and k = 4; the
    bias-driven error with k = 4 should be about a quarter of k = 1's.

    Run on the raw gyro (``gyr_null_rest_s = 0``), as 000's test was (its rate sensors had
    no working bias compensation); the figure ``k=1 drift_error_deg_with_rest_null`` shows
    what the default initial-rest null leaves (only the bias random walk).
    """
    duration_s, block_s = (120.0, 10.0) if quick else (3600.0, 60.0)
    rec = _simulate(sim.static(duration_s, 100.0, q0=Q_REST), seed=4)
    per_block = int(block_s * 100.0)

    def block_means(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Block means of the estimate ``q`` and their error, deg: block means average the
        noise out; what is left is the slow, bias-driven error."""
        n_blocks = q.shape[0] // per_block
        means = q[: n_blocks * per_block].reshape(n_blocks, per_block, 4).mean(axis=1)
        means = means[1:]  # the first block holds the start from TRIAD
        return means, _angle_deg(quat.normalize(means), Q_REST)

    figures, series = {}, []
    for k in (1.0, 4.0):
        q = quat.continuous(_bachmann(gain=k, gyr_null_rest_s=0.0).run(rec).quat)
        means, slow = block_means(q)
        drift = means.max(axis=0) - means.min(axis=0)
        for name, d in zip("wxyz", drift, strict=True):
            figures[f"k={k:g} drift_{name}"] = float(d)
        figures[f"k={k:g} drift_error_deg"] = float(slow.mean())
        error = _angle_deg(q, rec.quat_true)
        figures[f"k={k:g} rms_error_deg"] = float(np.sqrt(np.mean(error[per_block:] ** 2)))
        series.append((k, means, slow))
    ratio = figures["k=1 drift_error_deg"] / figures["k=4 drift_error_deg"]
    figures["drift_error_ratio_k1_over_k4"] = ratio
    figures["k=1 drift_error_deg_with_rest_null"] = float(block_means(
        quat.continuous(_bachmann(gain=1.0).run(rec).quat)
    )[1].mean())

    def draw(axes):
        t_min = (np.arange(len(series[0][1])) + 1.5) * block_s / 60.0
        for (k, means, slow), style in zip(series, ("-", "--"), strict=True):
            for c, name in enumerate("wxyz"):
                axes[0].plot(
                    t_min,
                    means[:, c] - means[0, c],
                    style,
                    color=f"C{c}",
                    label=f"{name}, k = {k:g}",
                )
            axes[1].plot(t_min, slow, style, label=f"k = {k:g}")
        axes[0].set(
            xlabel="time (min)",
            ylabel=f"{block_s:g}-s mean - first one",
            title="Fig. 6: quaternion components at rest",
        )
        axes[0].legend(ncol=2, fontsize=7, loc="upper right")
        axes[1].set(
            xlabel="time (min)",
            ylabel="error of the block means (deg)",
            title="bias-driven error: about b / k",
            ylim=(0, None),
        )
        axes[1].legend(loc="upper right")

    plot = _figure(out_dir, "static-stability", draw)
    notes = (
        f"drift = max - min of the {block_s:g}-s means of each quaternion component, "
        "the first block (settling from the TRIAD start) left out.",
    )
    return ExperimentResult("static-stability", figures, (plot,), notes)


def reduced_drift_correction(out_dir: Path, quick: bool) -> ExperimentResult:
    """000 "Reduce Rate Drift Correction": 16 filters at 100 Hz (limb swings, k = 0.5), a new
    correction on every cycle vs one filter per cycle (round robin, about 6 Hz each)."""
    n_sensors, duration_s = 16, (10.0 if quick else 120.0)
    rng = np.random.default_rng(5)
    recs = []
    for s in range(n_sensors):
        heading = rng.uniform(0.0, 2.0 * np.pi)
        motion = sim.limb_swing(
            duration_s,
            100.0,
            amplitude_deg=rng.uniform(15.0, 40.0),
            frequency_hz=rng.uniform(0.3, 1.0),
            length_m=rng.uniform(0.25, 0.4),
            axis=(np.cos(heading), np.sin(heading), 0.0),
        )
        recs.append(_simulate(motion, seed=100 + s))
    truth = np.stack([r.quat_true for r in recs])
    every = _bachmann(gain=0.5)
    shared = _bachmann(gain=0.5, correction_interval=n_sensors, round_robin=True)
    timings = {}
    outputs = {}
    for label, est in (("every_cycle", every), ("round_robin", shared)):
        best = np.inf
        for _ in range(3):
            est.reset()
            start = time.perf_counter()
            outputs[label] = est.run(recs).quat
            best = min(best, time.perf_counter() - start)
        timings[label] = n_sensors * recs[0].n_samples / best
    diff = _angle_deg(outputs["every_cycle"], outputs["round_robin"])

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x**2)))

    figures = {
        "rms_difference_deg": rms(diff),
        "max_difference_deg": float(diff.max()),
        "every_cycle_rmse_deg": rms(_angle_deg(outputs["every_cycle"], truth)),
        "round_robin_rmse_deg": rms(_angle_deg(outputs["round_robin"], truth)),
        "every_cycle_samples_per_s": timings["every_cycle"],
        "round_robin_samples_per_s": timings["round_robin"],
        "speed_gain": timings["round_robin"] / timings["every_cycle"],
    }

    def draw(axes):
        t = recs[0].t
        axes[0].plot(t, diff.T, lw=0.5)
        axes[0].set(
            xlabel="time (s)",
            ylabel="every cycle vs round robin (deg)",
            title="16 limb-swing filters at 100 Hz, k = 0.5",
        )
        axes[1].bar(
            ["every cycle", "round robin"],
            [figures["every_cycle_rmse_deg"], figures["round_robin_rmse_deg"]],
        )
        axes[1].set(ylabel="RMSE against the truth (deg)", title="accuracy")

    plot = _figure(out_dir, "reduced-drift-correction", draw)
    return ExperimentResult("reduced-drift-correction", figures, (plot,))


def _quick_raise(
    rate_hz: float, angle_deg: float, move_s: float, length_m: float
) -> sim.Trajectory:
    """A forearm raised about the elbow from horizontal to vertical (minimum-jerk profile):
    the sensor ends above the pivot, so deceleration tilts apparent gravity forwards."""
    t = np.arange(0.0, 1.0 + move_s + 4.0, 1.0 / rate_hz)
    tau = np.clip((t - 1.0) / move_s, 0.0, 1.0)
    total = np.radians(angle_deg)
    theta = total * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
    theta_dot = total * (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / move_s
    theta_ddot = total * (60 * tau - 180 * tau**2 + 120 * tau**3) / move_s**2
    axis = np.array([1.0, 0.0, 0.0])
    q = quat.from_rotvec(axis * theta[:, None])
    pos = quat.rotate(q, [0.0, length_m, 0.0])  # starts forward (ENU y), ends up
    acc = theta_ddot[:, None] * np.cross(axis, pos) - (theta_dot**2)[:, None] * pos
    return sim.Trajectory(t, q, pos, acc, "quick_raise", {"angle_deg": angle_deg})


def acc_mag_overshoot(out_dir: Path, quick: bool) -> ExperimentResult:
    """000 "Accelerometer/Magnetometer Only Tracking": without a gyro, raising the gain
    makes quick motions trackable but overshoots at their end (linear acceleration)."""
    gains = (4.0, 32.0) if quick else (1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)
    rate_hz, angle_deg, move_s = 400.0, 90.0, 0.6
    rec = _simulate(_quick_raise(rate_hz, angle_deg, move_s, 0.3), seed=6)
    t_end = 1.0 + move_s
    figures, series = {}, []
    truth = np.degrees(quat.to_rotvec(rec.quat_true)[:, 0])
    for k in gains:
        for label, cls in (("accmag", BachmannAccMag), ("marg", Bachmann)):
            q = _bachmann(cls, gain=k).run(rec).quat
            angle = np.degrees(quat.to_rotvec(q)[:, 0])  # about the motion axis, from the start
            peak = int(np.argmax(angle))
            figures[f"k={k:g} {label}_overshoot_deg"] = max(0.0, float(angle[peak]) - angle_deg)
            if label == "accmag":
                figures[f"k={k:g} accmag_peak_after_end_s"] = float(rec.t[peak] - t_end)
                figures[f"k={k:g} accmag_max_lag_deg"] = float(np.abs(angle - truth).max())
                series.append((k, angle))

    def draw(axes):
        axes[0].plot(rec.t, truth, "k", lw=2, label="truth")
        for k, angle in series:
            axes[0].plot(rec.t, angle, label=f"k = {k:g}")
        axes[0].set(
            xlabel="time (s)",
            ylabel="angle (deg)",
            xlim=(0.8, 3.5),
            title=f"acc/mag only: 90° in {move_s:g} s, sensor 0.3 m from the elbow",
        )
        axes[0].legend(fontsize=7)
        for label in ("accmag", "marg"):
            axes[1].plot(
                gains,
                [figures[f"k={k:g} {label}_overshoot_deg"] for k in gains],
                "o-",
                label="acc/mag only" if label == "accmag" else "with gyro",
            )
        axes[1].set(
            xscale="log",
            xlabel="gain k (1/s)",
            ylabel="overshoot (deg)",
            title="largest angle beyond the final 90°",
        )
        axes[1].legend()

    plot = _figure(out_dir, "acc-mag-overshoot", draw)
    notes = (
        "overshoot = largest estimated angle beyond the final one; peak time is relative "
        "to the end of the motion (negative: during the final deceleration).",
    )
    return ExperimentResult("acc-mag-overshoot", figures, (plot,), notes)


EXPERIMENTS: dict[str, Callable[[Path, bool], ExperimentResult]] = {
    "static-convergence": static_convergence,
    "magnetic-disturbance": magnetic_disturbance,
    "dynamic-accuracy": dynamic_accuracy,
    "static-stability": static_stability,
    "reduced-drift-correction": reduced_drift_correction,
    "acc-mag-overshoot": acc_mag_overshoot,
}
