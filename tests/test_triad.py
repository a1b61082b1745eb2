"""TRIAD (002 eqs. 1-8): exactness, frames, heading-only magnetometer, degenerate input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.single_frame.triad import Triad

pytestmark = pytest.mark.kernel

def _measure(q_true, frame, dip_deg=65.0, g=9.81, field=48.0):
    up = frames.gravity_reference(frame, g)
    m_ref = frames.mag_reference(frame, dip_deg, field)
    return quat.rotate_inverse(q_true, up), quat.rotate_inverse(q_true, m_ref)


def _random_quats(n, seed):
    rng = np.random.default_rng(seed)
    q = quat.normalize(rng.normal(size=(n, 4)))
    # add the hard cases: pitch at and near +-90 deg and half turns
    special = quat.from_euler(
        [[0.3, np.pi / 2, 0.1], [-2.0, -np.pi / 2, 1.0], [1.0, np.pi / 2 - 1e-7, -0.4]]
    )
    half_turns = quat.from_axis_angle(rng.normal(size=(3, 3)), np.pi - np.array([0, 1e-9, 1e-4]))
    return np.concatenate([q, special, half_turns])


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_noise_free_triad_recovers_every_orientation(frame):
    q_true = _random_quats(500, 1)
    acc, mag = _measure(q_true, frame)
    est = Triad(frame=frame).run(gyr=None, acc=acc, mag=mag, rate_hz=1.0)
    assert np.max(quat.angle_between(est.quat, q_true)) < 1e-9
    assert np.all(est.quat[:, 0] >= 0)
    assert not est.outputs["degenerate"].any()


def test_triad_matches_scipy_align_vectors_with_gravity_weighted_infinitely():
    # align_vectors with an infinite weight on the first pair is exactly TRIAD
    q_true = _random_quats(50, 2)
    rng = np.random.default_rng(5)
    acc, mag = _measure(q_true, "ENU")
    acc = acc + rng.normal(scale=0.2, size=acc.shape)
    mag = mag + rng.normal(scale=3.0, size=mag.shape)
    est = Triad().run(gyr=None, acc=acc, mag=mag, rate_hz=1.0)
    up = frames.up("ENU")
    north = frames.mag_reference("ENU", 65.0)
    for i in range(len(acc)):
        rot, _ = Rotation.align_vectors(
            [up, north], [acc[i], mag[i]], weights=[np.inf, 1.0]
        )
        x, y, z, w = rot.as_quat()
        assert quat.angle_between(est.quat[i], [w, x, y, z]) < 1e-9


def test_magnetometer_changes_only_heading():
    q_true = quat.from_euler([0.4, 0.5, -0.3])
    acc, mag = _measure(q_true, "NED")
    rng = np.random.default_rng(7)
    disturbed = mag[None] + rng.normal(scale=30.0, size=(200, 3))
    est = Triad(frame="NED").run(gyr=None, acc=np.tile(acc, (200, 1)), mag=disturbed, rate_hz=1.0)
    euler = quat.to_euler(est.quat)
    np.testing.assert_allclose(euler[:, 1], 0.5, atol=1e-12)  # pitch
    np.testing.assert_allclose(euler[:, 2], -0.3, atol=1e-12)  # roll
    assert np.ptp(euler[:, 0]) > 0.5  # heading moved with the disturbance


def test_degenerate_samples_are_flagged_and_keep_the_previous_orientation():
    q_true = quat.from_euler([1.0, 0.2, 0.1])
    acc, mag = _measure(q_true, "ENU")
    accs = np.tile(acc, (5, 1))
    mags = np.tile(mag, (5, 1))
    accs[1] = 0.0
    mags[2] = 0.0
    mags[3] = 3.0 * accs[3]
    # the dip gate opened, or the screening would zero the parallel field first
    est = Triad(mag_norm_tol=10.0, mag_dip_tol_deg=180.0).run(
        gyr=None, acc=accs, mag=mags, rate_hz=1.0, check_units=False)
    np.testing.assert_array_equal(est.outputs["degenerate"], [0, 1, 2, 3, 0])
    assert np.all(np.isfinite(est.quat))
    assert np.max(quat.angle_between(est.quat, q_true)) < 1e-12


def test_triad_needs_a_magnetometer():
    with pytest.raises(ValueError, match="method 'triad' needs a magnetometer"):
        Triad().run(gyr=None, acc=np.ones((3, 3)), rate_hz=1.0, check_units=False)


def test_triad_is_003s_world_frame_direction_cosine_matrix():
    # 003 eqs. 10-13: z_W = Ĝ (measured, up), y_W = z_W × N / |.|, x_W = y_W × z_W and
    # C = [x_W y_W z_W]ᵀ maps body to the world frame x north, y west, z up (NWU), which
    # is NED turned by a half turn about north: q_nwu = [0, 1, 0, 0] ⊗ q_ned
    rng = np.random.default_rng(11)
    q_true = _random_quats(40, 12)
    acc, mag = _measure(q_true, "NED")
    acc = acc + rng.normal(scale=0.3, size=acc.shape)
    mag = mag + rng.normal(scale=3.0, size=mag.shape)
    est = Triad(frame="NED").run(gyr=None, acc=acc, mag=mag, rate_hz=1.0)
    for i in range(len(acc)):
        z_w = acc[i] / np.linalg.norm(acc[i])
        y_w = np.cross(z_w, mag[i])
        y_w /= np.linalg.norm(y_w)
        x_w = np.cross(y_w, z_w)
        c_003 = np.array([x_w, y_w, z_w])
        q_nwu = quat.multiply([0.0, 1.0, 0.0, 0.0], est.quat[i])
        np.testing.assert_allclose(quat.to_matrix(q_nwu), c_003, atol=1e-12)


def test_the_single_sensor_kernel_used_for_initialisation_agrees_with_the_estimator():
    from margtrack.estimator.triad_kernel import triad

    q_true = _random_quats(30, 13)
    acc, mag = _measure(q_true, "ENU")
    acc[5] = 0.0
    out = np.empty((len(acc), 4))
    flags = np.empty(len(acc), dtype=np.int8)
    triad(acc, mag, frames.up("ENU"), frames.mag_reference("ENU", 0.0), out, flags)
    est = Triad().run(gyr=None, acc=acc, mag=mag, rate_hz=1.0, check_units=False)
    np.testing.assert_allclose(out, est.quat, atol=1e-15)  # two compilations: rounding only
    np.testing.assert_array_equal(flags, est.outputs["degenerate"])
