"""simulate(): measurements consistent with the truth in both frames, determinism, provenance.

The accelerometer and magnetometer are checked against scipy's Rotation (an independent
implementation) and against hand-written reference vectors, with no conjugation.
"""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from margtrack import quaternion as qt
from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.recording import Recording
from margtrack.sim import (
    DEFAULT_DIP_DEG,
    DEFAULT_FIELD_UT,
    Hold,
    Rotate,
    SensorErrors,
    body_rate,
    constant_rotation,
    limb_swing,
    random_motion,
    rotation_sequence,
    simulate,
    simulate_default,
    static,
)

Q0 = qt.from_euler(np.radians([-60.0, 25.0, 140.0]))
G = STANDARD_GRAVITY_M_S2

KINDS = {
    "static": lambda frame: static(2.0, 100.0, q0=Q0),
    "constant_rotation": lambda frame: constant_rotation((1.0, -1.0, 0.5), 45.0, 5.0, 100.0, q0=Q0),
    "rotation_sequence": lambda frame: rotation_sequence(
        [
            Rotate((1, 0, 0), 45, 10),
            Hold(2),
            Rotate((0, 1, 0), -30, 20),
            Hold(1),
        ],
        100.0,
        q0=Q0,
    ),
    "random_motion": lambda frame: random_motion(10.0, 100.0, seed=2, translation_m=0.05, q0=Q0),
    "limb_swing": lambda frame: limb_swing(5.0, 100.0, amplitude_deg=50.0, q0=Q0, frame=frame),
}


def reference_vectors(frame, dip_deg, field_ut):
    """Hand-written: what a level accelerometer reads (up) and the field (north, down by dip)."""
    c, s = math.cos(math.radians(dip_deg)), math.sin(math.radians(dip_deg))
    if frame == "NED":
        return np.array([0.0, 0.0, -G]), field_ut * np.array([c, 0.0, s])
    return np.array([0.0, 0.0, G]), field_ut * np.array([0.0, c, -s])


def to_body(quat, v_earth):
    """scipy oracle for q* ⊗ v ⊗ q: scipy wants [x, y, z, w] and applies R, so invert."""
    return Rotation.from_quat(quat[:, [1, 2, 3, 0]]).apply(v_earth, inverse=True)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
@pytest.mark.parametrize("kind", sorted(KINDS))
def test_integrating_the_simulated_gyro_recovers_the_truth(kind, frame):
    rec = simulate(KINDS[kind](frame), frame=frame)
    q = np.empty_like(rec.quat_true)
    q[0] = rec.quat_true[0]
    for i in range(1, rec.n_samples):
        q[i] = qt.integrate(q[i - 1], rec.gyr[i], rec.t[i] - rec.t[i - 1])
    assert qt.angle_between(q, rec.quat_true).max() < 1e-10
    assert np.abs(rec.gyr).max() > 0.0 or kind == "static"


@pytest.mark.parametrize("frame", ["ENU", "NED"])
@pytest.mark.parametrize("kind", sorted(KINDS))
def test_acc_and_mag_are_the_earth_vectors_seen_from_the_body(kind, frame):
    traj = KINDS[kind](frame)
    rec = simulate(traj, frame=frame, dip_deg=55.0, field_ut=48.0)
    g_up, m_ref = reference_vectors(frame, 55.0, 48.0)
    np.testing.assert_allclose(
        rec.acc, to_body(traj.quat, g_up + traj.acc_lin_m_s2), rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(
        rec.mag, to_body(traj.quat, np.tile(m_ref, (traj.n_samples, 1))), rtol=0, atol=1e-12
    )
    # and the same through margtrack's own rotate_inverse
    np.testing.assert_allclose(
        rec.acc, qt.rotate_inverse(traj.quat, g_up + traj.acc_lin_m_s2), atol=1e-12
    )


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_a_level_sensor_reads_the_hand_values(frame):
    rec = simulate(static(1.0, 10.0), frame=frame)
    g_up, m_ref = reference_vectors(frame, DEFAULT_DIP_DEG, DEFAULT_FIELD_UT)
    np.testing.assert_allclose(rec.acc, np.tile(g_up, (11, 1)), atol=1e-15)
    np.testing.assert_allclose(rec.mag, np.tile(m_ref, (11, 1)), atol=1e-13)
    assert rec.acc[0, 2] == pytest.approx(-G if frame == "NED" else G)
    np.testing.assert_array_equal(rec.gyr, 0.0)


def test_each_sensor_gets_its_own_errors():
    traj = constant_rotation((0, 0, 1), 20.0, 2.0, 100.0, q0=Q0)
    clean = simulate(traj, frame="NED")
    rec = simulate(
        traj,
        frame="NED",
        gyr_errors=SensorErrors(bias=(0.01, 0.02, 0.03)),
        acc_errors=SensorErrors(bias=(0.1, 0.2, 0.3)),
        mag_errors=SensorErrors(bias=(1.0, 2.0, 3.0)),
    )
    np.testing.assert_allclose(
        rec.gyr - clean.gyr, np.tile([0.01, 0.02, 0.03], (201, 1)), atol=1e-15
    )
    np.testing.assert_allclose(rec.acc - clean.acc, np.tile([0.1, 0.2, 0.3], (201, 1)), atol=1e-13)
    np.testing.assert_allclose(rec.mag - clean.mag, np.tile([1.0, 2.0, 3.0], (201, 1)), atol=1e-13)


def test_the_recording_carries_truth_frame_and_provenance():
    traj = random_motion(3.0, 50.0, seed=4)
    rec = simulate(
        traj,
        frame="NED",
        dip_deg=62.5,
        field_ut=47.0,
        seed=17,
        name="trial",
        gyr_errors=SensorErrors.mems_gyr(),
    )
    assert isinstance(rec, Recording)
    assert (rec.frame, rec.name, rec.n_samples) == ("NED", "trial", 151)
    np.testing.assert_allclose(rec.quat_true, traj.quat, atol=1e-15)
    np.testing.assert_array_equal(rec.t, traj.t)
    assert rec.movement.dtype == bool and rec.movement.all()
    meta = rec.meta
    assert (meta["seed"], meta["dip_deg"], meta["field_ut"], meta["frame"]) == (
        17,
        62.5,
        47.0,
        "NED",
    )
    assert meta["gravity_m_s2"] == G
    assert meta["gyr_errors"]["noise_density"] == SensorErrors.mems_gyr().noise_density
    assert meta["acc_errors"]["noise_density"] == 0.0
    assert meta["trajectory"]["name"] == "random_motion"
    assert meta["trajectory"]["seed"] == 4


def test_same_seed_same_data_different_seed_different_data():
    a = simulate_default(duration_s=5.0, rate_hz=100.0, seed=1)
    b = simulate_default(duration_s=5.0, rate_hz=100.0, seed=1)
    c = simulate_default(duration_s=5.0, rate_hz=100.0, seed=2)
    for field in ("gyr", "acc", "mag", "quat_true"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
        assert np.abs(getattr(a, field) - getattr(c, field)).max() > 1e-3
    traj = static(1.0, 100.0)
    noisy = {"gyr_errors": SensorErrors.mems_gyr()}
    d, e = simulate(traj, seed=5, **noisy), simulate(traj, seed=6, **noisy)
    np.testing.assert_array_equal(d.quat_true, e.quat_true)
    assert np.abs(d.gyr - e.gyr).max() > 1e-4


def test_without_mag_the_other_signals_do_not_change():
    traj = random_motion(2.0, 100.0, seed=0)
    errors = {
        "gyr_errors": SensorErrors.mems_gyr(),
        "acc_errors": SensorErrors.mems_acc(),
        "mag_errors": SensorErrors.mems_mag(),
    }
    full = simulate(traj, seed=3, **errors)
    six = simulate(traj, seed=3, with_mag=False, **errors)
    assert six.mag is None
    np.testing.assert_array_equal(six.gyr, full.gyr)
    np.testing.assert_array_equal(six.acc, full.acc)


def test_simulate_default_is_random_motion_with_mems_errors():
    clean = simulate_default(duration_s=4.0, rate_hz=50.0, seed=3, frame="NED", noise=False)
    traj = random_motion(4.0, 50.0, 3, max_rate_deg_s=200.0, bandwidth_hz=2.0, translation_m=0.02)
    np.testing.assert_array_equal(clean.gyr, body_rate(traj))
    assert clean.frame == "NED" and clean.n_samples == 201
    noisy = simulate_default(duration_s=4.0, rate_hz=50.0, seed=3, frame="NED")
    residual = noisy.gyr - clean.gyr - np.asarray(SensorErrors.mems_gyr().bias)
    # white noise 0.005 deg/s/√Hz at 50 Hz is 0.035 deg/s; scale, misalignment and
    # quantization of up to 200 deg/s add a few tenths of a deg/s at most
    assert 0.02 < np.degrees(residual[1:].std()) < 1.0
    assert noisy.meta["acc_errors"] == SensorErrors.mems_acc().__dict__


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="built for 'NED'"):
        simulate(limb_swing(1.0, 100.0, frame="NED"), frame="ENU")
    with pytest.raises(ValueError, match="frame"):
        simulate(static(1.0, 10.0), frame="XYZ")
    with pytest.raises(ValueError, match="seed"):
        simulate(static(1.0, 10.0), seed=-3)
    with pytest.raises(ValueError, match="dip_deg"):
        simulate(static(1.0, 10.0), dip_deg=95.0)
