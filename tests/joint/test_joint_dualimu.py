"""margtrack.joint on a real trial of the dual-IMU dataset, against its optical reference."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack.joint import read_dualimu, relative_orientation
from margtrack.joint.dualimu import relative_error_deg, score

pytestmark = pytest.mark.kernel


@pytest.fixture(scope="module")
def trial(dualimu_folder):
    return read_dualimu(dualimu_folder / "data_2D_01.mat")


def test_the_trial_reads_as_two_recordings_and_a_reference(trial):
    assert trial.parent.n_samples == trial.child.n_samples == 3069
    assert trial.parent.rate_hz == pytest.approx(50.0)
    np.testing.assert_allclose(np.linalg.norm(trial.reference, axis=1), 1.0, atol=1e-9)
    # the dataset's r_12 points from sensor 1 to the joint centre: ours the other way
    assert trial.lever_arms_m[0, 0] < -0.1 and trial.lever_arms_m[1, 0] > 0.1
    assert relative_error_deg(trial.reference, trial.reference, shift=0).max() < 1e-5


def test_online_and_offline_are_within_bounds_of_the_optical_reference(trial):
    """Bounds a little above today's figures (docs/joint.md: 1.8 and 1.7 deg on this trial;
    MEKF-acc 3.9 and MAP-acc 4.1 deg with the same lever arms)."""
    online = relative_orientation(trial.parent, trial.child)
    offline = relative_orientation(trial.parent, trial.child, offline=True)
    # estimated lever arms within a centimetre of the measured ones
    assert np.abs(online.lever_arms.r_m - trial.lever_arms_m).max() < 0.01
    assert score(online.quat, trial) < 2.2
    assert score(offline.quat, trial) < 2.0
    assert np.median(relative_error_deg(offline.quat, trial.reference)) < 2.0
