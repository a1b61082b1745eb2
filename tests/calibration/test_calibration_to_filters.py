"""The calibration file reaches the filters: reference field and noise densities by declaration."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest

from margtrack import methods
from margtrack.calibration import Calibration
from margtrack.calibration.allan import NoiseDensities
from margtrack.calibration.reference import ReferenceVectors
from margtrack.estimator.params import Params, param, specs

REFERENCE = ReferenceVectors((0.0, 0.0, 9.81), (0.0, 25.0, -43.3), 9.81, 50.0, 60.0, 0.0)
NOISE = NoiseDensities(
    gyr_noise_density_rad_s_sqrt_hz=2e-4,
    gyr_bias_walk_rad_s2_sqrt_hz=3e-5,
    gyr_bias_instability_rad_s=1e-4,
    acc_noise_density_m_s2_sqrt_hz=2e-3,
    acc_bias_walk_m_s3_sqrt_hz=1e-4,
    acc_bias_instability_m_s2=1e-3,
)


@dataclass(frozen=True)
class _Noisy(Params):
    walk_deg_s_sqrt_s: float = param(
        0.01, unit="deg/s/√s", gt=0, help="bias walk",
        calibrated_by="noise.gyr_bias_walk_rad_s2_sqrt_hz",
    )
    gyr_noise_rad_s_sqrt_hz: float = param(
        1e-3, unit="rad/s/√Hz", gt=0, help="white",
        calibrated_by="noise.gyr_noise_density_rad_s_sqrt_hz",
    )


def test_declared_parameters_take_the_file_values_with_units_converted():
    values = Calibration(reference=REFERENCE, noise=NOISE).parameter_values(_Noisy)
    assert values["mag_norm_ref"] == 50.0 and values["mag_dip_ref_deg"] == 60.0
    assert values["walk_deg_s_sqrt_s"] == pytest.approx(math.degrees(3e-5), rel=1e-15)
    assert values["gyr_noise_rad_s_sqrt_hz"] == 2e-4
    _Noisy(**values)  # they pass the declaration


def test_a_file_without_noise_or_reference_sets_nothing():
    assert Calibration().parameter_values(_Noisy) == {}
    only_ref = Calibration(reference=REFERENCE).parameter_values(_Noisy)
    assert set(only_ref) == {"mag_norm_ref", "mag_dip_ref_deg"}


@pytest.mark.parametrize("name", methods.available())
def test_every_method_takes_the_reference_field(name):
    cls = methods.get(name)
    values = Calibration(reference=REFERENCE, noise=NOISE).parameter_values(cls.params_type)
    assert values["mag_dip_ref_deg"] == 60.0 and values["mag_norm_ref"] == 50.0
    est = methods.create(name, values)
    assert est.params.mag_dip_ref_deg == 60.0


def test_the_kalman_filters_and_robust_declare_their_noise_sources():
    for name in ("bias-kf", "robust"):
        sources = {s.calibrated_by for s in specs(methods.get(name).params_type)}
        assert "noise.gyr_bias_walk_rad_s2_sqrt_hz" in sources, name
