"""Accelerometer: six-position (000 eqs. 1-2), 12-parameter and norm least squares.

Tolerances of the issue: scale within 0.1 %, bias within 0.01 m/s², misalignment within
0.05 deg, at a realistic noise level: the MEMS model (150 µg/√Hz white noise, 1e-4 m/s²/√s
bias walk, 16-bit LSB at ±16 g) at 100 Hz with 2 s holds. Expected errors, for scale
and misalignment: pose mean noise 0.0147/√200 ≈ 1e-3 m/s², over 2 g ≈ 5e-5 (0.005 %,
0.003 deg); bias: 1e-3 m/s² plus the walk over the run (1e-4·√60 ≈ 8e-4). The bounds
hold with a 10x margin.
"""

import itertools

import numpy as np
import pytest

from margtrack import quaternion as qt
from margtrack import sim
from margtrack.calibration import (
    TriadCalibration,
    fit_known_directions,
    fit_norm,
    nearest_axes,
    segment_means,
    six_position,
    static_segments,
)
from margtrack.calibration.simulate_procedure import error_profile
from margtrack.frames import STANDARD_GRAVITY_M_S2 as G

UP_NED = np.array([0.0, 0.0, -1.0])


def orientation_with_up(up_body, yaw_deg=0.0):
    """A body-to-NED quaternion whose body vector ``up_body`` points up (then a yaw)."""
    q = qt.shortest_arc(np.asarray(up_body, dtype=float), UP_NED)
    return qt.multiply(qt.from_axis_angle([0, 0, 1], np.radians(yaw_deg)), q)


def poses_recording(ups, errors, seed, hold_s=2.0, rate_hz=100.0):
    """Still poses with the given body up directions, joined by 60 deg/s turns."""
    targets = [orientation_with_up(u, 17.0 * k) for k, u in enumerate(ups)]
    steps = [sim.Hold(hold_s)]
    for prev, nxt in itertools.pairwise(targets):
        rotvec = qt.to_rotvec(qt.multiply(nxt, qt.conjugate(prev)))
        angle = np.degrees(np.linalg.norm(rotvec))
        steps += [sim.Rotate(tuple(rotvec), angle, 60.0), sim.Hold(hold_s)]
    trajectory = sim.rotation_sequence(steps, rate_hz, q0=targets[0])
    return sim.simulate(trajectory, frame="NED", acc_errors=errors, seed=seed)


SIX = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
CORNERS = [(sx, sy, sz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]


@pytest.fixture(scope="module", params=["mems", "raw"])
def errors(request):
    return error_profile(request.param)[1]


@pytest.fixture(scope="module")
def pose_means(errors):
    rec = poses_recording(SIX + CORNERS, errors, seed=5)
    segments = static_segments(rec)
    assert len(segments) == len(SIX) + len(CORNERS)
    return segment_means(rec.acc, segments)


def axis_angles_deg(k_est, k_true):
    a = k_est / np.linalg.norm(k_est, axis=1)[:, None]
    b = k_true / np.linalg.norm(k_true, axis=1)[:, None]
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))


def test_six_position_recovers_null_and_scale(errors, pose_means):
    result = six_position(pose_means[:6])
    np.testing.assert_allclose(result.null_m_s2, errors.bias, atol=0.01)
    # eq. 2's multiplier undoes the sensitivity (1 + scale) · cos(misalignment) of each axis
    m = errors.misalignment_matrix()
    sensitivity = np.linalg.norm(errors.matrix(), axis=1) * np.abs(np.diag(m))
    np.testing.assert_allclose(1.0 / result.scale, sensitivity, atol=1e-3)
    np.testing.assert_allclose(1.0 / result.scale - 1.0, errors.scale, atol=1e-3)


def test_twelve_parameter_fit_recovers_everything(errors, pose_means):
    fit = fit_known_directions(pose_means[:6])
    np.testing.assert_allclose(fit.bias, errors.bias, atol=0.01)
    scale, misalignment, _ = TriadCalibration("acc", fit.matrix).decompose()
    np.testing.assert_allclose(scale, errors.scale, atol=1e-3)
    assert np.all(axis_angles_deg(fit.matrix, errors.matrix()) < 0.05)
    np.testing.assert_allclose(misalignment, errors.misalignment_deg, atol=0.05)
    assert fit.residuals_m_s2.shape == (6, 3)
    assert fit.rms_residual_m_s2 < 0.005  # the noise of a pose mean is ~1e-3


def test_norm_fit_from_free_poses(errors, pose_means):
    fit = fit_norm(pose_means)
    np.testing.assert_allclose(fit.bias, errors.bias, atol=0.01)
    scale, misalignment, rotation = TriadCalibration("acc", fit.matrix).decompose()
    np.testing.assert_allclose(scale, errors.scale, atol=1e-3)
    np.testing.assert_allclose(misalignment, errors.misalignment_deg, atol=0.05)
    assert rotation == pytest.approx(0.0, abs=1e-9)  # the lower-triangular convention
    assert np.all(np.abs(fit.residuals_m_s2) < 0.01)
    # the corners alone (8 poses) are too few for 9 parameters
    with pytest.raises(ValueError, match="at least 9 still poses"):
        fit_norm(pose_means[6:])


def test_eqs_1_and_2_by_hand():
    """Axis up reads 10.1, down -9.5 (g = 9.8): null 0.3 (eq. 1), scale 19.6/19.6 = 1 (eq. 2)."""
    means = np.array([[10.1, 0.3, 0.3], [-9.5, 0.3, 0.3], [0.3, 10.3, 0.3], [0.3, -9.7, 0.3],
                      [0.3, 0.3, 9.9], [0.3, 0.3, -9.9]])
    result = six_position(means, gravity_m_s2=9.8)
    np.testing.assert_allclose(result.null_m_s2, [0.3, 0.3, 0.0])
    np.testing.assert_allclose(result.scale, [1.0, 19.6 / 20.0, 19.6 / 19.8])


def test_missing_or_tilted_poses_are_explained():
    means = G * np.array(SIX[:5], dtype=float)
    with pytest.raises(ValueError, match="need at least 6"):
        six_position(means)
    with pytest.raises(ValueError, match=r"no still pose with the \+z axis pointing down"):
        six_position(np.vstack([means, means[0]]))
    with pytest.raises(ValueError, match=r"pose 1 is tilted 45\.0 deg"):
        nearest_axes([[0, 0, G], [G, 0, G]])
    coplanar = G * np.array([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)], dtype=float)
    with pytest.raises(ValueError, match="do not determine the model"):
        fit_known_directions(coplanar)
