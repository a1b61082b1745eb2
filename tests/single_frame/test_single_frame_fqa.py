"""FQA specifics (002 section II): half angles, the switch flag, decoupling, parameters."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import frames, sim
from margtrack import quaternion as quat
from margtrack.single_frame.fqa import Fqa, FqaParams
from margtrack.single_frame.fqa_kernel import half_angle
from margtrack.single_frame.quest import Quest

pytestmark = pytest.mark.kernel

DIP = 60.0


def _measure(q, frame="NED"):
    return (quat.rotate_inverse(q, frames.gravity_reference(frame)),
            quat.rotate_inverse(q, frames.mag_reference(frame, DIP, 50.0)))


def test_half_angle_is_exact_over_the_whole_circle_without_trig():
    x = np.concatenate([np.linspace(-np.pi, np.pi, 2001)[1:],
                        [1e-12, -1e-12, 1e-8, np.pi - 1e-9, -np.pi + 1e-9, 0.0]])
    for angle in x:
        c2, s2 = half_angle(np.cos(angle), np.sin(angle))
        assert c2 >= 0.0
        assert abs(c2 - np.cos(angle / 2)) < 2e-16 and abs(s2 - np.sin(angle / 2)) < 2e-16


def test_half_angle_sign_of_zero_is_plus_one():
    # 002 after eq. 31: cos φ = -1, sin φ = 0 must give (0, 1), not (0, 0)
    assert half_angle(-1.0, 0.0) == (0.0, 1.0)
    assert half_angle(-1.0, -0.0) == (0.0, 1.0)


def test_literal_half_angle_formulas_lose_a_tiny_angle_that_fqa_keeps():
    # why eqs. 23-24 are not used literally: sqrt((1 - cos x)/2) of x = 1e-8 rad is 0
    yaw = 1e-8
    assert np.sqrt((1.0 - np.cos(yaw)) / 2.0) == 0.0
    q = quat.from_euler([yaw, 0.0, 0.0])
    acc, mag = _measure(q[None])
    est = Fqa(frame="NED").run(acc=acc, mag=mag, rate_hz=1.0)
    assert quat.angle_between(est.quat[0], q) < 1e-15


def test_upside_down_level_sensor_is_a_roll_of_180_deg():
    q = np.array([0.0, 1.0, 0.0, 0.0])  # roll π in NED: sin φ = 0, cos φ = -1 exactly
    acc, mag = _measure(q[None])
    est = Fqa(frame="NED").run(acc=acc, mag=mag, rate_hz=1.0)
    assert quat.angle_between(est.quat[0], q) < 1e-15


def test_switch_flag_is_on_exactly_while_cos_pitch_is_below_epsilon():
    # a fine sweep of pitch through +90 and -90 deg with roll and yaw, plus noise
    pitch = np.linspace(-np.pi, np.pi, 4001)
    yaw, roll = quat.from_euler([0.7, 0.0, 0.0]), quat.from_euler([0.0, 0.0, -0.4])
    q = quat.multiply(quat.multiply(yaw, quat.from_axis_angle([0.0, 1.0, 0.0], pitch)), roll)
    rng = np.random.default_rng(1)
    acc, mag = _measure(q)
    acc += rng.normal(scale=0.05, size=acc.shape)
    unit = acc / np.linalg.norm(acc, axis=1)[:, None]
    cos_t = np.hypot(unit[:, 1], unit[:, 2])  # 002 eq. 22 on the measured vector
    for eps, alpha in ((0.1, 20.0), (0.2, 45.0), (0.0, 20.0)):
        est = Fqa(frame="NED", epsilon=eps, alpha_deg=alpha).run(acc=acc, mag=mag, rate_hz=1.0)
        np.testing.assert_array_equal(est.outputs["switched"], cos_t < eps)
        assert est.outputs["switched"].sum() == np.sum(cos_t < eps)
    assert np.sum(cos_t < 0.1) > 100


def test_offset_sensor_gives_the_same_orientation_where_both_are_defined():
    rng = np.random.default_rng(2)
    q = quat.normalize(rng.normal(size=(400, 4)))
    acc, mag = _measure(q)
    acc += rng.normal(scale=0.2, size=acc.shape)
    plain = Fqa(frame="NED", epsilon=0.0).run(acc=acc, mag=mag, rate_hz=1.0)
    offset = Fqa(frame="NED", epsilon=0.9, alpha_deg=90.0).run(acc=acc, mag=mag, rate_hz=1.0)
    assert offset.outputs["switched"].mean() > 0.5
    assert np.max(quat.angle_between(plain.quat, offset.quat)) < 1e-12


@pytest.mark.parametrize("offset_deg", [1e-3, 1e-7, 1e-9, 0.0])
def test_pitch_at_the_singularity_is_exact_with_and_without_the_offset_sensor(offset_deg):
    # eq. 22 literally, sqrt(1 - sin²θ), rounds cos θ to 0 within ~1e-7 deg of ±90 deg
    # (roll then undefined); cos θ = sqrt(ā_y² + ā_z²), equal for a unit ā, keeps it
    q = quat.from_euler([0.3, np.radians(90.0 - offset_deg), 0.8])
    acc, mag = _measure(q[None])
    unit = acc[0] / np.linalg.norm(acc[0])
    if 0.0 < offset_deg <= 1e-7:
        assert np.sqrt(1.0 - unit[0] ** 2) == 0.0
    for eps in (0.0, 0.1):
        est = Fqa(frame="NED", epsilon=eps).run(acc=acc, mag=mag, rate_hz=1.0)
        assert est.outputs["switched"][0] == (eps > 0.0)
        assert quat.angle_between(est.quat[0], q) < 1e-15


def test_field_disturbance_moves_only_the_heading_of_fqa_but_tilts_quest():
    rec = sim.simulate(sim.static(10.0, 20.0, q0=quat.from_euler([0.4, 0.3, -0.2])),
                       frame="NED", dip_deg=DIP,
                       mag_disturbances=[sim.rotating_field(1.0, 45.0, 360.0, (1, 1, 1))])
    truth = quat.to_euler(rec.quat_true)
    fqa = quat.to_euler(Fqa(frame="NED").run(rec).quat)
    quest = quat.to_euler(Quest(frame="NED").run(rec).quat)
    assert np.max(np.abs(fqa[:, 1:] - truth[:, 1:])) < 1e-12
    assert np.max(np.abs(fqa[:, 0] - truth[:, 0])) > 0.5
    assert np.max(np.abs(quest[:, 1:] - truth[:, 1:])) > np.radians(5.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"epsilon": 0.2, "alpha_deg": 20.0},
         r"parameter epsilon must be < tan\(alpha_deg / 2\) = 0.1763 for alpha_deg = 20"),
        ({"epsilon": 0.45, "alpha_deg": 45.0}, r"parameter epsilon must be < tan\(alpha_deg / 2\)"),
        ({"epsilon": -0.1}, "parameter epsilon must be a finite number, >= 0"),
        ({"alpha_deg": 0.0}, "parameter alpha_deg must be a finite number, > 0 and <= 90 deg"),
        ({"alpha_deg": 120.0}, "parameter alpha_deg must be a finite number, > 0 and <= 90 deg"),
        ({"epsilon": float("nan")}, "parameter epsilon must be a finite number"),
    ],
)
def test_fqa_parameters_are_validated(kwargs, message):
    with pytest.raises(ValueError, match=message):
        FqaParams(**kwargs)


def test_fqa_defaults_are_the_papers():
    p = FqaParams()
    assert (p.epsilon, p.alpha_deg) == (0.1, 20.0)
