"""Gyroscope: null within the noise floor, scale from known turns (000 eq. 5) within 0.2 %."""

import itertools
import math

import numpy as np
import pytest

from margtrack import quaternion as qt
from margtrack import sim
from margtrack.calibration import (
    fit_gyro_matrix,
    gyro_null,
    gyro_scale,
    integrate_rotation,
    rotation_estimate,
    static_segments,
)
from margtrack.calibration.simulate_procedure import error_profile

RATE_HZ = 100.0


def test_null_is_within_the_noise_floor():
    """The true null over the period is ``bias + mean(walk)``: the simulator draws white
    noise, then the walk, from the same stream whatever the densities, so the walk is
    reproduced with the white noise and quantisation switched off. The estimate must be
    within 3 standard errors (``noise_floor_rad_s``, from the data) of it."""
    errors = error_profile("raw")[0]
    n = int(5.0 * RATE_HZ)
    still = errors.apply(np.zeros((n, 3)), RATE_HZ, np.random.default_rng(7))
    walk_only = errors.__class__(bias=errors.bias, bias_random_walk=errors.bias_random_walk)
    truth = walk_only.apply(np.zeros((n, 3)), RATE_HZ, np.random.default_rng(7)).mean(axis=0)
    null = gyro_null(still)
    assert np.all(np.abs(null.null_rad_s - truth) < 3.0 * null.noise_floor_rad_s)
    # the floor is the white noise's standard error (0.005 deg/s/√Hz · √100 / √500),
    # widened slightly by the dithered quantisation
    expected = errors.noise_density * math.sqrt(RATE_HZ) / math.sqrt(n)
    np.testing.assert_allclose(null.noise_floor_rad_s, expected, rtol=0.2)


def test_eq5_by_hand():
    """A sensor reading 2 % high turned exactly 90 deg in 1 s: eq. 5 gives 1 / 1.02."""
    t = np.linspace(0.0, 1.0, 101)
    gyr = np.zeros((101, 3))
    gyr[1:, 2] = 1.02 * math.pi / 2 + 0.01  # + null
    turn = rotation_estimate(t, gyr, [0.0, 0.0, 0.01], 90.0)
    assert turn.axis == 2
    assert turn.integrated_deg == pytest.approx(91.8, rel=1e-12)
    assert turn.scale_factor == pytest.approx(1 / 1.02, rel=1e-12)


def turns_recording(errors, seed):
    """000's turns: ±90 and ∓180 about each body axis with holds (like steps 1-13)."""
    q = qt.identity()
    steps = [sim.Hold(3.0)]
    for axis in np.eye(3):
        for angle in (90.0, -180.0, 90.0):
            steps += [sim.Rotate(tuple(qt.rotate(q, axis)), angle, 90.0), sim.Hold(2.0)]
            q = qt.multiply(qt.from_axis_angle(qt.rotate(q, axis), np.radians(angle)), q)
    return sim.simulate(sim.rotation_sequence(steps, RATE_HZ), frame="NED", gyr_errors=errors,
                        seed=seed)


@pytest.mark.parametrize("profile", ["mems", "raw"])
def test_scale_from_known_turns_within_0p2_percent(profile):
    errors = error_profile(profile)[0]
    rec = turns_recording(errors, seed=8)
    segments = static_segments(rec)
    assert len(segments) == 10
    null = gyro_null(rec.gyr[segments[0][0]:segments[0][1]])
    known = [90.0, -180.0, 90.0] * 3
    turns, measured, true = [], [], []
    for k, ((_, stop), (start, _)) in enumerate(itertools.pairwise(segments)):
        s = slice(stop - 1, start + 1)
        turns.append(rotation_estimate(rec.t[s], rec.gyr[s], null.null_rad_s, known[k]))
        measured.append(integrate_rotation(rec.t[s], rec.gyr[s], null.null_rad_s))
        true.append(np.radians(known[k]) * np.eye(3)[k // 3])
    scale = gyro_scale(turns, null.null_rad_s)
    sensitivity = np.diag(errors.matrix())  # eq. 5 sees the axis' own reading of the turn
    np.testing.assert_allclose(1.0 / scale.scale_factor, sensitivity, rtol=2e-3)
    # the full matrix (eq. 5 extended): scale and misalignment of every axis
    k = fit_gyro_matrix(measured, true)
    np.testing.assert_allclose(k, errors.matrix(), atol=2e-3 * 0.1)
    # positive and negative turns agree to the noise: half range well under 0.1 %
    assert np.all(scale.spread < 1e-3)


def test_wrong_turns_are_refused():
    t = np.linspace(0.0, 1.0, 101)
    gyr = np.zeros((101, 3))
    gyr[1:, 0] = math.pi / 2
    with pytest.raises(ValueError, match=r"x gyro integrates to 90\.0 deg but the rotation is -90"):
        rotation_estimate(t, gyr, np.zeros(3), -90.0)
    with pytest.raises(ValueError, match="no known rotation about the y, z axis"):
        gyro_scale([rotation_estimate(t, gyr, np.zeros(3), 90.0)], np.zeros(3))
    with pytest.raises(ValueError, match="three independent axes"):
        fit_gyro_matrix([[1.0, 0, 0], [2.0, 0, 0], [0, 1.0, 0]], [[1.0, 0, 0], [2.0, 0, 0],
                                                                  [0, 1.0, 0]])
