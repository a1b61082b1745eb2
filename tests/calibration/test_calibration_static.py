"""Still-period detection: live and batch agree, and they find exactly the simulator's holds."""

import numpy as np
import pytest

from margtrack import frames
from margtrack import quaternion as qt
from margtrack.calibration import (
    StillnessDetector,
    StillnessSettings,
    segment_means,
    simulate_procedure,
    static_segments,
    still_mask,
)
from margtrack.calibration.simulate_procedure import error_profile


@pytest.fixture(scope="module")
def procedure():
    return simulate_procedure(*error_profile("raw"), seed=11)


def test_live_detector_equals_batch_mask(procedure):
    detector = StillnessDetector()
    live = np.array([detector.update(t, g, a) for t, g, a in
                     zip(procedure.t, procedure.gyr, procedure.acc, strict=True)])
    np.testing.assert_array_equal(live, still_mask(procedure))


def test_segments_are_the_holds_of_the_procedure(procedure):
    """Every hold is found; a segment never contains a moving sample and misses at most the
    detector's window (0.5 s) plus one sample at each end of a hold."""
    holds = [(t0, t1) for _, label, t0, t1 in procedure.meta["procedure"] if label == "hold"]
    holds.insert(0, (0.0, 5.0))  # the first hold of step 1
    segments = static_segments(procedure)
    assert len(segments) == len(holds)
    dt = 1.0 / procedure.rate_hz
    for (start, stop), (t0, t1) in zip(segments, holds, strict=True):
        assert procedure.t[start] >= t0 - 1e-9
        assert procedure.t[stop - 1] <= t1 + dt  # the time grid may overrun the last hold
        assert procedure.t[start] - t0 <= 0.5 + 2 * dt
        assert t1 - procedure.t[stop - 1] <= 2 * dt
    # truth: the orientation does not change within a segment
    for start, stop in segments:
        q = procedure.quat_true[start + 1:stop]
        np.testing.assert_allclose(np.abs(q @ procedure.quat_true[stop - 1]), 1.0, atol=1e-12)


def test_segment_means_are_the_pose_means(procedure):
    """Means equal the model ``K g_body + b`` of the pose to 0.01 m/s²: white noise
    0.0147 m/s² over >= 250 samples (1e-3), bias walk over 60 s (8e-4), dithered LSB."""
    segments = static_segments(procedure)
    means = segment_means(procedure.acc, segments)
    _, acc_errors, _ = error_profile("raw")
    for k, (start, stop) in enumerate(segments):
        np.testing.assert_allclose(means[k], procedure.acc[start:stop].mean(axis=0))
        g_body = qt.rotate_inverse(procedure.quat_true[stop - 1], frames.gravity_reference("NED"))
        expected = acc_errors.matrix() @ g_body + np.array(acc_errors.bias)
        np.testing.assert_allclose(means[k], expected, atol=0.01)


def test_slow_steady_turn_is_not_still():
    """A 10 deg/s turn has a quiet-looking accelerometer over 0.5 s, but its mean rate
    0.17 rad/s exceeds max_rate_rad_s = 0.1: never still."""
    t = np.arange(0, 10, 0.01)
    gyr = np.tile([0.0, 0.0, np.radians(10.0)], (t.size, 1))
    acc = np.tile([0.0, 0.0, 9.81], (t.size, 1))
    assert not still_mask(t=t, gyr=gyr, acc=acc).any()
    assert still_mask(t=t, gyr=0.0 * gyr, acc=acc)[t >= 0.5].all()


def test_bad_input():
    with pytest.raises(ValueError, match="window_s must be a finite number > 0"):
        StillnessSettings(window_s=0.0)
    detector = StillnessDetector()
    detector.update(1.0, np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="strictly increasing: sample 1"):
        detector.update(1.0, np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="no still segment"):
        segment_means(np.zeros((5, 3)), [])
