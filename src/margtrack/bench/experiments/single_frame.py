"""002's and 001's experiments with the single-frame estimators, on simulated data.

- ``decoupling`` (002 III-C, Figs. 9-10): a level static sensor while a ferrous object turns
  the field by 360 deg; FQA and TRIAD keep pitch and roll, QUEST and Davenport do not.
- ``singularity`` (002 Figs. 1-3, 7-8): 180 and 110 deg pitch rotations through ±90 deg.
- ``gauss-newton-convergence`` (001 5.1): iterations to a criterion of 1e-10 from guesses
  up to 90 deg off, and one iteration while tracking at 100 Hz.
- ``single-frame-speed`` (002 III-D): samples/s of every estimator and of ``ahrs``.

Each function ``(out_dir, quick) -> ExperimentResult`` writes one PNG; ``quick`` shortens it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from margtrack import frames, sim
from margtrack import quaternion as quat
from margtrack.bench.experiments import ExperimentResult
from margtrack.recording import Recording
from margtrack.single_frame.davenport import Davenport
from margtrack.single_frame.fqa import Fqa
from margtrack.single_frame.gauss_newton import GaussNewton, Newton
from margtrack.single_frame.gauss_newton_kernel import gauss_newton_solve, newton_solve
from margtrack.single_frame.quest import Quest
from margtrack.single_frame.triad import Triad

__all__ = ["ESTIMATORS", "EXPERIMENTS", "speed_table"]

DIP = sim.DEFAULT_DIP_DEG
ESTIMATORS = (Triad, Fqa, Quest, Davenport, GaussNewton, Newton)


def _figure(out_dir: Path, name: str, rows: int, cols: int, draw: Callable) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.6 * rows), squeeze=False,
                             constrained_layout=True)
    draw(axes)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    path = Path(out_dir) / f"{name}.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def decoupling(out_dir: Path, quick: bool) -> ExperimentResult:
    """002 III-C: static level sensor (NED, x north), the field turned 360 deg about an
    earth axis (1, 1, 1) so its direction changes on every body axis, noise-free. Pitch
    and roll errors of FQA/TRIAD should stay at rounding (< 1e-6 deg)."""
    rate_hz, duration = (50.0, 12.0) if quick else (100.0, 40.0)
    turn = sim.rotating_field(2.0, 360.0 / (duration - 4.0), 360.0, axis=(1.0, 1.0, 1.0))
    rec = sim.simulate(sim.static(duration, rate_hz), frame="NED", dip_deg=DIP,
                       mag_disturbances=[turn])
    truth = np.degrees(quat.to_euler(rec.quat_true))
    figures: dict[str, float] = {}
    curves = {}
    for cls in (Fqa, Triad, Quest, Davenport):
        est = cls(frame="NED").run(rec)
        error = np.degrees(quat.to_euler(est.quat)) - truth
        error = (error + 180.0) % 360.0 - 180.0
        figures[f"{cls.name} max_pitch_error_deg"] = float(np.abs(error[:, 1]).max())
        figures[f"{cls.name} max_roll_error_deg"] = float(np.abs(error[:, 2]).max())
        figures[f"{cls.name} max_yaw_error_deg"] = float(np.abs(error[:, 0]).max())
        curves[cls.name] = error

    def draw(axes):
        axes[0, 0].plot(rec.t, rec.mag / np.linalg.norm(rec.mag, axis=1)[:, None])
        axes[0, 0].set(title="Fig. 9: normalised field (body)", xlabel="t (s)")
        for col, (label, k) in enumerate((("yaw", 0), ("pitch", 1), ("roll", 2)), start=1):
            for name, err in curves.items():
                axes[0, col].plot(rec.t, err[:, k], label=name)
            axes[0, col].set(title=f"Fig. 10: {label} error (deg)", xlabel="t (s)")
        axes[0, 1].legend(fontsize=7)

    plot = _figure(out_dir, "decoupling", 1, 4, draw)
    notes = ("002: QUEST errs on every axis, FQA only in azimuth.",)
    return ExperimentResult("decoupling", figures, (plot,), notes)


def _calibrated_errors() -> tuple[sim.SensorErrors, sim.SensorErrors]:
    """MEMS accelerometer and magnetometer after calibration: noise and quantization only."""
    def keep_noise(e: sim.SensorErrors) -> sim.SensorErrors:
        return dataclasses.replace(e, bias=(0.0, 0.0, 0.0), scale=(0.0, 0.0, 0.0),
                                   misalignment_deg=(0.0, 0.0, 0.0))

    return keep_noise(sim.SensorErrors.mems_acc()), keep_noise(sim.SensorErrors.mems_mag())


def _pitch_runs(quick: bool) -> dict[str, sim.Trajectory]:
    rate = 50.0 if quick else 200.0
    pitch = (0.0, 1.0, 0.0)  # east in NED: the body y axis of a level sensor facing north
    seq110 = [sim.Hold(1.0), sim.Rotate(pitch, 110.0, 40.0), sim.Hold(1.0),
              sim.Rotate(pitch, -110.0, 40.0)] * (1 if quick else 2)
    return {
        "180deg": sim.rotation_sequence(
            [sim.Hold(1.0), sim.Rotate(pitch, 180.0, 30.0), sim.Hold(1.0)], rate),
        "110deg": sim.rotation_sequence([*seq110, sim.Hold(1.0)], rate),
    }


def singularity(out_dir: Path, quick: bool) -> ExperimentResult:
    """002 Figs. 1-3 and 7-8: FQA through pitch ±90 deg, noise-free and noisy (calibrated
    MEMS: noise and quantization), with
    (epsilon, alpha) = (0.1, 20 deg) and (0.2, 45 deg). Reports the largest step of the
    estimate while switched and elsewhere against the largest true step, the largest
    difference to TRIAD (which has no singularity: FQA equals it wherever it has none
    either), the error, and switch-flag mismatches with ``cos θ < epsilon`` computed from
    the measured accelerometer."""
    figures: dict[str, Any] = {}
    shown = None
    for motion, traj in _pitch_runs(quick).items():
        for noisy in (False, True):
            errors = _calibrated_errors() if noisy else (None, None)
            rec = sim.simulate(traj, frame="NED", dip_deg=DIP, acc_errors=errors[0],
                               mag_errors=errors[1], seed=3)
            triad = Triad(frame="NED").run(rec).quat
            acc = rec.acc / np.linalg.norm(rec.acc, axis=1)[:, None]
            cos_t = np.hypot(acc[:, 1], acc[:, 2])
            true_step = np.degrees(quat.angle_between(rec.quat_true[1:], rec.quat_true[:-1]))
            for eps, alpha in ((0.1, 20.0), (0.2, 45.0)):
                est = Fqa(frame="NED", epsilon=eps, alpha_deg=alpha).run(rec)
                step = np.degrees(quat.angle_between(est.quat[1:], est.quat[:-1]))
                key = f"{motion} {'noisy' if noisy else 'ideal'} eps={eps} alpha={alpha:g}"
                switched = est.outputs["switched"]
                near = switched[1:] | switched[:-1]
                figures[f"{key} max_step_switched_deg"] = float(step[near].max())
                figures[f"{key} max_step_elsewhere_deg"] = float(step[~near].max())
                figures[f"{key} max_true_step_deg"] = float(true_step.max())
                figures[f"{key} max_diff_to_triad_deg"] = float(
                    np.degrees(quat.angle_between(est.quat, triad)).max())
                figures[f"{key} max_error_deg"] = float(
                    np.degrees(quat.angle_between(est.quat, rec.quat_true)).max())
                figures[f"{key} switched_samples"] = int(switched.sum())
                figures[f"{key} flag_mismatches"] = int(np.sum(switched != (cos_t < eps)))
                if motion == "180deg" and noisy and eps == 0.1:
                    shown = (rec, est, cos_t, eps)

    def draw(axes):
        rec, est, cos_t, eps = shown
        euler = np.degrees(quat.to_euler(est.quat))
        for k, label in enumerate(("yaw", "pitch", "roll")):
            axes[0, 0].plot(rec.t, euler[:, k], label=label)
        axes[0, 0].set(title="Fig. 2: angles (deg), 180° pitch, noisy", xlabel="t (s)")
        axes[0, 0].legend(fontsize=7)
        axes[0, 1].plot(rec.t, cos_t, label="cos θ")
        axes[0, 1].plot(rec.t, est.outputs["switched"], label="switch flag")
        axes[0, 1].axhline(eps, color="k", lw=0.7, ls=":")
        axes[0, 1].set(title=f"cos θ and switch (ε = {eps})", xlabel="t (s)")
        axes[0, 1].legend(fontsize=7)
        axes[0, 2].plot(rec.t, quat.continuous(est.quat))
        axes[0, 2].set(title="Fig. 3: quaternion (made sign-continuous)", xlabel="t (s)")

    plot = _figure(out_dir, "singularity", 1, 3, draw)
    notes = ("steps while switched should be no larger than elsewhere (noise) and equal "
             "the true steps without noise; flag_mismatches must be 0.",)
    return ExperimentResult("singularity", figures, (plot,), notes)


GUESS_BINS_DEG = ((0, 30), (30, 60), (60, 90))


def _random_guesses(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    q_true = quat.normalize(rng.normal(size=(n, 4)))
    axis = rng.normal(size=(n, 3))
    angle = rng.uniform(0.0, 0.5 * np.pi, n)
    return q_true, quat.multiply(quat.from_axis_angle(axis, angle), q_true)


def gauss_newton_convergence(out_dir: Path, quick: bool) -> ExperimentResult:
    """001 5.1: noise-free, random true orientations and initial guesses up to 90 deg off:
    iterations until the criterion is <= 1e-10 (kernel-level solvers, no restart); then
    Gauss-Newton with one iteration per sample from the previous estimate on a noisy
    100 Hz motion, against the converged fit and the truth."""
    n_cases = 500 if quick else 10_000
    q_true, guess = _random_guesses(n_cases, seed=11)
    off_deg = np.degrees(quat.angle_between(q_true, guess))
    up = frames.up("NED")
    field = frames.mag_reference("NED", DIP)
    acc = quat.rotate_inverse(q_true, up)
    mag = quat.rotate_inverse(q_true, field)
    figures: dict[str, Any] = {}
    counts = {}
    for label, solve in (("gauss-newton", gauss_newton_solve), ("newton", newton_solve)):
        its = np.empty(n_cases, dtype=int)
        crit = np.empty(n_cases)
        for i in range(n_cases):
            _, _, _, _, _, its[i], crit[i] = solve(*acc[i], *mag[i], *up, *field, *guess[i],
                                                   1.0, 1e-10, 20)
        reached = crit <= 1e-10
        counts[label] = np.bincount(its[reached], minlength=8)
        figures[f"{label} iterations_histogram"] = {
            int(k): int(v) for k, v in enumerate(np.bincount(its[reached])) if v}
        figures[f"{label} fraction_within_4_iterations"] = float(np.mean(reached & (its <= 4)))
        figures[f"{label} fraction_converged"] = float(np.mean(reached))
        # 001 5.1 draws its guesses "around the real value": split by how far off they start
        for low, high in GUESS_BINS_DEG:
            inside = (off_deg >= low) & (off_deg < high)
            figures[f"{label} within_4_iterations_guess_{low}_{high}_deg"] = float(
                np.mean(reached[inside] & (its[inside] <= 4)))
    figures["cases"] = n_cases

    duration = 10.0 if quick else 60.0
    acc_errors, mag_errors = _calibrated_errors()
    rec = sim.simulate(sim.random_motion(duration, 100.0, seed=4), frame="NED", dip_deg=DIP,
                       acc_errors=acc_errors, mag_errors=mag_errors, seed=4)
    one = GaussNewton(frame="NED", max_iterations=1).run(rec)
    full = GaussNewton(frame="NED", tolerance=1e-16, max_iterations=50).run(rec)
    rms = lambda a, b: float(np.sqrt(np.mean(np.degrees(quat.angle_between(a, b)) ** 2)))  # noqa: E731
    figures["tracking one_iteration_vs_converged_rms_deg"] = rms(one.quat, full.quat)
    figures["tracking converged_vs_truth_rms_deg"] = rms(full.quat, rec.quat_true)
    figures["tracking one_iteration_vs_truth_rms_deg"] = rms(one.quat, rec.quat_true)

    def draw(axes):
        width = 0.4
        for k, (label, c) in enumerate(counts.items()):
            axes[0, 0].bar(np.arange(len(c)) + (k - 0.5) * width, c, width, label=label)
        axes[0, 0].set(title=f"iterations to Q <= 1e-10 ({n_cases} cases)",
                       xlabel="iterations", ylabel="cases")
        axes[0, 0].legend(fontsize=7)
        axes[0, 1].plot(rec.t, np.degrees(quat.angle_between(one.quat, full.quat)),
                        label="1 iteration vs converged")
        axes[0, 1].plot(rec.t, np.degrees(quat.angle_between(full.quat, rec.quat_true)),
                        label="converged vs truth", alpha=0.6)
        axes[0, 1].set(title="tracking at 100 Hz", xlabel="t (s)", ylabel="deg", yscale="log")
        axes[0, 1].legend(fontsize=7)

    plot = _figure(out_dir, "gauss-newton-convergence", 1, 2, draw)
    far = f"{GUESS_BINS_DEG[-1][0]}_{GUESS_BINS_DEG[-1][1]}"
    notes = (
        "001: 3-4 steps from guesses around the true value, one step when tracking.",
        "Up to 60 deg off, both methods take at most 4 steps in "
        f"{100 * figures['gauss-newton within_4_iterations_guess_30_60_deg']:.1f} % "
        f"(Gauss-Newton) and {100 * figures['newton within_4_iterations_guess_30_60_deg']:.1f} %"
        " (Newton) of the cases from 30-60 deg. From 60-90 deg off, Newton needs a fifth step "
        f"in {100 * (1 - figures[f'newton within_4_iterations_guess_{far}_deg']):.0f} % of the "
        "cases (Gauss-Newton in "
        f"{100 * (1 - figures[f'gauss-newton within_4_iterations_guess_{far}_deg']):.0f} %): "
        "Q is quartic in n, and far from the minimum its Hessian, which Newton follows, is not "
        "positive definite, while Gauss-Newton's JᵀJ always is.",
    )
    return ExperimentResult("gauss-newton-convergence", figures, (plot,), notes)


def _ahrs_runs(acc: np.ndarray, mag: np.ndarray) -> dict[str, Callable[[], object]]:
    """ahrs's single-frame estimators on the same data (NED references, dip DIP)."""
    try:
        import ahrs  # noqa: F401
        from ahrs.filters import FQA, QUEST, TRIAD
        from ahrs.filters import Davenport as AhrsDavenport
    except ImportError:
        return {}
    m_ned = frames.mag_reference("NED", DIP)
    return {
        "ahrs FQA": lambda: FQA(acc=acc, mag=mag, mag_ref=m_ned),
        "ahrs QUEST": lambda: QUEST(acc=acc, mag=mag, magnetic_dip=-DIP),
        "ahrs TRIAD": lambda: TRIAD(w1=acc, w2=mag, v1=frames.up("NED"), v2=m_ned,
                                    representation="quaternion"),
        "ahrs Davenport": lambda: AhrsDavenport(acc=acc, mag=mag, magnetic_dip=-DIP),
    }


def speed_input(n_samples: int) -> Recording:
    """A noisy MEMS recording of a random motion at 100 Hz with ``n_samples`` samples (NED)."""
    return sim.simulate(sim.random_motion((n_samples - 1) / 100.0, 100.0, seed=9),
                        frame="NED", acc_errors=sim.SensorErrors.mems_acc(),
                        mag_errors=sim.SensorErrors.mems_mag(), seed=9)


def _rate(func: Callable[[], object], n_samples: int, repeats: int, warmup: bool = True) -> float:
    """Samples/s of ``func`` by process CPU time, best of ``repeats`` (after one warm-up
    call that compiles the kernels, unless ``warmup`` is False).

    CPU time rather than wall time: on a shared machine other processes then do not slow
    one side of a comparison more than the other (every implementation timed here runs
    on one thread).
    """
    if warmup:
        func()
    best = math.inf
    for _ in range(max(1, repeats)):
        start = time.process_time()
        func()
        best = min(best, time.process_time() - start)
    return n_samples / max(best, 1e-9)


def speed_table(rec: Recording, repeats: int = 5, ahrs_repeats: int = 1) -> dict[str, float]:
    """Samples/s of every estimator here and of ahrs's FQA, QUEST, TRIAD and Davenport on
    the same samples, by CPU time.

    Ours: the public ``run(acc=, mag=, t=, check_units=False)`` (validation, state and the
    kernel; a Recording adds ~5 ns/sample of array stacking in the base class), state
    reset each time, best of ``repeats``; ``"<name> kernel"`` is the kernel call alone.
    ahrs: best of ``ahrs_repeats`` (its per-sample Python loop takes seconds).
    """
    rates: dict[str, float] = {}
    acc, mag, t = rec.acc, rec.mag, rec.t
    dt = np.r_[0.0, np.diff(t)]
    variants = [(cls.name, cls(frame="NED")) for cls in ESTIMATORS]
    # 002 timed the original QUEST, which iterates on the characteristic equation
    variants.append(("quest-newton", Quest(frame="NED", eigenvalue="newton")))
    for name, est in variants:

        def run(est=est):
            est.reset()
            return est.run(acc=acc, mag=mag, t=t, check_units=False)

        def kernel(est=est):
            state = est._new_state(np.array([[1.0, 0.0, 0.0, 0.0]]))
            return est._process(state, None, acc[None], mag[None], dt)

        rates[name] = _rate(run, rec.n_samples, repeats)
        rates[f"{name} kernel"] = _rate(kernel, rec.n_samples, repeats)
    for label, func in _ahrs_runs(acc, mag).items():
        rates[label] = _rate(func, rec.n_samples, ahrs_repeats, warmup=False)
    return rates


#: the ahrs estimator each margtrack estimator is compared with (GN/Newton: the fastest)
COUNTERPART = {"triad": "ahrs TRIAD", "fqa": "ahrs FQA", "quest": "ahrs QUEST",
               "davenport": "ahrs Davenport", "gauss-newton": "ahrs QUEST", "newton": "ahrs QUEST",
               "quest-newton": "ahrs QUEST"}


def single_frame_speed(out_dir: Path, quick: bool) -> ExperimentResult:
    """002 III-D: samples/s of each estimator and of ahrs in the same run on the same data
    (100,000 samples; 2,000 when quick), with ratios to the ahrs counterpart."""
    start = time.perf_counter()
    rates = speed_table(speed_input(2_000 if quick else 100_000), repeats=3 if quick else 7)
    figures: dict[str, float] = {f"{k} samples_per_s": v for k, v in rates.items()}
    figures["clock"] = "process CPU time"
    for name, other in COUNTERPART.items():
        if other in rates:
            figures[f"{name} / {other}"] = rates[name] / rates[other]
    figures["fqa / quest, closed-form eigenvalue"] = rates["fqa"] / rates["quest"]
    figures["fqa / quest-newton (002: 1.25 in MATLAB)"] = rates["fqa"] / rates["quest-newton"]
    for other in ("quest", "quest-newton"):
        figures[f"fqa / {other}, kernels alone"] = rates["fqa kernel"] / rates[f"{other} kernel"]
    figures["wall_s"] = time.perf_counter() - start

    def draw(axes):
        names = [k for k in rates if not k.endswith("kernel")]
        axes[0, 0].barh(names, [rates[n] for n in names])
        axes[0, 0].set(xscale="log", xlabel="samples/s", title="single-frame estimators")

    plot = _figure(out_dir, "single-frame-speed", 1, 1, draw)
    notes = ("target: >= 1000 x ahrs; ahrs loops in Python per sample.",)
    if not any(k.startswith("ahrs") for k in rates):
        notes += ("ahrs is not installed: no comparison.",)
    return ExperimentResult("single-frame-speed", figures, (plot,), notes)


EXPERIMENTS: dict[str, Callable[[Path, bool], ExperimentResult]] = {
    "decoupling": decoupling,
    "singularity": singularity,
    "gauss-newton-convergence": gauss_newton_convergence,
    "single-frame-speed": single_frame_speed,
}
