"""Allan variance: equal to allantools, exact on the model curve, and the simulated noise
densities recovered within 10 % (003 III-B)."""

import math

import allantools
import numpy as np
import pytest

from margtrack import sim
from margtrack.calibration import (
    AllanDeviation,
    NoiseDensities,
    NoiseTerms,
    allan_deviation,
    identify_noise,
    noise_densities,
)

GYR = sim.SensorErrors(noise_density=math.radians(0.005), bias_random_walk=math.radians(0.001))
ACC = sim.SensorErrors(noise_density=150e-6 * 9.80665, bias_random_walk=1e-4)


@pytest.fixture(scope="module")
def still():
    """12 h of a still MEMS gyro and accelerometer at 5 Hz (216,000 samples): the rate
    random walk of 0.001 deg/s/√s crosses the 0.005 deg/s/√Hz white noise at τ = √3 N/K
    = 8.7 s, and 12 h leaves ~500 clusters at 10x that. No quantisation: at 5 Hz the
    16-bit LSB would exceed the white noise (it is a separate term, Q)."""
    rate_hz, n = 5.0, 216_000
    rng = np.random.default_rng(21)
    return rate_hz, GYR.apply(np.zeros((n, 3)), rate_hz, rng), ACC.apply(np.zeros((n, 3)),
                                                                           rate_hz, rng)


def test_equals_allantools_oadev(still):
    rate_hz, gyr, _ = still
    dev = allan_deviation(gyr, rate_hz)
    for c in range(3):
        taus, adev, _, _ = allantools.oadev(gyr[:, c], rate=rate_hz, data_type="freq",
                                            taus=dev.tau_s)
        np.testing.assert_allclose(taus, dev.tau_s, rtol=1e-12)
        np.testing.assert_allclose(adev, dev.adev[:, c], rtol=1e-9)


def test_recovers_simulated_densities_within_10_percent(still):
    rate_hz, gyr, acc = still
    g = identify_noise(allan_deviation(gyr, rate_hz))
    a = identify_noise(allan_deviation(acc, rate_hz))
    np.testing.assert_allclose(g.white, GYR.noise_density, rtol=0.10)
    np.testing.assert_allclose(g.random_walk, GYR.bias_random_walk, rtol=0.10)
    np.testing.assert_allclose(a.white, ACC.noise_density, rtol=0.10)
    np.testing.assert_allclose(a.random_walk, ACC.bias_random_walk, rtol=0.10)
    # no flicker noise was simulated: B is small against the curve's minimum
    assert np.all(g.bias_instability < 0.5 * g.flat_bias_instability)
    noise = noise_densities(g, a)
    assert noise.gyr_noise_density_rad_s_sqrt_hz == pytest.approx(GYR.noise_density, rel=0.1)
    assert noise.kalman_params() == {
        "gyr_noise_rad_s_sqrt_hz": noise.gyr_noise_density_rad_s_sqrt_hz,
        "gyr_bias_walk_rad_s_sqrt_s": noise.gyr_bias_walk_rad_s2_sqrt_hz,
        "acc_noise_m_s2_sqrt_hz": noise.acc_noise_density_m_s2_sqrt_hz,
    }
    per_sample = noise.per_sample(100.0)
    assert per_sample["gyr_noise_rad_s"] == pytest.approx(
        noise.gyr_noise_density_rad_s_sqrt_hz * 10.0, rel=1e-12)
    assert per_sample["acc_bias_step_m_s2"] == pytest.approx(
        noise.acc_bias_walk_m_s3_sqrt_hz / 10.0, rel=1e-12)


def test_fit_is_exact_on_the_model_curve():
    """Feed σ(τ) of known Q, N, B, K, R (IEEE 952 table C.2): every term comes back."""
    truth = NoiseTerms(*(np.array([v]) for v in (2e-4, 3e-3, 5e-4, 2e-5, 1e-7)),
                       flat_bias_instability=np.array([0.0]))
    tau = np.logspace(-2, 4, 60)
    dev = AllanDeviation(tau, truth.model_adev(tau), n_samples=10**9, rate_hz=100.0)
    got = identify_noise(dev)
    for name in ("quantization", "white", "bias_instability", "random_walk", "ramp"):
        np.testing.assert_allclose(getattr(got, name), getattr(truth, name), rtol=1e-6)


def test_white_noise_slope_by_hand():
    """White noise of density N: σ(τ) = N / √τ (slope -1/2) at every τ."""
    rate_hz, n, density = 100.0, 200_000, 0.01
    y = sim.SensorErrors(noise_density=density).apply(np.zeros((n, 1)).repeat(3, 1), rate_hz,
                                                      np.random.default_rng(3))[:, 0]
    dev = allan_deviation(y, rate_hz, taus_s=[0.01, 0.1, 1.0, 10.0])
    # relative standard error of σ from ~n/m clusters is about 1/√(n/m): 5 of them at most
    np.testing.assert_allclose(dev.adev[:, 0], density / np.sqrt(dev.tau_s),
                               rtol=5.0 / math.sqrt(n / 1000.0))


def test_bad_input():
    with pytest.raises(ValueError, match="taus_s must lie in"):
        allan_deviation(np.zeros(100), 10.0, taus_s=[100.0])
    with pytest.raises(ValueError, match="record longer"):
        identify_noise(allan_deviation(np.random.default_rng(0).normal(size=40), 10.0))
    with pytest.raises(ValueError, match="finite number >= 0"):
        NoiseDensities(-1.0, 0, 0, 0, 0, 0)
