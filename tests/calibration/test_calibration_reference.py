"""Reference vectors (000 step 18): dip, field strength, heading offset from hand values."""

import numpy as np
import pytest

from margtrack import frames
from margtrack import quaternion as qt
from margtrack.calibration import reference_vectors


@pytest.mark.parametrize("dip_deg", [-70.0, 0.0, 35.0, 60.0])
@pytest.mark.parametrize("heading_deg", [0.0, 25.0, -100.0])
def test_dip_field_and_heading_of_an_exact_pose(dip_deg, heading_deg):
    """Sensor level, x turned heading_deg east of north, tilted 8 deg about its x axis:
    readings from the frames module's references; dip and field are pose-independent."""
    q = qt.multiply(qt.from_axis_angle([0, 0, 1], np.radians(heading_deg)),
                    qt.from_axis_angle([1, 0, 0], np.radians(8.0)))
    acc = qt.rotate_inverse(q, frames.gravity_reference("NED"))
    mag = qt.rotate_inverse(q, frames.mag_reference("NED", dip_deg, 48.0))
    ref = reference_vectors(acc, mag)
    assert ref.dip_deg == pytest.approx(dip_deg, abs=1e-9)
    assert ref.field_ut == pytest.approx(48.0, rel=1e-12)
    assert ref.gravity_m_s2 == pytest.approx(frames.STANDARD_GRAVITY_M_S2, rel=1e-12)
    # the x axis stays in the vertical plane through its heading when tilted about itself
    assert ref.heading_offset_deg == pytest.approx(heading_deg, abs=1e-9)


def test_reference_pose_gives_the_ned_vectors():
    acc = np.tile(frames.gravity_reference("NED"), (10, 1))
    mag = np.tile(frames.mag_reference("NED", 60.0, 50.0), (10, 1))
    ref = reference_vectors(acc, mag)
    np.testing.assert_allclose(ref.acc_m_s2, [0, 0, -frames.STANDARD_GRAVITY_M_S2])
    np.testing.assert_allclose(ref.mag_ut, [25.0, 0.0, 50.0 * np.sin(np.radians(60.0))])
    assert ref.heading_offset_deg == pytest.approx(0.0, abs=1e-12)


def test_vertical_field_is_refused():
    with pytest.raises(ValueError, match="vertical"):
        reference_vectors([0, 0, -9.81], [0, 0, 50.0])
