"""Experiments of 004's gradient-descent filter: vertical disturbance, linear acceleration, x-IMU3.

- ``gradient-vertical-disturbance``: a vertical field added to the earth field (its dip
  grows) while a MEMS sensor moves at random; the forward component (004) keeps the
  inclination error at its undisturbed level, a full-vector filter with a fixed reference
  tilts, Madgwick's re-estimated reference absorbs a pure dip change.
- ``gradient-linear-acceleration``: earth-frame linear acceleration against the simulator's
  analytic one, noise off and on (004 "Inputs and Outputs").
- ``gradient-xio``: the 7-sensor x-IMU3 lower-body recording against the devices' own
  orientation (``Quaternion.csv``), over time, raw and after the best constant heading offset.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack import quaternion as quat
from margtrack.accuracy import error_series
from margtrack.bench.experiments import ExperimentResult
from margtrack.methods.gradient import Gradient
from margtrack.sim import SensorErrors, limb_swing, random_motion, simulate, vertical_tilt

Array = NDArray[np.float64]

__all__ = [
    "EXPERIMENTS",
    "best_heading_offset",
    "linear_acceleration",
    "vertical_disturbance",
    "xio_comparison",
    "xio_folder",
]

_RATE_HZ = 100.0
_OBJECTIVES = ("forward", "madgwick", "fixed")
#: where the x-IMU3 recording is looked for unless MARGTRACK_XIO_DIR says otherwise
_XIO_DEFAULT = Path(__file__).resolve().parents[5] / "shared" / "data" / "xio_lower_body"
_XIO_SENSORS = (
    "pelvis", "left_upper_leg", "left_lower_leg", "left_foot",
    "right_upper_leg", "right_lower_leg", "right_foot",
)


def _mems() -> dict[str, SensorErrors]:
    return {
        "gyr_errors": SensorErrors.mems_gyr(),
        "acc_errors": SensorErrors.mems_acc(),
        "mag_errors": SensorErrors.mems_mag(),
    }


def _rms(x: Array) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _rms_deg(x_rad: Array) -> float:
    return float(np.degrees(_rms(x_rad)))


#: screening gate wide open (vertical_disturbance shows the objectives, not the gate)
_NO_GATE = {"mag_norm_tol": 10.0, "mag_dip_tol_deg": 180.0}


def vertical_disturbance(out_dir: Path, quick: bool) -> ExperimentResult:
    """Inclination error with and without a vertical field of 50 µT (dip 60 to 76 deg).

    A 60 s (quick: 20 s) random motion (200 deg/s, 2 Hz band) seen by MEMS sensors; from
    a third of the way in, :func:`vertical_tilt` adds 50 µT down over 1 s. RMSE after the
    onset, same noise with and without the disturbance.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    duration = 20.0 if quick else 60.0
    onset = duration / 3.0
    traj = random_motion(duration, _RATE_HZ, seed=3, max_rate_deg_s=200.0, bandwidth_hz=2.0)
    plain = simulate(traj, seed=1, **_mems())
    disturbed = simulate(traj, seed=1, mag_disturbances=[vertical_tilt(onset, 50.0)], **_mems())
    after = plain.t >= onset
    figures: dict[str, Any] = {"down_field_ut": 50.0, "onset_s": onset}
    series = {}
    for objective in _OBJECTIVES:
        for label, rec in (("undisturbed", plain), ("disturbed", disturbed)):
            # the objective's own immunity: the screening's norm/dip gate, which would
            # reject this field (+90 % norm, +16 deg dip) for 20 s, is opened wide
            est = Gradient(mag_objective=objective, **_NO_GATE).run(rec)
            err = error_series(est.quat, rec.quat_true)
            series[objective, label] = err
            figures[f"{objective}_inclination_rmse_{label}_deg"] = _rms_deg(
                err.inclination_rad[after]
            )
            figures[f"{objective}_heading_rmse_{label}_deg"] = _rms_deg(err.heading_rad[after])
        figures[f"{objective}_inclination_increase_deg"] = (
            figures[f"{objective}_inclination_rmse_disturbed_deg"]
            - figures[f"{objective}_inclination_rmse_undisturbed_deg"]
        )
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for objective in _OBJECTIVES:
        err = series[objective, "disturbed"]
        axes[0].plot(plain.t, np.degrees(err.inclination_rad), lw=0.8, label=objective)
        axes[1].plot(plain.t, np.degrees(err.heading_rad), lw=0.8, label=objective)
    ref = series["forward", "undisturbed"]
    axes[0].plot(plain.t, np.degrees(ref.inclination_rad), "k:", lw=0.8,
                 label="forward, undisturbed")
    for ax, what in zip(axes, ("inclination", "heading"), strict=True):
        ax.axvline(onset, color="grey", lw=0.8)
        ax.set_ylabel(f"{what} error (deg)")
    axes[0].legend(fontsize=8)
    axes[1].set_xlabel("time (s)")
    axes[0].set_title("vertical field of 50 µT from the grey line (004 forward component)")
    path = Path(out_dir) / "gradient_vertical_disturbance.png"
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    notes = (
        "forward: 004's forward component; the magnetometer only corrects heading.",
        "madgwick: full vector, reference re-estimated from h = q m q* each sample, so a pure "
        "dip change is absorbed at once and does not tilt it either.",
        "fixed: full vector against the field measured at the start (known dip): tilts.",
    )
    return ExperimentResult("gradient-vertical-disturbance", figures, (path,), notes)


def linear_acceleration(out_dir: Path, quick: bool) -> ExperimentResult:
    """Earth-frame linear acceleration against the truth, noise off and on, default β.

    Motions: ``random`` (:func:`random_motion` with 2 cm of translation, the demo motion of
    :func:`margtrack.sim.simulate_default`) and ``limb`` (1 Hz, 30 deg swing of a 0.4 m
    limb, 6 m/s² rms). Noise off the error is the tilt that the linear acceleration itself
    causes (the filter takes the accelerometer for gravity): about g·tilt.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    duration = 20.0 if quick else 60.0
    motions = {
        "random": random_motion(duration, _RATE_HZ, seed=5, translation_m=0.02),
        "limb": limb_swing(duration, _RATE_HZ),
    }
    figures: dict[str, Any] = {}
    shown = None
    for name, traj in motions.items():
        figures[f"{name}_true_rms_m_s2"] = _rms(np.linalg.norm(traj.acc_lin_m_s2, axis=1))
        for noise in (False, True):
            rec = simulate(traj, seed=2, **(_mems() if noise else {}))
            est = Gradient().run(rec)
            lin = est.outputs["lin_acc_earth_m_s2"]
            err = lin - traj.acc_lin_m_s2
            tag = f"{name}_{'noise' if noise else 'no_noise'}"
            figures[f"{tag}_lin_acc_rmse_m_s2"] = _rms(np.linalg.norm(err, axis=1))
            incl = error_series(est.quat, rec.quat_true).inclination_rad
            # the part explained by the tilt alone: |R a - R_true a| = 2 g sin(incl / 2)
            figures[f"{tag}_tilt_part_m_s2"] = _rms(2.0 * 9.80665 * np.sin(incl / 2.0))
            if shown is None:
                shown = (rec.t, lin, traj.acc_lin_m_s2)
    assert shown is not None
    t, lin, true = shown
    fig, axes = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    for k, axis in enumerate("xyz"):
        axes[0].plot(t, true[:, k], lw=1.0, label=f"true {axis}")
        axes[1].plot(t, lin[:, k] - true[:, k], lw=0.8, label=axis)
    axes[0].set_ylabel("linear acc (m/s²)")
    axes[1].set_ylabel("error (m/s²)")
    axes[1].set_xlabel("time (s)")
    axes[0].legend(fontsize=8, ncol=3)
    axes[1].legend(fontsize=8, ncol=3)
    axes[0].set_title("earth-frame linear acceleration, random motion, noise off (ENU)")
    path = Path(out_dir) / "gradient_linear_acceleration.png"
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    notes = ("noise on adds the accelerometer's bias (0.1-0.15 m/s²) and noise in full",)
    return ExperimentResult("gradient-linear-acceleration", figures, (path,), notes)


def best_heading_offset(q_est: Array, q_ref: Array) -> tuple[float, Array]:
    """Constant heading offset ψ (rad) minimising the rms angle of ``qz(ψ) ⊗ q_est`` to ``q_ref``.

    Both (N, 4) in the same earth frame (z vertical). Returns ψ and the angles (N,) rad after
    applying it. Grid of 1 deg, then a bounded 1-D refinement.
    """
    from scipy.optimize import minimize_scalar

    def cost(psi: float) -> float:
        turn = quat.from_axis_angle([0.0, 0.0, 1.0], psi)
        return float(np.mean(quat.angle_between(quat.multiply(turn, q_est), q_ref) ** 2))

    grid = np.radians(np.arange(-180.0, 180.0, 1.0))
    start = float(grid[np.argmin([cost(p) for p in grid])])
    step = np.radians(1.0)
    psi = float(minimize_scalar(cost, bounds=(start - step, start + step), method="bounded").x)
    turn = quat.from_axis_angle([0.0, 0.0, 1.0], psi)
    return psi, quat.angle_between(quat.multiply(turn, q_est), q_ref)


def xio_folder() -> Path:
    """The x-IMU3 lower-body folder: $MARGTRACK_XIO_DIR or ../shared/data/xio_lower_body."""
    path = Path(os.environ.get("MARGTRACK_XIO_DIR", _XIO_DEFAULT))
    if not path.is_dir():
        raise FileNotFoundError(
            f"x-IMU3 recording not found at {path}; set MARGTRACK_XIO_DIR to the "
            "xio_lower_body folder"
        )
    return path


def xio_comparison(out_dir: Path, quick: bool) -> ExperimentResult:
    """Each of the 7 x-IMU3 sensors (MARG, NED output) against the device's Quaternion.csv.

    The device frame is found by comparison: the device quaternion is compared with this
    filter's output converted to NED, ENU and NWU (``q_nwu = [0, 1, 0, 0] ⊗ q_ned``); the
    frame with the smallest raw error is used (ENU and NWU differ by a 90 deg heading turn,
    which a heading offset would absorb, so the raw error decides). ``quick`` runs 2 sensors.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from margtrack import frames
    from margtrack.io import read_xio_quaternion, read_xio_sensor

    root = xio_folder()
    sensors = _XIO_SENSORS[:2] if quick else _XIO_SENSORS
    to_frame: dict[str, Callable[[Array], Array]] = {
        "NED": lambda q: q,
        "ENU": lambda q: frames.convert(q, "NED", "ENU"),
        "NWU": lambda q: quat.multiply([0.0, 1.0, 0.0, 0.0], q),
    }
    figures: dict[str, Any] = {}
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    frame_cost = dict.fromkeys(to_frame, 0.0)
    for name in sensors:
        rec = read_xio_sensor(root / name)
        t_dev, q_dev = read_xio_quaternion(root / name)
        # the device writes one quaternion per inertial sample; interpolate in case it does not
        q_dev = quat.normalize(
            np.stack([np.interp(rec.t, t_dev, q_dev[:, k]) for k in range(4)], axis=1)
        )
        est = Gradient(frame="NED").run(rec)
        for f, conv in to_frame.items():
            frame_cost[f] += _rms(quat.angle_between(conv(est.quat), q_dev)) / len(sensors)
        q_nwu = to_frame["NWU"](est.quat)
        psi, ang_fit = best_heading_offset(q_nwu, q_dev)
        raw = quat.angle_between(q_nwu, q_dev)
        t = rec.t - rec.t[0]
        figures[f"{name}_inertial_gaps"] = int(rec.meta["inertial_gaps"])
        figures[f"{name}_raw_rms_deg"] = _rms_deg(raw)
        figures[f"{name}_raw_final_deg"] = float(np.degrees(raw[-1]))
        figures[f"{name}_heading_offset_deg"] = float(np.degrees(psi))
        figures[f"{name}_offset_removed_rms_deg"] = _rms_deg(ang_fit)
        late = t >= 5.0
        figures[f"{name}_offset_removed_rms_after_5s_deg"] = _rms_deg(ang_fit[late])
        axes[0].plot(t, np.degrees(raw), lw=0.8, label=name)
        axes[1].plot(t, np.degrees(ang_fit), lw=0.8, label=name)
    for f, cost in frame_cost.items():
        figures[f"device_frame_{f}_raw_mean_rms_deg"] = float(np.degrees(cost))
    figures["device_frame"] = min(frame_cost, key=frame_cost.__getitem__)
    axes[0].set_ylabel("raw angle (deg)")
    axes[1].set_ylabel("heading offset removed (deg)")
    axes[1].set_xlabel("time (s)")
    axes[0].legend(fontsize=7, ncol=4)
    axes[0].set_title("gradient filter vs x-IMU3 on-board orientation (device frame NWU)")
    path = Path(out_dir) / "gradient_xio.png"
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    notes = (
        "the filter starts from TRIAD on the first sample; the device's filter had been "
        "running since boot (device clock at 917 s), so the first seconds include our convergence",
        "dropped packets (inertial_gaps, 40-60 ms) show as steps: the device integrated the "
        "lost samples, this filter turns by the next sample's rate over the whole gap",
        "no ground truth: the device's own filter (x-io Fusion) is a reference, not the truth",
    )
    return ExperimentResult("gradient-xio", figures, (path,), notes)


EXPERIMENTS: dict[str, Callable[[Path, bool], ExperimentResult]] = {
    "gradient-vertical-disturbance": vertical_disturbance,
    "gradient-linear-acceleration": linear_acceleration,
    "gradient-xio": xio_comparison,
}
