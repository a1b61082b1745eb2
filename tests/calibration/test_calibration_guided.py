"""The guided procedure (000 Appendix B) on simulated recordings of a person following it."""

import dataclasses
import functools

import numpy as np
import pytest
from scipy.linalg import sqrtm

from margtrack import methods, sim
from margtrack import quaternion as qt
from margtrack.bench.broad import evaluate_recording
from margtrack.calibration import GuidedCalibration, run_guided, simulate_procedure
from margtrack.calibration.simulate_procedure import error_profile, procedure_steps

F = 50.0
Q0 = qt.from_axis_angle([0.0, 0.0, 1.0], np.radians(20.0))  # procedure_steps' default start


@functools.cache
def simulated_case(profile):
    errors = error_profile(profile)
    rec = simulate_procedure(*errors, seed=1, field_ut=F)
    return errors, rec, run_guided(rec)


@pytest.fixture(params=["mems", "raw"])
def case(request):
    return simulated_case(request.param)


def test_recovers_the_known_errors(case):
    (gyr, acc, mag), _, result = case
    cal = result.calibration
    # gyroscope: null within 0.02 deg/s (5 s still, white noise 0.05 deg/s per sample,
    # walk 0.001 deg/s/√s), full matrix within 0.2 % and 0.05 deg
    np.testing.assert_allclose(cal.gyr.b, gyr.bias, atol=np.radians(0.02))
    scale, misalignment, rotation = cal.gyr.decompose()
    np.testing.assert_allclose(scale, gyr.scale, atol=2e-3)
    np.testing.assert_allclose(misalignment, gyr.misalignment_deg, atol=0.05)
    assert rotation < 0.05
    np.testing.assert_allclose(1.0 / result.gyro_scale.scale_factor, np.diag(gyr.matrix()),
                               rtol=2e-3)  # 000 eq. 5 averaged per axis
    # accelerometer: 12-parameter fit, 0.1 % / 0.01 m/s² / 0.05 deg
    np.testing.assert_allclose(cal.acc.b, acc.bias, atol=0.01)
    scale, misalignment, _ = cal.acc.decompose()
    np.testing.assert_allclose(scale, acc.scale, atol=1e-3)
    np.testing.assert_allclose(misalignment, acc.misalignment_deg, atol=0.05)
    np.testing.assert_allclose(result.six_position.null_m_s2, acc.bias, atol=0.01)
    # magnetometer: hard iron within 1 % of F; the aligned K equals the truth up to the
    # field unit (det-normalised), within 1 %
    assert np.linalg.norm(cal.mag.b - np.array(mag.bias)) < 0.01 * F
    k_true = mag.matrix() / np.linalg.det(mag.matrix()) ** (1 / 3)
    assert np.linalg.norm(cal.mag.K - k_true, 2) < 0.01
    assert np.linalg.norm(result.ellipsoid.soft_iron - np.real(sqrtm(k_true @ k_true.T)), 2) \
        < 0.01
    # reference vectors (step 18): dip and gravity
    assert result.reference.dip_deg == pytest.approx(sim.DEFAULT_DIP_DEG, abs=0.3)
    assert result.reference.gravity_m_s2 == pytest.approx(9.80665, abs=0.01)
    assert abs(result.reference.heading_offset_deg) < 1.0


def test_calibration_improves_broad_style_errors(case):
    """The same sensor on a minute of random motion, before and after calibration."""
    (gyr, acc, mag), _, result = case
    test = sim.simulate(sim.random_motion(60.0, 100.0, seed=5), gyr_errors=gyr,
                        acc_errors=acc, mag_errors=mag, seed=6)
    calibrated = result.calibration.apply(test)
    for name in ("triad", "gyro"):
        before, _ = evaluate_recording(methods.create(name), test)
        after, _ = evaluate_recording(methods.create(name), calibrated)
        assert after.total_rmse_deg < 0.5 * before.total_rmse_deg
        assert after.heading_rmse_deg < before.heading_rmse_deg
        # what is left is noise: TRIAD heading from 0.5 µT noise on a 25 µT horizontal
        # field is ~1.1 deg rms; gyro drift from the residual null over 60 s
        assert after.total_rmse_deg < 1.5


def test_sample_by_sample_equals_whole_recording():
    _, rec, result = simulated_case("raw")
    machine = GuidedCalibration()
    events = []
    for i in range(rec.n_samples):
        events += machine.add_sample(rec.t[i], rec.gyr[i], rec.acc[i], rec.mag[i])
    assert machine.finished and machine.step == 19
    assert machine.result().calibration == result.calibration
    kinds = [e.kind for e in events]
    assert kinds.count("warning") == 0 and kinds[-1] == "finished"
    done_steps = [e.step for e in events if e.kind == "done"]
    assert set(done_steps) >= {1, 2, 4, 6, 8, 10, 12, 15, 16, 18}


def test_instructions_follow_the_paper_steps():
    machine = GuidedCalibration()
    assert machine.instruction.startswith("step 1:") and "+z down" in machine.instruction
    with pytest.raises(ValueError, match="not finished; still waiting for step 1"):
        machine.result()


def test_a_wrong_turn_is_detected_and_explained():
    """Step 2 done the wrong way (-90 instead of +90 about x): the sensor lands with +y up;
    the machine says to go back and never finishes."""
    steps, _ = procedure_steps()
    first = steps[1]
    steps[1] = dataclasses.replace(first, angle_deg=-first.angle_deg)
    rec = sim.simulate(sim.rotation_sequence(steps, 100.0, q0=Q0), frame="NED", seed=2)
    machine = GuidedCalibration()
    events = machine.add_recording(rec)
    warnings = [e.message for e in events if e.kind == "warning"]
    assert warnings and "-y is down; go back to +z down" in warnings[0]
    assert not machine.finished
    with pytest.raises(ValueError, match="ends before the procedure does"):
        run_guided(rec)


def test_reference_pose_not_facing_north_is_refused():
    """If the last pose faces 40 deg east of north, step 18 asks to turn back."""
    steps, labels = procedure_steps()
    last_turn = max(k for k, (step, _) in enumerate(labels) if step == 18)
    turn = steps[last_turn - 1]
    steps[last_turn - 1] = dataclasses.replace(turn, angle_deg=turn.angle_deg + 40.0)
    rec = sim.simulate(sim.rotation_sequence(steps, 100.0, q0=Q0), frame="NED", seed=3)
    machine = GuidedCalibration()
    warnings = [e.message for e in machine.add_recording(rec) if e.kind == "warning"]
    assert any("+40" in w and "from magnetic north" in w for w in warnings)
    assert not machine.finished
