"""The calibration file: model, units, JSON round trip, apply()."""

import json
import math

import numpy as np
import pytest

from margtrack import sim
from margtrack.calibration import (
    Calibration,
    NoiseDensities,
    ReferenceVectors,
    TriadCalibration,
    load_calibration,
    save_calibration,
)


def full_calibration() -> Calibration:
    rng = np.random.default_rng(0)
    k = np.eye(3) + rng.normal(0.0, 0.01, (3, 3))
    return Calibration(
        gyr=TriadCalibration("gyr", k, (0.01, -0.02, 0.003), "rad/s", "test"),
        acc=TriadCalibration("acc", k.T, (0.1, -0.2, 0.3)),
        mag=TriadCalibration("mag", 1.1 * k, (20.0, -10.0, 35.5), "uT"),
        reference=ReferenceVectors((0.0, 0.01, -9.81), (25.0, 0.2, 43.3), 9.81, 50.0, 60.0, 0.3),
        noise=NoiseDensities(8.7e-5, 1.7e-5, 1e-5, 1.47e-3, 1e-4, 2e-4),
        source="unit test",
        notes=("a", "b"),
    )


def test_json_round_trip_is_exact(tmp_path):
    cal = full_calibration()
    path = save_calibration(cal, tmp_path / "cal.json")
    back = load_calibration(path)
    assert back == cal  # frozen dataclasses of tuples: field-by-field equality, bit for bit
    assert back.to_dict() == cal.to_dict()
    doc = json.loads(path.read_text())
    assert doc["format"] == "margtrack-calibration" and doc["version"] == 1


def test_correct_inverts_the_simulator_model_exactly():
    """A noise-free SensorErrors sensor corrected with K = matrix(), b = bias gives the truth."""
    errors = sim.SensorErrors(bias=(0.1, -0.2, 0.3), scale=(0.01, -0.02, 0.03),
                              misalignment_deg=(1.0, -2.0, 0.5))
    truth = np.random.default_rng(1).normal(0.0, 9.0, (50, 3))
    measured = errors.apply(truth, 100.0, np.random.default_rng(2))
    triad = TriadCalibration("acc", errors.matrix(), errors.bias)
    np.testing.assert_allclose(triad.correct(measured), truth, atol=1e-12)
    scale, misalignment, rotation = triad.decompose()
    np.testing.assert_allclose(scale, errors.scale, atol=1e-12)
    np.testing.assert_allclose(misalignment, errors.misalignment_deg, atol=1e-10)
    assert rotation == pytest.approx(0.0, abs=1e-6)


def test_units_are_converted_on_reading():
    gyr = TriadCalibration.from_dict("gyr", {"unit": "deg/s", "bias": [1.0, -2.0, 0.5]})
    np.testing.assert_allclose(gyr.b, np.radians([1.0, -2.0, 0.5]), rtol=1e-15)
    assert gyr.unit == "rad/s"
    acc = TriadCalibration("acc", bias=(0.01, 0.0, -0.02), unit="g")
    np.testing.assert_allclose(acc.b, np.array([0.01, 0.0, -0.02]) * 9.80665)
    mag = TriadCalibration("mag", bias=(200.0, 0.0, 0.0), unit="mG")
    assert mag.b[0] == pytest.approx(20.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"sensor": "gyr", "bias": (30.0, 0.0, 0.0), "unit": "rad/s"}, "check the unit"),
        ({"sensor": "gyr", "unit": "rpm"}, "unit must be one of"),
        ({"sensor": "baro"}, "sensor must be one of"),
        ({"sensor": "acc", "matrix": np.diag([1.0, 1.0, 0.1])}, "sensitivities"),
        ({"sensor": "acc", "matrix": [[1, 0, 0], [1, 0.2, 0], [0, 0, 1]]}, "nearly singular"),
    ],
)
def test_bad_triads_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TriadCalibration(**kwargs)


def test_file_checks(tmp_path):
    doc = full_calibration().to_dict()
    with pytest.raises(ValueError, match="newer than this margtrack"):
        Calibration.from_dict({**doc, "version": 2})
    with pytest.raises(ValueError, match="not a margtrack calibration"):
        Calibration.from_dict({**doc, "format": "other"})
    with pytest.raises(ValueError, match="unknown calibration keys"):
        Calibration.from_dict({**doc, "extra": 1})
    with pytest.raises(ValueError, match="gravity_m_s2 must be in"):
        Calibration.from_dict({**doc, "reference": {**doc["reference"], "gravity_m_s2": 1.0}})
    with pytest.raises(ValueError, match="deg/s"):
        NoiseDensities(math.radians(0.005) * 180 / math.pi * 100, 0, 0, 0, 0, 0)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_calibration(bad)
    with pytest.raises(FileNotFoundError):
        load_calibration(tmp_path / "missing.json")


def test_apply_is_pure_and_refuses_twice():
    errors = sim.SensorErrors(bias=(0.01, -0.02, 0.03), scale=(0.02, 0.0, -0.01))
    rec = sim.simulate(sim.random_motion(2.0, 100.0, seed=3), gyr_errors=errors, seed=4)
    before = rec.gyr.copy()
    cal = Calibration(gyr=TriadCalibration("gyr", errors.matrix(), errors.bias))
    out = cal.apply(rec)
    np.testing.assert_array_equal(rec.gyr, before)  # input untouched
    truth = sim.body_rate(sim.random_motion(2.0, 100.0, seed=3))
    np.testing.assert_allclose(out.gyr, truth, atol=1e-12)
    np.testing.assert_array_equal(out.acc, rec.acc)  # identity calibration of acc
    np.testing.assert_array_equal(out.mag, rec.mag)  # no mag calibration: left as measured
    assert out.meta["calibration"]["version"] == 1
    with pytest.raises(ValueError, match="already calibrated"):
        cal.apply(out)
