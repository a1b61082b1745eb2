"""The gradient filter's experiments, quick: figures that would be false were the filter wrong."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.bench.experiments import gradient as experiments
from margtrack.bench.experiments.gradient import EXPERIMENTS, best_heading_offset


def test_registry_names():
    assert set(EXPERIMENTS) == {
        "gradient-vertical-disturbance",
        "gradient-linear-acceleration",
        "gradient-xio",
    }


def test_vertical_disturbance(tmp_path):
    result = EXPERIMENTS["gradient-vertical-disturbance"](tmp_path, True)
    f = result.figures
    assert f["forward_inclination_increase_deg"] < 0.1
    assert f["fixed_inclination_increase_deg"] > 2.0
    assert all(p.is_file() and p.stat().st_size > 10_000 for p in result.plots)


def test_linear_acceleration(tmp_path):
    f = EXPERIMENTS["gradient-linear-acceleration"](tmp_path, True).figures
    # noise off, the whole error is the tilt the acceleration causes (g · tilt)
    assert f["random_no_noise_lin_acc_rmse_m_s2"] == pytest.approx(
        f["random_no_noise_tilt_part_m_s2"], rel=0.05
    )
    assert f["random_no_noise_lin_acc_rmse_m_s2"] < f["random_true_rms_m_s2"] / 2
    # noise adds the accelerometer bias (up to 0.15 m/s²) in full
    assert f["random_noise_lin_acc_rmse_m_s2"] > f["random_no_noise_lin_acc_rmse_m_s2"]


def test_best_heading_offset_recovers_a_known_offset():
    rng = np.random.default_rng(8)
    q = quat.normalize(rng.normal(size=(100, 4)))
    turn = quat.from_axis_angle([0.0, 0.0, 1.0], np.radians(-37.0))
    psi, angles = best_heading_offset(q, quat.multiply(turn, q))
    assert np.degrees(psi) == pytest.approx(-37.0, abs=1e-4)
    assert np.max(angles) < 1e-5


def test_xio(tmp_path):
    try:
        experiments.xio_folder()
    except FileNotFoundError as exc:
        pytest.skip(str(exc))
    f = EXPERIMENTS["gradient-xio"](tmp_path, True).figures
    # the devices report in NWU; our NED output converted to NWU matches within degrees
    assert f["device_frame"] == "NWU"
    assert f["device_frame_NED_raw_mean_rms_deg"] > 90.0
    assert f["pelvis_raw_rms_deg"] < 5.0
    assert f["pelvis_offset_removed_rms_deg"] <= f["pelvis_raw_rms_deg"]
