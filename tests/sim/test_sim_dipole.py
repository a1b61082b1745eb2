"""A magnet carried by the sensor: the dipole's field by hand, and that it turns with the body."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from margtrack import quaternion as qt
from margtrack.sim import (
    AttachedDipole,
    attached_dipole,
    dipole_field_ut,
    random_motion,
    simulate,
    static,
)

MU0 = 4e-7 * np.pi  # T·m/A


@pytest.mark.parametrize("r_m", [0.01, 0.02, 0.04, 0.1])
def test_on_axis_and_equatorial_fields_by_hand(r_m):
    m = 0.3  # A·m²
    axis = np.array([0.0, 0.6, 0.8])
    on_axis = dipole_field_ut(m * axis, r_m * axis)
    np.testing.assert_allclose(on_axis, 2 * MU0 * m / (4 * np.pi * r_m**3) * 1e6 * axis,
                               rtol=1e-12)
    side = np.array([1.0, 0.0, 0.0])  # perpendicular to the moment
    equatorial = dipole_field_ut(m * axis, r_m * side)
    np.testing.assert_allclose(equatorial, -MU0 * m / (4 * np.pi * r_m**3) * 1e6 * axis,
                               rtol=1e-12, atol=1e-9)
    # the field is even in the offset (either sense of "between")
    np.testing.assert_array_equal(dipole_field_ut(m * axis, -r_m * side), equatorial)


def test_one_tenth_am2_at_ten_cm_is_twenty_microtesla_on_axis():
    np.testing.assert_allclose(attached_dipole(0.1, 0.1).offset_ut, [20.0, 0.0, 0.0], rtol=1e-12)
    np.testing.assert_allclose(attached_dipole(0.01, 0.1).offset_ut, [2e4, 0.0, 0.0], rtol=1e-12)
    # perpendicular moment: equatorial, against the moment, half the size
    side = attached_dipole(0.1, 0.1, direction=(1, 0, 0), moment_direction=(0, 0, 1))
    np.testing.assert_allclose(side.offset_ut, [0.0, 0.0, -10.0], atol=1e-12)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_the_offset_is_constant_in_the_body_frame_while_the_body_turns(frame):
    traj = random_motion(10.0, 100.0, seed=3, max_rate_deg_s=150.0)
    magnet = attached_dipole(0.04, 0.2, direction=(0.0, 1.0, 1.0), start_s=4.0)
    clean = simulate(traj, frame=frame, seed=1)
    rec = simulate(traj, frame=frame, seed=1, mag_disturbances=[magnet])
    np.testing.assert_array_equal(rec.gyr, clean.gyr)
    np.testing.assert_array_equal(rec.acc, clean.acc)
    diff = rec.mag - clean.mag
    on = rec.t >= 4.0
    np.testing.assert_allclose(diff[on], np.broadcast_to(magnet.offset_ut, diff[on].shape),
                               rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(diff[~on], 0.0)
    # in the earth frame the same offset turns with the sensor: not constant there
    earth = qt.rotate(traj.quat[on], diff[on])
    assert np.ptp(earth, axis=0).max() > np.linalg.norm(magnet.offset_ut)
    assert rec.meta["mag_disturbances"][0]["type"] == "AttachedDipole"


def test_bad_dipoles_are_refused():
    with pytest.raises(ValueError, match="position_m must not be zero"):
        AttachedDipole((0.1, 0.0, 0.0), (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="moment_am2 must be 3 finite numbers"):
        AttachedDipole((0.1, 0.0), (0.01, 0.0, 0.0))
    with pytest.raises(ValueError, match="distance_m must be a finite number > 0"):
        attached_dipole(0.0)
    with pytest.raises(ValueError, match="moment_direction must be a finite non-zero"):
        attached_dipole(0.01, moment_direction=(0, 0, 0))


def test_static_sensor_field_is_earth_plus_offset():
    traj = static(1.0, 50.0)
    magnet = attached_dipole(0.02, 0.1)
    rec = simulate(traj, mag_disturbances=[magnet])
    clean = simulate(traj)
    np.testing.assert_allclose(rec.mag - clean.mag, np.broadcast_to([2500.0, 0, 0], rec.mag.shape),
                               rtol=1e-12)


def _sweep_module():
    path = Path(__file__).parents[2] / "benchmarks" / "attached_magnet_sweep.py"
    spec = importlib.util.spec_from_file_location("attached_magnet_sweep", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_sweep_runs_and_triad_is_worse_near_the_magnet():
    from margtrack import methods

    sweep = _sweep_module()
    runs = [("triad", methods.get("triad")(frame="ENU"))]
    rows = sweep.sweep(runs, (None, 1.0, 4.0, 10.0), seeds=(0,), duration_s=10.0)
    heading = {r["distance_cm"]: r["heading_rmse_deg"] for r in rows}
    inclination = {r["distance_cm"]: r["inclination_rmse_deg"] for r in rows}
    assert [r["distance_cm"] for r in rows] == [None, 1.0, 4.0, 10.0]
    # TRIAD's heading follows the magnetometer sample by sample: nearer is worse, and
    # even 10 cm (20 µT against 50 µT) is worse than no magnet
    assert heading[1.0] >= heading[4.0] >= heading[10.0] > heading[None]
    assert heading[1.0] > 30.0 and heading[None] < 5.0
    # its inclination comes from the accelerometer alone: the magnet does not change it
    assert np.ptp(list(inclination.values())) < 1e-9
