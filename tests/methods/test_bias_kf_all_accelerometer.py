"""All-accelerometer rates (003 eqs. 1-6, 32-37) and the bias filter fed with them."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.methods.bias_kf import BiasKalmanParams, track_all_accelerometer
from margtrack.sim import SensorErrors
from margtrack.sim import all_accelerometer as aa
from margtrack.single_frame import all_accelerometer as est
from margtrack.single_frame import all_accelerometer_kernel as kernel
from margtrack.single_frame.triad import Triad

ARRAY = aa.AccelerometerArray.handheld_instrument()
RATE = 500.0
T = 1.0 / RATE


def _constant_alpha(n=1500, alpha=2.0, axis=(0.3, -0.5, 0.8)):
    """Rotation about a fixed axis from rest with constant α: ω = α t n, linear in t, so
    eq. 3's backward difference is exact."""
    unit = np.asarray(axis) / np.linalg.norm(axis)
    t = np.arange(n) * T
    omega = (alpha * t)[:, None] * unit
    f0 = np.tile([0.3, -0.2, 9.7], (n, 1))
    return t, omega, aa.specific_forces(ARRAY, omega, np.tile(alpha * unit, (n, 1)), f0)


@pytest.mark.kernel
@pytest.mark.parametrize("damping", [0.0, 1e-3])
def test_solver_recovers_exact_rates_gauss_newton_and_levenberg_marquardt(damping):
    t, omega, readings = _constant_alpha()
    res = est.angular_velocity(readings, ARRAY, t=t, damping=damping)
    assert np.max(np.abs(res.omega_rad_s - omega)) < 1e-9
    assert res.converged.all()
    assert np.max(res.residual_m_s2) < 1e-9
    assert res.iterations[0] == 0 and np.all(res.iterations[1:] >= 1)


@pytest.mark.kernel
def test_residual_jacobian_against_finite_differences():
    rng = np.random.default_rng(0)
    omega, prev, a_d = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
    base = ARRAY.baselines()
    r, jac = np.empty(3), np.empty((3, 3))
    kernel.residual_jacobian(omega, prev, a_d, base, T, r, jac)
    fd = np.empty((3, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1e-6
        rp, rm, scratch = np.empty(3), np.empty(3), np.empty((3, 3))
        kernel.residual_jacobian(omega + e, prev, a_d, base, T, rp, scratch)
        kernel.residual_jacobian(omega - e, prev, a_d, base, T, rm, scratch)
        fd[:, j] = -(rp - rm) / 2e-6  # J = ∂g/∂Ω = -∂r/∂Ω
    np.testing.assert_allclose(jac, fd, rtol=1e-7, atol=1e-6)


@pytest.mark.kernel
def test_residual_rows_follow_eq_4_not_the_garbled_third_row_of_eq_5():
    # eq. 5 prints a12x and P23|y in row 3; eq. 4 and Fig. 1 make it a12z with P12|z
    rng = np.random.default_rng(1)
    omega, prev, a_d = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
    r = np.empty(3)
    kernel.residual_jacobian(omega, prev, a_d, ARRAY.baselines(), T, r, np.empty((3, 3)))
    alpha = (omega - prev) / T
    p13, p23, p12 = ARRAY.baselines()

    def g(p):
        return np.cross(omega, np.cross(omega, p)) + np.cross(alpha, p)

    np.testing.assert_allclose(r, a_d - [g(p13)[0], g(p23)[1], g(p12)[2]], rtol=1e-12)
    assert abs(r[2] - (a_d[2] - g(p23)[1])) > 1e-3


def test_differential_noise_is_twice_a_channel_variance_and_averaging_halves_it():
    # eq. 32 prints 4 σ_A²; the difference of two independent channels has 2 σ_A²
    rng = np.random.default_rng(2)
    noise = rng.normal(scale=0.03, size=(200_000, 6))
    var_d = np.var(est.differential_acceleration(noise), axis=0)
    var_g = np.var(est.gravity_estimate(noise), axis=0)
    # sampling error of a variance: sqrt(2/N) = 0.3 %
    np.testing.assert_allclose(var_d, 2 * 0.03**2, rtol=0.015)
    np.testing.assert_allclose(var_g, 0.5 * 0.03**2, rtol=0.015)  # eq. 42


@pytest.mark.kernel
def test_unscented_transform_is_exact_for_linear_maps_and_gaussian_squares():
    a = np.array([[1.0, 2.0, 0.0], [0.0, -1.0, 3.0]])
    cov = np.array([[2.0, 0.3, 0.0], [0.3, 1.0, -0.2], [0.0, -0.2, 0.5]])
    mean, out = est.unscented_transform(lambda x: a @ x + 1.0, [1.0, 0.0, -1.0], cov, kappa=1.0)
    np.testing.assert_allclose(mean, a @ [1.0, 0.0, -1.0] + 1.0, atol=1e-12)
    np.testing.assert_allclose(out, a @ cov @ a.T, atol=1e-12)
    # y = x², x ~ N(0, σ²): mean σ², variance 2σ⁴; exact when n + κ = 3 (fourth moment)
    m, v = est.unscented_transform(lambda x: x**2, [0.0], [[0.25]], kappa=2.0)
    assert m[0] == pytest.approx(0.25, rel=1e-12)
    assert v[0, 0] == pytest.approx(2 * 0.25**2, rel=1e-12)
    with pytest.raises(ValueError, match="n \\+ kappa > 0"):
        est.unscented_transform(lambda x: x, [0.0], [[1.0]], kappa=-1.0)


def test_solver_noise_increments_match_the_unscented_covariance():
    # the solver's error is integrated noise: its increments have the per-sample
    # covariance Ξ_Ω of all_accelerometer_noise (pass 1); the carried-over part is Ξ_B ≈ Ξ_Ω
    t, omega, readings = _constant_alpha(n=400, alpha=0.02)
    density = aa.ADXL203_NOISE_M_S2_SQRT_HZ
    rng = np.random.default_rng(3)
    steps = []
    for _ in range(10):  # short runs: the integrated error stays in the linear regime
        noisy = readings + rng.normal(scale=density * np.sqrt(RATE), size=readings.shape)
        err = est.angular_velocity(noisy, ARRAY, t=t).omega_rad_s - omega
        steps.append(np.diff(err, axis=0))
    noise = est.all_accelerometer_noise(ARRAY, density, RATE)
    xi = noise.rate_cov_rad2_s2
    m_inv = np.linalg.inv(ARRAY.tangential_matrix())
    linear = T**2 * 2 * density**2 * RATE * m_inv @ m_inv.T
    np.testing.assert_allclose(xi, linear, rtol=1e-6, atol=1e-12 * np.abs(linear).max())
    np.testing.assert_allclose(noise.bias_step_cov_rad2_s2, xi, rtol=1e-3,
                               atol=1e-6 * np.abs(xi).max())
    emp = np.cov(np.concatenate(steps).T)
    # variance sampling error sqrt(2/N) ≈ 2.2 % for N ≈ 4000; 4σ, on the diagonal
    np.testing.assert_allclose(np.diag(emp), np.diag(xi), rtol=0.09)
    np.testing.assert_allclose(noise.gyr_noise_rad_s_sqrt_hz, np.sqrt(np.diag(xi) * T))
    np.testing.assert_allclose(noise.gyr_bias_walk_rad_s_sqrt_s,
                               np.sqrt(np.diag(noise.bias_step_cov_rad2_s2) / T))


def test_tremor_rates_without_noise_are_within_the_backward_difference_bound():
    # eq. 3 integrates α by the rectangle rule: |Ω̂ - Ω| <= T max|α| (twice the leading term)
    motion = aa.tremor_motion(10.0, RATE, seed=1)
    rec = aa.simulate_all_accelerometer(motion, ARRAY)
    res = est.angular_velocity(rec.readings_m_s2, ARRAY, t=rec.t)
    bound = T * np.max(np.abs(rec.alpha_rad_s2))
    assert np.max(np.abs(res.omega_rad_s - rec.omega_rad_s)) < bound
    assert np.max(np.abs(res.omega_rad_s - rec.omega_rad_s)) > 0.1 * bound  # tight


def _tracking_setup(seconds):
    rec = aa.simulate_all_accelerometer(
        aa.tremor_motion(seconds, RATE, seed=2), ARRAY,
        acc_noise_m_s2_sqrt_hz=aa.ADXL203_NOISE_M_S2_SQRT_HZ,
        mag_errors=SensorErrors(noise_density=0.02), seed=3,
    )
    noise = est.all_accelerometer_noise(ARRAY, aa.ADXL203_NOISE_M_S2_SQRT_HZ, RATE)
    params = BiasKalmanParams(
        gyr_noise_rad_s_sqrt_hz=noise.gyr_noise_rad_s_sqrt_hz,
        gyr_bias_walk_rad_s_sqrt_s=noise.gyr_bias_walk_rad_s_sqrt_s,
        acc_noise_m_s2_sqrt_hz=aa.ADXL203_NOISE_M_S2_SQRT_HZ / np.sqrt(2.0),  # eq. 42
        acc_motion_fraction=0.01, mag_noise_ut_sqrt_hz=0.02,  # eq. 43; the simulated mag
    )
    return rec, params


def test_filter_with_bias_feedback_beats_triad_and_the_open_loop_solver_diverges():
    rec, params = _tracking_setup(6.0)
    closed = track_all_accelerometer(rec, params, feedback=True)
    opened = track_all_accelerometer(rec, params, feedback=False)
    triad = Triad().run(gyr=None, acc=est.gravity_estimate(rec.readings_m_s2), mag=rec.mag,
                        t=rec.t)

    def rms_deg(q):
        return np.degrees(np.sqrt(np.mean(quat.angle_between(q, rec.quat_true) ** 2)))

    assert rms_deg(closed.quat) < 0.5 * rms_deg(triad.quat)
    assert rms_deg(opened.quat) > 5.0 * rms_deg(closed.quat)
    # open loop: the solver's rate error grows without bound (integrated noise, then the
    # centripetal instability); with feedback it stays near the filter's bias uncertainty
    assert np.max(np.abs(opened.rate_rad_s - rec.omega_rad_s)) > 1.0
    assert np.max(np.abs(closed.rate_rad_s - rec.omega_rad_s)) < 0.5


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: est.differential_acceleration(np.zeros((5, 4))), r"shape \(N, 6\)"),
        (lambda: est.solve_angular_velocity(np.zeros((5, 3)), ARRAY), "exactly one of t"),
        (lambda: est.solve_angular_velocity(np.zeros((5, 3)), ARRAY, rate_hz=1.0, damping=-1),
         "damping must be"),
        (lambda: est.solve_angular_velocity(np.full((5, 3), np.nan), ARRAY, rate_hz=1.0),
         "non-finite value at sample 0"),
        (lambda: est.solve_angular_velocity(np.zeros((3, 3)), ARRAY, t=[0.0, 1.0, 1.0]),
         "increase strictly"),
        (lambda: est.all_accelerometer_noise(ARRAY, 0.0, RATE), "acc_noise_m_s2_sqrt_hz"),
        (lambda: aa.AccelerometerArray(((0, 0, 0), (0, 0, 0.1), (0, 0, 0.2))),
         "do not determine the angular acceleration"),
    ],
)
def test_bad_input_is_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call()
