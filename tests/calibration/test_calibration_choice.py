"""The model choices `calibrate accel` / `calibrate gyro` and the report share (calibration/)."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as qt
from margtrack import sim
from margtrack.calibration.accelerometer import ACCEL_MODELS, choose_accel_model
from margtrack.calibration.gyroscope import gyro_from_turns
from margtrack.calibration.static import static_segments

G = 9.80665
K_TRUE = np.array([[1.02, 0.0, 0.0], [0.004, 0.97, 0.0], [-0.003, 0.006, 1.01]])
B_TRUE = np.array([0.12, -0.08, 0.2])


def _readings(up_body: np.ndarray) -> np.ndarray:
    """Noise-free still readings ``K g u + b`` (the model of calibration_file)."""
    return (K_TRUE @ (G * up_body).T).T + B_TRUE


def test_box_faces_choose_the_12_parameter_fit_and_recover_the_model():
    faces = np.vstack([np.eye(3), -np.eye(3)])
    choice = choose_accel_model(_readings(faces))
    assert choice.chosen_name == "known directions" == ACCEL_MODELS[0]
    np.testing.assert_allclose(choice.chosen.K, K_TRUE, atol=1e-12)
    np.testing.assert_allclose(choice.chosen.b, B_TRUE, atol=1e-12)
    assert set(choice.failures) == {"norm"}  # 6 poses cannot determine the 9-parameter fit
    assert "9" in choice.failures["norm"] or "pose" in choice.failures["norm"]
    assert choice.six is not None  # eqs. 1-2 still computed for the table
    np.testing.assert_allclose(choice.six.null_m_s2, B_TRUE + 0.0, atol=0.05)


def test_free_poses_choose_the_norm_fit():
    rng = np.random.default_rng(7)
    ups = rng.normal(size=(14, 3))
    ups /= np.linalg.norm(ups, axis=1, keepdims=True)
    choice = choose_accel_model(_readings(ups))
    assert choice.chosen_name == "norm"
    assert "known directions" in choice.failures and "tilted" in choice.failures["known directions"]
    np.testing.assert_allclose(choice.chosen.K, K_TRUE, atol=1e-8)
    np.testing.assert_allclose(choice.chosen.b, B_TRUE, atol=1e-8)


def test_no_model_lists_every_reason():
    with pytest.raises(ValueError, match=r"no accelerometer model.*known directions.*norm.*"
                                         r"six-position.*each axis up and down"):
        choose_accel_model(_readings(np.eye(3)))


def _turns_recording(angles_deg, scale=(0.02, -0.02, 0.01), seed=8):
    """Still 3 s, then turns about x, y, z (each ``angles_deg``) with 2 s holds."""
    errors = sim.SensorErrors(scale=scale, bias=(0.01, -0.02, 0.005))
    q = qt.identity()
    steps = [sim.Hold(3.0)]
    known = []
    for axis in np.eye(3):
        for angle in angles_deg:
            steps += [sim.Rotate(tuple(qt.rotate(q, axis)), angle, 90.0), sim.Hold(2.0)]
            q = qt.multiply(qt.from_axis_angle(qt.rotate(q, axis), np.radians(angle)), q)
            known.append(angle)
    rec = sim.simulate(sim.rotation_sequence(steps, 100.0), frame="NED", gyr_errors=errors,
                       seed=seed)
    return rec, known, errors


def test_gyro_turns_find_the_known_angles_and_scale():
    rec, known, errors = _turns_recording((90.0, -180.0, 90.0))
    found = gyro_from_turns(rec.t, rec.gyr, static_segments(rec), 90.0)
    assert [r.known_deg for r in found.rotations] == known
    assert [r.axis for r in found.rotations] == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert found.skipped_deg == ()
    # eq. 5 gives known / integrated = 1 / sensitivity: within 0.2 % of the simulated scale
    np.testing.assert_allclose(1.0 / found.scale.scale_factor, np.diag(errors.matrix()),
                               rtol=2e-3)
    np.testing.assert_allclose(found.null.null_rad_s, errors.bias, atol=2e-3)


def test_gyro_turns_skip_what_is_not_a_multiple_and_say_so():
    rec, _, _ = _turns_recording((90.0, 45.0))
    found = gyro_from_turns(rec.t, rec.gyr, static_segments(rec), 90.0)
    assert len(found.rotations) == 3 and len(found.skipped_deg) == 3
    assert all(abs(abs(a).max() - 45.0) < 3.0 for a in found.skipped_deg)
    only_45, _, _ = _turns_recording((45.0,))
    with pytest.raises(ValueError, match=r"no known rotation about the x, y, z axis.*3 turn\(s\) "
                                         r"skipped"):
        gyro_from_turns(only_45.t, only_45.gyr, static_segments(only_45), 90.0)
    with pytest.raises(ValueError, match="still period"):
        gyro_from_turns(rec.t, rec.gyr, static_segments(rec)[:1], 90.0)
    with pytest.raises(ValueError, match="angle_deg"):
        gyro_from_turns(rec.t, rec.gyr, static_segments(rec), 0.0)
