"""margtrack.joint on a simulated two-segment chain with known lever arms and relative truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from chain_sim import angle_deg, heading_deg, simulate_chain

from margtrack import quaternion as qt
from margtrack.estimator.flags import Flag
from margtrack.joint import JointParams, estimate_lever_arms, pair_inputs, relative_orientation
from margtrack.joint.kernel import _level, _set_rows, centre_forces, rate_derivative
from margtrack.recording import Recording
from margtrack.units import UnitError

pytestmark = pytest.mark.kernel


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.fixture(scope="module")
def chain():
    return simulate_chain(duration_s=60, rate_hz=100, seed=0)


@pytest.fixture(scope="module")
def online(chain):
    return relative_orientation(chain.parent, chain.child)


@pytest.fixture(scope="module")
def offline(chain):
    return relative_orientation(chain.parent, chain.child, offline=True)


# -- the pieces ------------------------------------------------------------------------------


def test_rate_derivative_matches_the_analytic_derivative():
    t = np.arange(0, 2, 0.01)
    w = np.stack([np.sin(3 * t), np.cos(2 * t), t**2], axis=1)
    exact = np.stack([3 * np.cos(3 * t), -2 * np.sin(2 * t), 2 * t], axis=1)
    inner = slice(2, -2)
    assert np.max(np.abs(rate_derivative(t, w)[inner] - exact[inner])) < 2e-6  # five-point
    assert np.max(np.abs(rate_derivative(t, w) - exact)) < 2e-3  # edges: second order
    jitter = t + 0.002 * np.sin(7 * t)  # an irregular clock: second order everywhere
    w_j = np.stack([np.sin(3 * jitter), np.cos(2 * jitter), jitter**2], axis=1)
    exact_j = np.stack([3 * np.cos(3 * jitter), -2 * np.sin(2 * jitter), 2 * jitter], axis=1)
    assert np.max(np.abs(rate_derivative(jitter, w_j) - exact_j)) < 3e-3


def test_centre_forces_agree_in_the_earth_frame_only_with_the_right_lever_arms(chain):
    gyr = np.stack([chain.parent.gyr, chain.child.gyr])
    acc = np.stack([chain.parent.acc, chain.child.acc])

    def link(r: np.ndarray) -> float:
        c = centre_forces(chain.parent.t, gyr, acc, r)
        return rms(qt.rotate(chain.q_parent, c[0]) - qt.rotate(chain.q_child, c[1]))

    # sensor noise (0.05 m/s², and the rate's derivative times 0.18 m) leaves about 0.2
    assert link(chain.lever_arms_m) < 0.3
    assert link(-chain.lever_arms_m) > 1.5  # the sign: joint centre to sensor
    assert link(np.zeros((2, 3))) > 1.0


def test_measurement_rows_are_the_derivatives_of_the_measurement():
    """H (link rows, inclination rows) against central differences of the measurement."""
    rng = np.random.default_rng(3)
    q = qt.normalize(rng.standard_normal((2, 4)))
    c = rng.standard_normal((2, 3)) * 5.0

    def measure(eps: np.ndarray) -> np.ndarray:
        v = [qt.rotate(qt.multiply(qt.from_rotvec(eps[3 * s:3 * s + 3]), q[s]), c[s])
             for s in range(2)]
        return np.concatenate([v[0] - v[1], 0.5 * (v[0] + v[1])])

    v1, v2 = qt.rotate(q[0], c[0]), qt.rotate(q[1], c[1])
    h = np.zeros((6, 6))
    _set_rows(v1, v2, h)
    step = 1e-6
    numeric = np.stack([(measure(step * e) - measure(-step * e)) / (2 * step)
                        for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(h, numeric, atol=1e-6)


def test_levelling_turns_the_specific_force_up_about_a_horizontal_axis():
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = qt.normalize(rng.standard_normal(4))
        c = rng.standard_normal(3)
        new = q.copy()
        _level(c, new, np.zeros(3))
        np.testing.assert_allclose(qt.rotate(new, c), [0, 0, np.linalg.norm(c)], atol=1e-9)
        turn = qt.to_rotvec(qt.multiply(new, qt.conjugate(q)))  # earth frame
        assert abs(turn[2]) < 1e-9  # about a horizontal axis: the heading is kept


def test_block_tridiagonal_solve_matches_a_dense_solve():
    from margtrack.joint.offline import _solve

    rng = np.random.default_rng(11)
    n = 7
    blocks = []
    for _ in range(n):
        m = rng.standard_normal((6, 6))
        blocks.append(m @ m.T + 6 * np.eye(6))
    off = rng.uniform(0.5, 2.0, n - 1)
    dense = np.zeros((6 * n, 6 * n))
    for k in range(n):
        dense[6 * k:6 * k + 6, 6 * k:6 * k + 6] = blocks[k]
    for k in range(n - 1):
        dense[6 * k + np.arange(6), 6 * k + 6 + np.arange(6)] = -off[k]
        dense[6 * k + 6 + np.arange(6), 6 * k + np.arange(6)] = -off[k]
    rhs = rng.standard_normal((n, 6))
    upper = np.triu(np.array(blocks))  # _solve reads the upper triangles only
    x = _solve(upper, off, rhs)
    np.testing.assert_allclose(x.ravel(), np.linalg.solve(dense, rhs.ravel()), atol=1e-12)


# -- lever arms ------------------------------------------------------------------------------


def test_lever_arms_are_estimated_within_millimetres(online, chain):
    arms = online.lever_arms
    assert arms.source == "estimated" and arms.samples == chain.parent.n_samples
    err = np.abs(arms.r_m - chain.lever_arms_m)
    # noise 0.05 m/s² and 0.005 rad/s over a minute: a few tenths of a mm of spread, plus
    # the small bias of a gyroscope offset in K
    assert err.max() < 0.003, err
    assert np.all(np.isfinite(arms.std_m)) and np.all(arms.std_m > 0)
    assert arms.std_m.max() < 0.002


def test_a_hinge_leaves_the_lever_arms_along_its_axis_undetermined():
    hinge = simulate_chain(duration_s=60, rate_hz=100, seed=1, hinge=True)
    inputs = pair_inputs(hinge.parent, hinge.child)
    arms = estimate_lever_arms(inputs.t, inputs.gyr, inputs.acc)
    across = [0, 2]  # the hinge turns about each sensor's y axis
    err = arms.r_m - hinge.lever_arms_m
    assert np.abs(err[:, across]).max() < 0.004
    # along the axis only noise tells the points apart: both lever arms move together (the
    # joint centre slides along the axis) and their std says they are the least certain
    assert abs(err[0, 1] - err[1, 1]) < 0.002
    assert arms.std_m[:, 1].min() > 2 * arms.std_m[:, across].max()


def test_given_lever_arms_are_used_as_given(chain):
    est = relative_orientation(chain.parent, chain.child, lever_arms=chain.lever_arms_m)
    assert est.lever_arms.source == "given"
    np.testing.assert_array_equal(est.lever_arms.r_m, chain.lever_arms_m)
    assert np.isnan(est.lever_arms.std_m).all()
    assert rms(angle_deg(est.quat, chain.q_rel)[500:]) < 3.0
    with pytest.raises(ValueError, match=r"shape \(2, 3\)"):
        relative_orientation(chain.parent, chain.child, lever_arms=[0.1, 0.2, 0.3])


# -- the relative orientation ----------------------------------------------------------------


def test_online_and_offline_follow_the_true_relative_orientation(online, offline, chain):
    assert online.method == "joint_online" and offline.method == "joint_offline"
    assert online.quat.shape == (chain.parent.n_samples, 4)
    np.testing.assert_allclose(np.linalg.norm(online.quat, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(
        online.quat, qt.multiply(qt.conjugate(online.quat_parent), online.quat_child),
        atol=1e-12)
    # the first 5 s: the relative heading converges from its first guess
    on = rms(angle_deg(online.quat, chain.q_rel)[500:])
    off = rms(angle_deg(offline.quat, chain.q_rel))
    assert on < 3.0, on
    assert off < 1.0, off
    assert off < on
    assert not (online.flags & ~np.uint16(Flag.INITIALISING)).any()
    assert not offline.flags.any()


def test_inclinations_of_each_sensor_are_right_too(offline, chain):
    """Each sensor's orientation is right up to a common heading (no magnetometer)."""
    for est, truth in ((offline.quat_parent, chain.q_parent), (offline.quat_child, chain.q_child)):
        up_est = qt.rotate_inverse(est, [0.0, 0.0, 1.0])
        up_true = qt.rotate_inverse(truth, [0.0, 0.0, 1.0])
        tilt = np.degrees(np.arccos(np.clip(np.sum(up_est * up_true, axis=1), -1, 1)))
        assert rms(tilt) < 1.0


def test_two_independent_6d_filters_drift_in_relative_heading(online, chain):
    """The constraint is what holds the relative heading: two vqf 6-D filters let it drift."""
    vqf = pytest.importorskip("vqf")
    quats = []
    for rec in (chain.parent, chain.child):
        filt = vqf.VQF(float(np.median(np.diff(rec.t))))
        quats.append(filt.updateBatch(np.ascontiguousarray(rec.gyr),
                                      np.ascontiguousarray(rec.acc))["quat6D"])
    rel_6d = qt.multiply(qt.conjugate(quats[0]), quats[1])
    head_6d = rms(heading_deg(rel_6d, chain.q_rel, chain.q_parent)[500:])
    head_joint = rms(heading_deg(online.quat, chain.q_rel, chain.q_parent)[500:])
    assert head_6d > 10.0, head_6d
    assert head_6d > 5 * head_joint, (head_6d, head_joint)


def test_different_rates_are_brought_onto_one_clock(chain):
    c = chain.child
    child = dataclasses.replace(c, t=c.t[::2], gyr=c.gyr[::2], acc=c.acc[::2])
    est = relative_orientation(chain.parent, child)
    assert any("merged onto 50 Hz" in n for n in est.notes)
    assert est.n_samples == child.n_samples
    truth = chain.q_rel[::2][: est.n_samples]
    assert rms(angle_deg(est.quat, truth)[250:]) < 3.5


# -- the input policy ------------------------------------------------------------------------


def test_held_samples_and_gaps_are_flagged_and_skipped(chain):
    child = dataclasses.replace(chain.child, meta={"invalid_samples": {"acc": [1000, 1001],
                                                                        "gyr": [3000]}})
    keep = np.ones(chain.parent.n_samples, bool)
    keep[2000:2050] = False  # half a second lost from both
    p = chain.parent
    parent = dataclasses.replace(p, t=p.t[keep], gyr=p.gyr[keep], acc=p.acc[keep])
    child = dataclasses.replace(child, t=child.t[keep], gyr=child.gyr[keep], acc=child.acc[keep])
    est = relative_orientation(parent, child)
    assert est.flags[1000] & Flag.INVALID and est.flags[1000] & Flag.ACC_IGNORED
    assert est.flags[3000] & Flag.INVALID and not est.flags[3000] & Flag.ACC_IGNORED
    assert est.flags[2000] == Flag.GAP
    assert np.all(np.isfinite(est.quat))
    truth = chain.q_rel[keep]
    assert rms(angle_deg(est.quat, truth)[500:]) < 3.5  # re-converges after the gap


def test_a_gyroscope_in_deg_per_s_is_refused_with_the_fix(chain):
    wrong = dataclasses.replace(chain.child, gyr=np.degrees(chain.child.gyr))
    with pytest.raises(UnitError, match=r"child.*with_units\(gyr='deg/s'\)"):
        relative_orientation(chain.parent, wrong)


def test_recordings_without_a_common_span_are_refused_with_the_fix(chain):
    later = dataclasses.replace(chain.child, t=chain.child.t + 100.0)
    with pytest.raises(ValueError, match="align_start"):
        relative_orientation(chain.parent, later)
    aligned = relative_orientation(chain.parent, later, align_start=True)
    assert aligned.n_samples == chain.parent.n_samples


def test_a_still_recording_cannot_give_lever_arms(chain):
    t = np.arange(500) / 100.0
    still = Recording(t=t, gyr=np.zeros((500, 3)), acc=np.tile([0, 0, 9.81], (500, 1)))
    with pytest.raises(ValueError, match="give the lever arms"):
        relative_orientation(still, still)
    est = relative_orientation(still, still, lever_arms=np.zeros((2, 3)))
    np.testing.assert_allclose(est.quat[-1], [1, 0, 0, 0], atol=1e-9)


def test_parameters_are_validated_with_their_range():
    with pytest.raises(ValueError, match="link_noise_m_s2 must be a finite number, > 0"):
        JointParams(link_noise_m_s2=0.0)
    with pytest.raises(ValueError, match="gyr_timing must be one of"):
        JointParams(gyr_timing="middle")
