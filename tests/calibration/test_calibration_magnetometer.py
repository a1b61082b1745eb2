"""Magnetometer: ellipsoid fit (hard + soft iron) within 1 % of the field, min/max (eqs. 3-4)
within its known limits, a clear error for too little rotation, axes aligned to gravity."""

import numpy as np
import pytest
from scipy.linalg import sqrtm

from margtrack import frames, sim
from margtrack import quaternion as qt
from margtrack.calibration import (
    align_to_gravity,
    fit_ellipsoid,
    min_max,
    simulate_procedure,
    sphere_coverage,
)
from margtrack.calibration.simulate_procedure import error_profile

F = 50.0


@pytest.fixture(scope="module", params=["mems", "raw"])
def tumble(request):
    """One minute of free rotation seen by a magnetometer with the profile's errors."""
    errors = error_profile(request.param)[2]
    rec = sim.simulate(sim.random_motion(60.0, 100.0, seed=1), frame="NED", field_ut=F,
                       mag_errors=errors, seed=2)
    return rec, errors


def symmetric_soft_iron(errors):
    """What the field alone can reveal of K: the symmetric factor (K Kᵀ)^½."""
    k = errors.matrix()
    return np.real(sqrtm(k @ k.T))


def test_ellipsoid_recovers_hard_and_soft_iron_within_1_percent(tumble):
    rec, errors = tumble
    fit = fit_ellipsoid(rec.mag, field_ut=F)
    # hard iron: error vector under 1 % of F
    assert np.linalg.norm(fit.offset_ut - np.array(errors.bias)) < 0.01 * F
    # soft iron: for every true field of norm F the reading errs by under 1 % of F
    assert np.linalg.norm(fit.soft_iron - symmetric_soft_iron(errors), 2) < 0.01
    # quality figures: the residual is the sensor noise (0.05 µT/√Hz at 100 Hz = 0.5 µT rms
    # per axis, quantisation 0.15 µT): about 0.5 µT on the norm
    assert 0.3 < fit.residual_rms_ut < 0.7
    assert fit.coverage > 0.6 and fit.thinnest_spread > 0.5


def test_default_scale_keeps_the_sensor_unit(tumble):
    rec, errors = tumble
    fit = fit_ellipsoid(rec.mag)
    assert np.linalg.det(fit.soft_iron) == pytest.approx(1.0, abs=1e-12)
    expected = F * np.linalg.det(symmetric_soft_iron(errors)) ** (1 / 3)
    assert fit.field_ut == pytest.approx(expected, rel=1e-3)


def test_too_little_rotation_is_refused():
    errors = error_profile("raw")[2]
    one_axis = sim.simulate(sim.constant_rotation((1, 0, 0), 30.0, 24.0, 100.0), frame="NED",
                            mag_errors=errors, seed=3)
    with pytest.raises(ValueError, match=r"too little rotation.*all three axes"):
        fit_ellipsoid(one_axis.mag)
    with pytest.raises(ValueError, match="at least 50"):
        fit_ellipsoid(one_axis.mag[:10])


def test_min_max_on_000_turns_within_its_known_limits():
    """Steps 15-16: x sweeps the field's (north, down) plane, y and z too: the extremes are
    ±F·(K_ii) exactly, so only noise limits min/max. Its known limits: the noise at the two
    extremes shifts the null by about one smoothed noise std (0.5 µT / √5 = 0.22 µT) and
    widens the range (by ~2 std): bounds 4 std = 0.9 µT (1.8 % of F) on the null, 4 std
    / F = 1.8 % on the scale, and the range is never narrower than K_ii F minus the
    smoothing attenuation (0.03 %)."""
    g, a, m = error_profile("raw")
    rec = simulate_procedure(g, a, m, seed=4, field_ut=F)
    spans = {label: (t0, t1) for _, label, t0, t1 in rec.meta["procedure"]}

    def turn(label):
        t0, t1 = spans[label]
        return rec.mag[(rec.t >= t0) & (rec.t <= t1)]

    step15, step16 = min_max(turn("turn 360 deg about +y")), min_max(turn("turn 360 deg about +x"))
    hi = np.array([step15.max_ut[0], step16.max_ut[1], step16.max_ut[2]])
    lo = np.array([step15.min_ut[0], step16.min_ut[1], step16.min_ut[2]])
    result = min_max(None, field_ut=F, max_ut=hi, min_ut=lo)
    sensitivity = np.diag(m.matrix()) * np.array([1.0, 1.0, 1.0])
    sensitivity[2] = np.linalg.norm(m.matrix()[2, 1:])  # z also sees the y-z plane field
    np.testing.assert_allclose(result.null_ut, m.bias, atol=0.9)
    np.testing.assert_allclose(1.0 / result.scale, sensitivity, rtol=0.018)
    assert np.all(1.0 / result.scale > sensitivity * (1 - 3e-4))
    # on a free tumble min/max is far worse: the extremes are never reached exactly
    tumble = sim.simulate(sim.random_motion(60.0, 100.0, seed=1), frame="NED", mag_errors=m,
                          seed=2)
    assert np.abs(min_max(tumble.mag, field_ut=F).null_ut - m.bias).max() > 1.0


def test_align_to_gravity_restores_the_full_matrix():
    """Exact readings in 8 still poses: the ellipsoid's symmetric S turned by the found
    rotation is K itself; without it the axes are off by the polar rotation of K."""
    errors = error_profile("raw")[2]
    k = errors.matrix()
    s = np.real(sqrtm(k @ k.T))
    ups = np.array([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1),
                    (1, 1, 1), (-1, 1, -1)], dtype=float)
    up = ups / np.linalg.norm(ups, axis=1)[:, None]
    field = frames.mag_reference("NED", 60.0, F)
    mag = []
    for k_pose, u in enumerate(up):
        q = qt.multiply(qt.from_axis_angle([0, 0, 1], 0.7 * k_pose),
                        qt.shortest_arc(u, np.array([0.0, 0.0, -1.0])))
        mag.append(k @ qt.rotate_inverse(q, field) + np.array(errors.bias))
    from margtrack.calibration import TriadCalibration

    aligned, angle, rms = align_to_gravity(TriadCalibration("mag", s, errors.bias), up,
                                           np.array(mag))
    np.testing.assert_allclose(aligned.K, k, atol=1e-9)
    polar = np.degrees(np.arccos((np.trace(np.linalg.solve(s, k)) - 1) / 2))
    assert angle == pytest.approx(polar, abs=1e-6)
    assert rms < 1e-9


def test_sphere_coverage_values():
    rng = np.random.default_rng(0)
    assert sphere_coverage(rng.normal(size=(20000, 3))) == 1.0
    t = np.linspace(0, 2 * np.pi, 2000)
    circle = np.stack([np.cos(t), np.sin(t), 0 * t], axis=1)
    # a great circle crosses about 2π / (π r / 2) cells of radius r = √(4π/100 / π) = 0.2
    # rad (mean chord π r / 2): 20 of 100
    assert 0.15 < sphere_coverage(circle) < 0.3
