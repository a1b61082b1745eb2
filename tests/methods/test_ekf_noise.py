"""The EKF's evidence-driven measurement noise (acc_disturbance_s, mag_disturbance_s)."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.methods.ekf import MarinsEkf
from margtrack.methods.ekf.noise import disturbance_share, quaternion_update, rotation_covariance
from margtrack.sim.trajectories import Trajectory

G = 9.80665
#: 001's filter as printed (the field's evidence is on by default)
PRINTED = {"mag_disturbance_s": 0.0, "acc_disturbance_s": 0.0}


def test_a_static_sample_has_no_share_and_twice_gravity_the_derived_one():
    h = 0.01
    assert disturbance_share(G, G, 0.5, 1.0 / h) == 0.0  # at rest: 001's noise as printed
    assert disturbance_share(3.0 * G, G, 0.0, 1.0 / h) == 0.0  # option off
    # |a| = 2 g: d = 1, s = 2 T d² / h
    assert disturbance_share(2.0 * G, G, 0.5, 1.0 / h) == pytest.approx(2.0 * 0.5 / h, rel=1e-15)
    assert disturbance_share(33.0, 44.0, 0.3, 1.0 / h) == pytest.approx(
        2.0 * 0.3 * 0.25**2 / h, rel=1e-14)


def test_rotation_covariance_matches_the_hand_derivation():
    # â = e_z, m̂ = e_x, ρ = 1: A = 2I - e_z e_zᵀ - e_x e_xᵀ = diag(1, 2, 1)
    ok, *c = rotation_covariance(0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 3.0, 0.0)
    assert ok
    # B = s_a diag(1, 1, 0): C = s_a diag(1, 1/4, 0): the tilts only, none on the heading
    np.testing.assert_allclose(c, [3.0, 0.0, 0.0, 0.75, 0.0, 0.0], atol=1e-15)
    ok, *c = rotation_covariance(0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0, 2.0)
    # B = s_m diag(0, 1, 1): C = s_m diag(0, 1/4, 1): the field turns the heading most
    np.testing.assert_allclose(c, [0.0, 0.0, 0.0, 0.5, 0.0, 2.0], atol=1e-15)


def test_rotation_covariance_is_the_sensitivity_of_the_fit_by_perturbation():
    rng = np.random.default_rng(4)
    a, m = rng.normal(size=3), rng.normal(size=3)
    a, m = a / np.linalg.norm(a), m / np.linalg.norm(m)
    rho, s_a, s_m = 0.7, 0.3, 1.1
    ok, c00, c01, c02, c11, c12, c22 = rotation_covariance(*a, *m, rho, s_a, s_m)
    assert ok
    c = np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]])
    # the least-squares rotation δθ = argmin |δa - [a]×δθ|² + ρ²|δm - [m]×δθ|², sampled
    cross = lambda v: np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])  # noqa: E731
    j = np.vstack([cross(a), rho * cross(m)])
    n = 200_000
    dy = np.hstack([rng.normal(size=(n, 3)) * np.sqrt(s_a),
                    rho * rng.normal(size=(n, 3)) * np.sqrt(s_m)])
    theta = np.linalg.lstsq(j, dy.T, rcond=None)[0].T
    np.testing.assert_allclose(np.cov(theta.T), c, atol=0.02 * np.abs(c).max())


def test_quaternion_update_equals_the_batch_update_with_the_derived_covariance():
    rng = np.random.default_rng(7)
    n = 7
    root = rng.normal(size=(n, n))
    p = root @ root.T * 0.1 + np.eye(n) * 0.05
    x = rng.normal(size=n)
    z = rng.normal(size=4)
    z /= np.linalg.norm(z)
    var = 0.4
    c = np.array([[1.0, 0.2, -0.1], [0.2, 0.5, 0.3], [-0.1, 0.3, 2.0]])
    st = np.zeros(n + n * n + n)
    st[:n], st[n : n + n * n] = x, p.ravel()
    ok = quaternion_update(st, 0, n, n, n + n * n, *z, var, c[0, 0], c[0, 1], c[0, 2],
                           c[1, 1], c[1, 2], c[2, 2])
    assert ok
    w, qx, qy, qz = z
    xi = np.array([[-qx, -qy, -qz], [w, -qz, qy], [qz, w, -qx], [-qy, qx, w]])  # z ⊗ (0, v)
    r = var * np.eye(4) + 0.25 * xi @ c @ xi.T
    hm = np.zeros((4, n))
    hm[:, 3:] = np.eye(4)
    k = p @ hm.T @ np.linalg.inv(hm @ p @ hm.T + r)
    x_ref = x + k @ (z - hm @ x)
    p_ref = (np.eye(n) - k @ hm) @ p
    np.testing.assert_allclose(st[:n], x_ref, atol=1e-12)
    upper = np.triu_indices(n)
    np.testing.assert_allclose(st[n : n + n * n].reshape(n, n)[upper], p_ref[upper], atol=1e-12)


def _shaken(seconds=8.0, rate=100.0, amplitude_m=0.05, freq_hz=2.0, start_s=3.0, cycles=6):
    """At rest at a tilted pose, shaken horizontally (north) for whole cycles in the middle:
    x = A (1 - cos ωt), so the linear acceleration A ω² cos ωt (7.9 m/s² at the defaults)."""
    t = np.arange(round(seconds * rate) + 1) / rate
    q0 = quat.from_euler([0.4, 0.2, -0.1])
    w = 2.0 * np.pi * freq_hz
    tau = t - start_s
    on = (tau >= 0.0) & (tau <= cycles / freq_hz)
    pos, acc = np.zeros((t.size, 3)), np.zeros((t.size, 3))
    pos[on, 1] = amplitude_m * (1.0 - np.cos(w * tau[on]))
    acc[on, 1] = amplitude_m * w**2 * np.cos(w * tau[on])
    traj = Trajectory(t, np.tile(q0, (t.size, 1)), pos, acc, "shaken")
    return sim.simulate(traj, frame="ENU", gyr_errors=sim.SensorErrors.mems_gyr(),
                        acc_errors=sim.SensorErrors.mems_acc(),
                        mag_errors=sim.SensorErrors.mems_mag(), seed=5)


def _tilt_deg(est_quat, true_quat):
    e = quat.multiply(est_quat, quat.conjugate(true_quat))
    w, x, y, z = np.abs(e).T
    return np.degrees(2.0 * np.arctan2(np.hypot(x, y), np.hypot(w, z)))


def test_a_linear_acceleration_burst_tilts_the_extension_less():
    rec = _shaken()
    printed = _tilt_deg(MarinsEkf(**PRINTED).run(rec).quat, rec.quat_true)
    evidence = _tilt_deg(MarinsEkf(**PRINTED | {"acc_disturbance_s": 0.3}).run(rec).quat,
                         rec.quat_true)
    burst = slice(300, 700)
    assert printed[burst].max() > 2.0  # the burst does tilt 001's filter
    assert evidence[burst].max() < 0.6 * printed[burst].max()
    # at rest before the burst the two are the same filter (|a| = g up to the sensor noise)
    np.testing.assert_allclose(evidence[100:290], printed[100:290], atol=0.05)


def test_a_static_recording_with_the_option_is_the_printed_filter():
    # noise-free at rest: |a| = g and |m| = its reference, so R is 001's at every sample
    rec = sim.simulate(sim.static(1.0, 100.0, q0=quat.from_euler([2.1, -0.4, 0.9])), seed=0)
    printed = MarinsEkf(**PRINTED).run(rec)
    on = MarinsEkf(acc_disturbance_s=0.5, mag_disturbance_s=0.5).run(rec)
    np.testing.assert_allclose(on.quat, printed.quat, atol=1e-12)
    np.testing.assert_allclose(on.outputs["cov_diag"], printed.outputs["cov_diag"],
                               rtol=1e-9, atol=1e-15)


def test_a_field_disturbance_turns_the_heading_of_the_extension_less():
    traj = sim.static(12.0, 100.0, q0=quat.from_euler([0.5, 0.1, 0.0]))
    # perfect sensors; a magnet pass raising the field's norm by 14 % (inside the
    # screening's gate, so 001's filter takes it) and turning it by up to 12 deg
    direction = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    rec = sim.simulate(traj, frame="ENU", seed=3,
                       mag_disturbances=[sim.magnet_pass(6.0, 4.0, 15.0, direction)])

    def heading_deg(q):
        e = quat.multiply(q, quat.conjugate(rec.quat_true))
        return np.degrees(np.abs(2.0 * np.arctan2(e[:, 3], e[:, 0])))

    printed = MarinsEkf(**PRINTED).run(rec)
    assert not np.any(printed.flags)  # no sample was screened out
    evidence = heading_deg(MarinsEkf().run(rec).quat)  # the default: 1 s
    assert heading_deg(printed.quat).max() > 4.0  # 4.95 deg
    assert evidence.max() < 0.6 * heading_deg(printed.quat).max()  # 2.40 deg


@pytest.mark.parametrize("approach", [1, 2])
def test_update_n_times_equals_run_once_with_the_option(approach):
    rec = _shaken(seconds=4.0)
    kw = dict(approach=approach, acc_disturbance_s=0.3, mag_disturbance_s=1.0)
    batch = MarinsEkf(**kw).run(rec)
    live = MarinsEkf(**kw, rate_hz=100.0)
    stepped = np.array([live.update(rec.gyr[i], rec.acc[i], rec.mag[i]) for i in range(400)])
    np.testing.assert_allclose(stepped, batch.quat[:400], atol=1e-12)
    np.testing.assert_allclose(np.diagonal(live.state.get("cov")[0].reshape(7, 7)),
                               batch.outputs["cov_diag"][399], rtol=1e-12, atol=0)


def test_several_sensors_in_one_run_equal_each_sensor_alone_with_the_option():
    recs = [_shaken(seconds=4.0), _shaken(seconds=4.0, amplitude_m=0.03, freq_hz=1.5)]
    t = recs[0].t
    kw = dict(acc_disturbance_s=0.3, mag_disturbance_s=1.0)
    both = MarinsEkf(**kw).run(gyr=np.stack([r.gyr for r in recs]),
                               acc=np.stack([r.acc for r in recs]),
                               mag=np.stack([r.mag for r in recs]), t=t)
    for s, r in enumerate(recs):
        alone = MarinsEkf(**kw).run(gyr=r.gyr, acc=r.acc, mag=r.mag, t=t)
        np.testing.assert_allclose(both.quat[s], alone.quat, atol=1e-15)
