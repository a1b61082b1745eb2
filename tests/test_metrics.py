"""Error metrics: hand values for pure heading, pure tilt and combined errors; frames; masks."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.accuracy import error_series, rmse_deg, summarize


def test_pure_heading_error():
    truth = quat.from_euler([[0.3, 0.4, -0.2]])
    est = quat.multiply(quat.from_axis_angle([0, 0, 1], 0.1), truth)
    e = error_series(est, truth)
    np.testing.assert_allclose(e.total_rad, 0.1, atol=1e-14)
    np.testing.assert_allclose(e.heading_rad, 0.1, atol=1e-14)
    np.testing.assert_allclose(e.inclination_rad, 0.0, atol=1e-14)


def test_pure_inclination_error_about_any_horizontal_axis():
    truth = quat.from_euler([[1.3, -0.4, 0.7]])
    for axis in ([1, 0, 0], [0, 1, 0], [1, -2, 0]):
        est = quat.multiply(quat.from_axis_angle(axis, 0.25), truth)
        e = error_series(est, truth)
        np.testing.assert_allclose(e.inclination_rad, 0.25, atol=1e-14)
        np.testing.assert_allclose(e.heading_rad, 0.0, atol=1e-14)


def test_heading_after_tilt_splits_like_the_definition():
    # e = q_z(b) ⊗ q_x(a): e_w = cos(a/2)cos(b/2), e_z = cos(a/2)sin(b/2)
    a, b = 0.3, 0.8
    e_rot = quat.multiply(quat.from_axis_angle([0, 0, 1], b), quat.from_axis_angle([1, 0, 0], a))
    truth = quat.identity((1,))
    err = error_series(e_rot[None], truth)
    np.testing.assert_allclose(err.heading_rad, b, atol=1e-14)
    np.testing.assert_allclose(err.inclination_rad, a, atol=1e-14)
    total = 2 * np.arccos(np.cos(a / 2) * np.cos(b / 2))
    np.testing.assert_allclose(err.total_rad, total, atol=1e-14)


def test_sign_of_the_quaternion_does_not_matter():
    rng = np.random.default_rng(0)
    truth = quat.normalize(rng.normal(size=(20, 4)))
    est = quat.normalize(truth + rng.normal(scale=0.05, size=(20, 4)))
    a = error_series(est, truth)
    b = error_series(-est, truth)
    np.testing.assert_allclose(a.total_rad, b.total_rad, atol=1e-15)
    np.testing.assert_allclose(a.heading_rad, b.heading_rad, atol=1e-15)


def test_estimate_in_other_frame_is_converted_before_comparing():
    rng = np.random.default_rng(1)
    truth_enu = quat.normalize(rng.normal(size=(10, 4)))
    est_ned = frames.convert(truth_enu, "ENU", "NED")
    e = error_series(est_ned, truth_enu, est_frame="NED", true_frame="ENU")
    assert np.max(e.total_rad) < 1e-7


def test_rmse_over_mask_and_empty_mask():
    err = np.radians([1.0, 3.0, 100.0])
    assert rmse_deg(err, [True, True, False]) == pytest.approx(np.sqrt(5.0))
    with pytest.raises(ValueError, match="mask selects none"):
        rmse_deg(err, [False, False, False])
    s = summarize(error_series(quat.identity((3,)), quat.identity((3,))), [True, False, True])
    assert s.n_samples == 2
    assert s.total_rmse_deg == 0.0
