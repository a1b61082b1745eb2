"""003's experiments: the all-accelerometer IMU with the bias filter, and bias recovery.

- ``all-accelerometer``: a handheld instrument (slow hand motion plus 8-12 Hz tremor of
  30 µm) sensed by three dual-axis ADXL-203 accelerometers and a magnetometer (003 Fig. 1).
  Orientation error without a filter (rates integrated; TRIAD alone) and with the bias
  filter (003 Fig. 2 as drawn: solver open loop; and with the bias fed back to the solver).
- ``bias-kf-bias``: a static sensor with a constant gyro bias: the filter's bias estimate
  converges to it within 4σ of the Riccati steady state of the same model.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import scipy.linalg

from margtrack import frames, sim
from margtrack import quaternion as quat
from margtrack.accuracy import error_series, summarize
from margtrack.bench.experiments import ExperimentResult
from margtrack.estimator import initial_orientation
from margtrack.methods.bias_kf import BiasKalman, BiasKalmanParams, track_all_accelerometer
from margtrack.methods.bias_kf.kernel import fill_triad_cov
from margtrack.sim import all_accelerometer as aa
from margtrack.single_frame.all_accelerometer import (
    all_accelerometer_noise,
    angular_velocity,
    gravity_estimate,
)
from margtrack.single_frame.triad import Triad

__all__ = ["EXPERIMENTS", "all_accelerometer", "bias_recovery"]

_RATE_HZ = 500.0
_MAG_NOISE_UT_SQRT_HZ = 0.02  # HMC-2003 class: 0.45 µT rms at 500 Hz (assumed)


def _rms_deg(rad: np.ndarray) -> float:
    return float(np.degrees(np.sqrt(np.mean(rad**2))))


def _band_rms_deg(err_rad: np.ndarray, rate_hz: float, low_hz: float, high_hz: float) -> float:
    """RMS of the part of an error series (N, 3) between ``low_hz`` and ``high_hz``, deg."""
    spec = np.fft.rfft(err_rad - err_rad.mean(axis=0), axis=0)
    freq = np.fft.rfftfreq(err_rad.shape[0], 1.0 / rate_hz)
    spec[(freq < low_hz) | (freq > high_hz)] = 0.0
    band = np.fft.irfft(spec, n=err_rad.shape[0], axis=0)
    return float(np.degrees(np.sqrt(np.mean(np.sum(band**2, axis=1)))))


def all_accelerometer(out_dir: Path, quick: bool) -> ExperimentResult:
    """Orientation of a tremulous handheld instrument from the all-accelerometer IMU."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seconds = 6.0 if quick else 30.0
    array = aa.AccelerometerArray.handheld_instrument()
    density = aa.ADXL203_NOISE_M_S2_SQRT_HZ
    motion = aa.tremor_motion(seconds, _RATE_HZ, seed=1)
    rec = aa.simulate_all_accelerometer(
        motion, array, acc_noise_m_s2_sqrt_hz=density,
        mag_errors=sim.SensorErrors(noise_density=_MAG_NOISE_UT_SQRT_HZ), seed=2,
    )
    noise = all_accelerometer_noise(array, density, _RATE_HZ)  # eqs. 32-37
    params = BiasKalmanParams.as_printed(
        gyr_noise_rad_s_sqrt_hz=noise.gyr_noise_rad_s_sqrt_hz,
        gyr_bias_walk_rad_s_sqrt_s=noise.gyr_bias_walk_rad_s_sqrt_s,
        acc_noise_m_s2_sqrt_hz=density / math.sqrt(2.0),  # eq. 42
        acc_motion_fraction=0.01,  # eq. 43
        mag_noise_ut_sqrt_hz=_MAG_NOISE_UT_SQRT_HZ,
    )
    rates = angular_velocity(rec.readings_m_s2, array, t=rec.t).omega_rad_s
    gravity = gravity_estimate(rec.readings_m_s2)
    q0 = initial_orientation(gravity[:1], rec.mag[:1], "ENU")[0]
    integrated = np.empty_like(rec.quat_true)
    integrated[0] = q0
    steps = quat.from_rotvec(rates[1:] * np.diff(rec.t)[:, None])
    for i in range(1, len(rec.t)):
        integrated[i] = quat.multiply(integrated[i - 1], steps[i - 1])
    triad_only = Triad().run(gyr=None, acc=gravity, mag=rec.mag, t=rec.t)
    open_loop = track_all_accelerometer(rec, params, feedback=False)
    closed = track_all_accelerometer(rec, params, feedback=True)
    series = {
        "rates integrated (no filter)": integrated,
        "TRIAD alone (no filter)": triad_only.quat,
        "bias KF, solver open loop (003 Fig. 2)": open_loop.quat,
        "bias KF, bias fed back to the solver": closed.quat,
    }
    keys = ("integrated", "triad", "kf_open_loop", "kf_feedback")
    figures: dict[str, float] = {"duration_s": seconds, "rate_hz": _RATE_HZ}
    body_err = {}
    for key, (label, q) in zip(keys, series.items(), strict=True):
        s = summarize(error_series(q, rec.quat_true, "ENU", rec.frame))
        figures[f"{key}_total_rmse_deg"] = s.total_rmse_deg
        figures[f"{key}_heading_rmse_deg"] = s.heading_rmse_deg
        figures[f"{key}_inclination_rmse_deg"] = s.inclination_rmse_deg
        body_err[label] = quat.to_rotvec(quat.multiply(quat.conjugate(rec.quat_true), q))
    figures["tremor_rotation_amplitude_deg"] = math.degrees(30e-6 / 0.1)
    for key, label in (("triad", "TRIAD alone (no filter)"),
                       ("kf_feedback", "bias KF, bias fed back to the solver")):
        figures[f"{key}_tremor_band_error_rms_deg"] = _band_rms_deg(body_err[label], _RATE_HZ,
                                                                    8.0, 12.0)
    figures["solver_open_loop_max_rate_error_rad_s"] = float(
        np.max(np.abs(open_loop.rate_rad_s - rec.omega_rad_s)))
    figures["solver_feedback_max_rate_error_rad_s"] = float(
        np.max(np.abs(closed.rate_rad_s - rec.omega_rad_s)))
    figures["ut_gyr_bias_walk_rad_s_sqrt_s"] = list(noise.gyr_bias_walk_rad_s_sqrt_s)

    fig, axes = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for label, err in body_err.items():
        axes[0].semilogy(rec.t, np.degrees(np.linalg.norm(err, axis=1)) + 1e-4, label=label,
                         lw=0.8)
    axes[0].set_ylabel("orientation error (deg)")
    axes[0].legend(fontsize=8)
    axes[0].set_title("all-accelerometer IMU + magnetometer, tremor on slow hand motion")
    for label, r in (("solver open loop", open_loop.rate_rad_s),
                     ("solver with bias feedback", closed.rate_rad_s)):
        axes[1].semilogy(rec.t, np.linalg.norm(r - rec.omega_rad_s, axis=1) + 1e-9, label=label,
                         lw=0.8)
    axes[1].set_ylabel("|rate error| (rad/s)")
    axes[1].set_xlabel("time (s)")
    axes[1].legend(fontsize=8)
    path = out_dir / "all_accelerometer.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    notes = (
        "rates: Gauss-Newton on eq. 5 with the backward difference of eq. 3; noise "
        "covariances by the unscented transform (eqs. 32-37)",
        "open loop the solver's error is integrated noise that the centripetal terms then "
        "amplify: it diverges within seconds; feeding the bias estimate back keeps it bounded",
    )
    return ExperimentResult("all-accelerometer", figures, (path,), notes)


def _riccati_bias_std(q0: np.ndarray, p: BiasKalmanParams, rate_hz: float) -> np.ndarray:
    """Steady-state bias std (3,) rad/s of the linear error-state model, by the DARE."""
    t = 1.0 / rate_hz
    z = quat.rotate_inverse(q0, frames.up(p.frame))
    n = quat.rotate_inverse(q0, frames.mag_reference(p.frame, sim.DEFAULT_DIP_DEG))
    xi = np.empty((3, 3))
    fill_triad_cov(*z, *n, p.acc_noise_m_s2_sqrt_hz**2 * rate_hz / p.gravity_m_s2**2,
                   p.mag_noise_ut_sqrt_hz**2 * rate_hz / sim.DEFAULT_FIELD_UT**2, xi)
    a = np.block([[np.eye(3), -t * np.eye(3)], [np.zeros((3, 3)), np.eye(3)]])
    h = np.c_[np.eye(3), np.zeros((3, 3))]
    gyr, walk = p.axis_variances()
    q = np.diag(np.r_[gyr * t, walk * t])
    prior = scipy.linalg.solve_discrete_are(a.T, h.T, q, xi)
    post = prior - prior @ h.T @ np.linalg.solve(h @ prior @ h.T + xi, h @ prior)
    return np.sqrt(np.diag(post)[3:])


def bias_recovery(out_dir: Path, quick: bool) -> ExperimentResult:
    """Static sensor with a constant gyro bias: the estimate converges within 4σ."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rate, seconds = 100.0, (40.0 if quick else 120.0)
    bias = np.radians([0.5, -0.3, 0.4])
    gyr_noise, acc_noise, mag_noise = math.radians(0.005), 150e-6 * 9.80665, 0.05
    q0 = quat.from_euler([0.7, 0.2, -0.3])
    rec = sim.simulate(
        sim.static(seconds, rate, q0=q0), frame="ENU",
        gyr_errors=sim.SensorErrors(noise_density=gyr_noise, bias=tuple(bias)),
        acc_errors=sim.SensorErrors(noise_density=acc_noise),
        mag_errors=sim.SensorErrors(noise_density=mag_noise), seed=1,
    )
    params = BiasKalmanParams.as_printed(
        gyr_noise_rad_s_sqrt_hz=gyr_noise, gyr_bias_walk_rad_s_sqrt_s=1e-5,
        acc_noise_m_s2_sqrt_hz=acc_noise, acc_motion_fraction=0.0, mag_noise_ut_sqrt_hz=mag_noise,
    )
    est = BiasKalman(params).run(rec)
    b = est.outputs["gyr_bias_rad_s"]
    sigma_filter = np.sqrt(est.outputs["cov_diag"][:, 4:])
    sigma = _riccati_bias_std(q0, params, rate)
    err = b - bias
    inside = np.all(np.abs(err) < 4.0 * sigma, axis=1)
    outside = np.flatnonzero(~inside)
    settle = 0.0 if outside.size == 0 else float(rec.t[min(outside[-1] + 1, len(rec.t) - 1)])
    figures = {
        "duration_s": seconds,
        "true_bias_deg_s": np.degrees(bias).tolist(),
        "estimated_bias_deg_s": np.degrees(b[-1]).tolist(),
        "bias_error_deg_s": np.degrees(err[-1]).tolist(),
        "riccati_bias_std_deg_s": np.degrees(sigma).tolist(),
        "filter_bias_std_deg_s": np.degrees(sigma_filter[-1]).tolist(),
        "error_in_riccati_sigmas": (err[-1] / sigma).tolist(),
        "within_4_sigma_from_s": settle,
        "converged": bool(inside[-1]),
    }
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(rec.t, np.degrees(b[:, k]), lw=0.8, label="estimate")
        ax.fill_between(rec.t, np.degrees(b[:, k] - 3 * sigma_filter[:, k]),
                        np.degrees(b[:, k] + 3 * sigma_filter[:, k]), alpha=0.3, label="±3σ (P)")
        ax.axhline(np.degrees(bias[k]), color="k", ls="--", lw=0.8, label="true bias")
        ax.set_ylabel(f"b_{'xyz'[k]} (deg/s)")
        ax.set_ylim(np.degrees(bias[k]) - 0.3, np.degrees(bias[k]) + 0.3)
    axes[0].legend(fontsize=8)
    axes[0].set_title("bias-kf: constant gyro bias recovered from a static recording")
    axes[-1].set_xlabel("time (s)")
    path = out_dir / "bias_kf_bias.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    notes = ("tolerance: 4σ of the discrete Riccati steady state of the same linear model "
             "(the truth has no bias walk, so the filter's σ is an upper bound)",)
    return ExperimentResult("bias-kf-bias", figures, (path,), notes)


EXPERIMENTS: dict[str, Callable[[Path, bool], ExperimentResult]] = {
    "all-accelerometer": all_accelerometer,
    "bias-kf-bias": bias_recovery,
}
