"""SensorErrors: each term of the documented model, with statistically derived tolerances.

Statistical tolerances are 5 standard errors, so a correct model fails with probability
below 1e-6 per check (and the seeds are fixed, so the outcome is deterministic): for N
iid normal samples the sample mean has standard error σ/√N and the sample standard
deviation a relative standard error of 1/√(2(N-1)).
"""

import math

import numpy as np
import pytest

from margtrack.sim import SensorErrors

N = 20_000


def five_se_std(n):
    return 5.0 / math.sqrt(2.0 * (n - 1))


def test_none_is_the_identity():
    x = np.random.default_rng(0).normal(size=(100, 3))
    np.testing.assert_array_equal(SensorErrors.none().apply(x, 100.0, np.random.default_rng(1)), x)


def test_white_noise_std_is_density_times_sqrt_rate():
    rate_hz, density = 200.0, 0.01
    y = SensorErrors(noise_density=density).apply(
        np.zeros((N, 3)), rate_hz, np.random.default_rng(2)
    )
    sigma = density * math.sqrt(rate_hz)
    np.testing.assert_allclose(y.std(axis=0, ddof=1) / sigma, 1.0, atol=five_se_std(N))
    np.testing.assert_allclose(y.mean(axis=0), 0.0, atol=5.0 * sigma / math.sqrt(N))
    corr = np.corrcoef(y.T)[np.triu_indices(3, 1)]
    np.testing.assert_allclose(corr, 0.0, atol=5.0 / math.sqrt(N))  # independent axes


def test_bias_is_recovered_by_averaging():
    bias, rate_hz, density = np.array([0.1, -0.2, 0.3]), 100.0, 0.01
    x = np.tile([0.5, 1.0, -2.0], (N, 1))
    y = SensorErrors(noise_density=density, bias=bias).apply(x, rate_hz, np.random.default_rng(3))
    se = density * math.sqrt(rate_hz) / math.sqrt(N)
    np.testing.assert_allclose((y - x).mean(axis=0), bias, atol=5.0 * se)


def test_bias_random_walk_steps_and_start():
    rate_hz, walk = 100.0, 0.002
    y = SensorErrors(bias_random_walk=walk).apply(
        np.zeros((N, 3)), rate_hz, np.random.default_rng(4)
    )
    np.testing.assert_array_equal(y[0], 0.0)  # the walk starts at zero
    step_sigma = walk / math.sqrt(rate_hz)
    np.testing.assert_allclose(
        np.diff(y, axis=0).std(axis=0, ddof=1) / step_sigma, 1.0, atol=five_se_std(N)
    )


def documented_matrix(scale, misalignment_deg):
    """(I + diag(scale)) @ M with M's rows written out as in the module docstring."""
    ax, ay, az = np.radians(misalignment_deg)
    m = np.array(
        [
            [1.0, 0.0, 0.0],
            [-math.sin(az), math.cos(az), 0.0],
            [math.sin(ay), -math.sin(ax) * math.cos(ay), math.cos(ax) * math.cos(ay)],
        ]
    )
    return np.diag(1.0 + np.asarray(scale)) @ m


def test_scale_and_misalignment_follow_the_documented_matrix():
    scale, misalignment = (0.01, -0.02, 0.03), (1.0, -2.0, 3.0)
    errors = SensorErrors(scale=scale, misalignment_deg=misalignment)
    x = np.random.default_rng(5).normal(size=(50, 3))
    y = errors.apply(x, 100.0, np.random.default_rng(6))
    np.testing.assert_allclose(y, x @ documented_matrix(scale, misalignment).T, atol=1e-14)
    # the sensitive axes are unit vectors and x stays the reference axis
    np.testing.assert_allclose(
        np.linalg.norm(errors.misalignment_matrix(), axis=1), 1.0, atol=1e-15
    )
    # hand values: the y axis turned 5 deg about z sees -sin 5° of a field along x
    turned = SensorErrors(misalignment_deg=(0.0, 0.0, 5.0))
    np.testing.assert_allclose(
        turned.apply(np.array([[1.0, 0.0, 0.0]]), 1.0, np.random.default_rng(0)),
        [[1.0, -math.sin(math.radians(5.0)), 0.0]],
        atol=1e-15,
    )
    high = SensorErrors(scale=(0.0, 0.01, 0.0)).apply(
        np.array([[0.0, 2.0, 0.0]]), 1.0, np.random.default_rng(0)
    )
    np.testing.assert_allclose(high, [[0.0, 2.02, 0.0]], atol=1e-15)


def test_quantization_gives_multiples_of_the_lsb_within_half_an_lsb():
    lsb = 0.01
    x = np.random.default_rng(7).normal(size=(1000, 3))
    raw = SensorErrors(noise_density=0.001).apply(x, 100.0, np.random.default_rng(8))
    y = SensorErrors(noise_density=0.001, quantization=lsb).apply(
        x, 100.0, np.random.default_rng(8)
    )
    np.testing.assert_allclose(y / lsb, np.round(y / lsb), atol=1e-9)
    assert np.abs(y - raw).max() <= lsb / 2 + 1e-12
    assert np.abs(y - raw).max() > lsb / 4  # quantization really happened


def test_saturation_clips_and_leaves_the_rest():
    x = np.array([[-5.0, 0.5, 3.0], [1.0, -1.0, 2.5], [0.0, 4.0, -0.1]])
    y = SensorErrors(saturation=2.0).apply(x, 10.0, np.random.default_rng(0))
    np.testing.assert_array_equal(y, np.clip(x, -2.0, 2.0))
    assert y.max() == 2.0
    assert y.min() == -2.0


def test_same_seed_same_data_different_seed_different_data():
    errors = SensorErrors.mems_gyr()
    x = np.zeros((500, 3))
    a = errors.apply(x, 100.0, np.random.default_rng(11))
    b = errors.apply(x, 100.0, np.random.default_rng(11))
    c = errors.apply(x, 100.0, np.random.default_rng(12))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-3


def test_apply_draws_two_blocks_whatever_the_parameters():
    rng_a, rng_b = np.random.default_rng(9), np.random.default_rng(9)
    SensorErrors.none().apply(np.zeros((10, 3)), 100.0, rng_a)
    rng_b.standard_normal((10, 3))
    rng_b.standard_normal((10, 3))
    assert rng_a.standard_normal() == rng_b.standard_normal()


def test_mems_presets_carry_the_stated_si_figures():
    gyr, acc, mag = SensorErrors.mems_gyr(), SensorErrors.mems_acc(), SensorErrors.mems_mag()
    # gyro: 0.005 deg/s/√Hz is 0.05 deg/s rms at 100 Hz; ±2000 deg/s over 16 bit
    assert math.degrees(gyr.noise_density * math.sqrt(100.0)) == pytest.approx(0.05)
    assert math.degrees(gyr.saturation) == pytest.approx(2000.0)
    assert math.degrees(gyr.quantization) * 65536 == pytest.approx(4000.0)
    assert np.degrees(gyr.bias) == pytest.approx([0.3, -0.2, 0.25])
    # accelerometer: 150 µg/√Hz, ±16 g over 16 bit
    assert acc.noise_density / 9.80665 == pytest.approx(150e-6)
    assert acc.saturation == pytest.approx(16 * 9.80665)
    assert acc.quantization * 65536 == pytest.approx(32 * 9.80665)
    # magnetometer: 0.5 µT rms at 100 Hz, 0.15 µT LSB, ±4900 µT
    assert mag.noise_density * 10.0 == pytest.approx(0.5)
    assert (mag.quantization, mag.saturation) == (0.15, 4900.0)
    assert mag.bias_random_walk == 0.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"noise_density": -1.0}, r"noise_density must be a finite number >= 0"),
        ({"noise_density": math.nan}, "noise_density"),
        ({"bias": (1.0, 2.0)}, "bias must be 3 finite numbers"),
        ({"bias_random_walk": -0.1}, "bias_random_walk"),
        ({"scale": (1.5, 0.0, 0.0)}, r"scale must have each entry in \(-1, 1\)"),
        ({"misalignment_deg": (0.0, 20.0, 0.0)}, r"misalignment_deg must have each entry in \[-10"),
        ({"quantization": -0.01}, "quantization"),
        ({"saturation": 0.0}, r"saturation must be > 0"),
        ({"saturation": math.nan}, "saturation"),
    ],
)
def test_bad_parameters_are_named_with_their_range(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SensorErrors(**kwargs)


def test_apply_rejects_bad_input():
    errors = SensorErrors()
    with pytest.raises(ValueError, match="true must be a finite"):
        errors.apply(np.zeros((5, 2)), 100.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="rate_hz"):
        errors.apply(np.zeros((5, 3)), 0.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="rng"):
        errors.apply(np.zeros((5, 3)), 100.0, 0)
