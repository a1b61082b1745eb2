"""Single-frame estimators are exact: against the truth, Davenport and scipy's Wahba solver.

Noise-free inputs cover the whole sphere, pitch at and near ±90 deg and rotations at and
near 180 deg (QUEST's Gibbs-vector singularity). With noise, every Wahba solver must agree
with Davenport (and Davenport with ``scipy.spatial.transform.Rotation.align_vectors``,
which solves the same weighted problem by SVD); TRIAD and FQA with align_vectors given an
infinite weight on gravity (exactly TRIAD's construction).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.single_frame.davenport import Davenport
from margtrack.single_frame.fqa import Fqa
from margtrack.single_frame.gauss_newton import GaussNewton, Newton
from margtrack.single_frame.quest import Quest
from margtrack.single_frame.triad import Triad

pytestmark = pytest.mark.kernel

DIP = 60.0
# tolerance 1e-20 lets the fits converge to rounding (the default 1e-10 stops within
# about 1e-5 rad, see GaussNewtonParams)
EXACT = {
    "triad": lambda f: Triad(frame=f),
    "fqa": lambda f: Fqa(frame=f),
    "quest": lambda f: Quest(frame=f, mag_dip_ref_deg=DIP),
    "davenport": lambda f: Davenport(frame=f, mag_dip_ref_deg=DIP),
    "gauss-newton": lambda f: GaussNewton(frame=f, mag_dip_ref_deg=DIP, tolerance=1e-20),
    "newton": lambda f: Newton(frame=f, mag_dip_ref_deg=DIP, tolerance=1e-20),
}


def _hard_orientations(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    uniform = quat.normalize(rng.normal(size=(n, 4)))
    pitch = quat.from_euler([[0.3, np.pi / 2, 0.1], [-2.0, -np.pi / 2, 1.0],
                             [1.0, np.pi / 2 - 1e-7, -0.4], [2.5, -np.pi / 2 + 1e-4, 3.0],
                             [0.0, np.pi / 2 - 0.1, 0.0], [0.0, 1e-9, 0.0], [0.0, 0.0, np.pi]])
    half_turns = quat.from_axis_angle(rng.normal(size=(6, 3)),
                                      np.pi - np.array([0.0, 1e-12, 1e-9, 1e-6, 1e-3, 0.2]))
    axes = np.array([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    return np.concatenate([uniform, pitch, half_turns, axes])


def _measure(q: np.ndarray, frame: str) -> tuple[np.ndarray, np.ndarray]:
    acc = quat.rotate_inverse(q, frames.gravity_reference(frame))
    mag = quat.rotate_inverse(q, frames.mag_reference(frame, DIP, 48.0))
    return acc, mag


def _noisy(q: np.ndarray, frame: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    acc, mag = _measure(q, frame)
    return acc + rng.normal(scale=0.3, size=acc.shape), mag + rng.normal(scale=4.0, size=mag.shape)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
@pytest.mark.parametrize("name", list(EXACT))
def test_noise_free_samples_give_the_true_orientation_everywhere(name, frame):
    q_true = _hard_orientations(300, seed=1)
    acc, mag = _measure(q_true, frame)
    est = EXACT[name](frame).run(acc=acc, mag=mag, rate_hz=10.0)
    assert np.max(quat.angle_between(est.quat, q_true)) < 1e-9
    assert np.all(est.quat[:, 0] >= 0.0)
    np.testing.assert_allclose(np.linalg.norm(est.quat, axis=1), 1.0, atol=1e-14)
    assert not est.outputs["degenerate"].any()


def _align_vectors(acc, mag, frame, weights):
    refs = [frames.up(frame), frames.mag_reference(frame, DIP)]
    out = []
    for a, m in zip(acc, mag, strict=True):
        rot, _ = Rotation.align_vectors(refs, [a / np.linalg.norm(a), m / np.linalg.norm(m)],
                                        weights=weights)
        out.append(rot.as_quat()[[3, 0, 1, 2]])  # scipy is scalar-last, same meaning
    return np.array(out)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_davenport_equals_scipy_wahba_solution_with_noise(frame):
    q_true = _hard_orientations(120, seed=2)
    acc, mag = _noisy(q_true, frame, seed=3)
    weights = (1.0, 0.3)
    # the screening's norm/dip gate opened: compare every sample
    est = Davenport(frame=frame, mag_dip_ref_deg=DIP, weights=weights, mag_norm_tol=10.0,
                    mag_dip_tol_deg=180.0).run(acc=acc, mag=mag, rate_hz=1.0)
    assert np.max(quat.angle_between(est.quat, _align_vectors(acc, mag, frame, weights))) < 1e-9


@pytest.mark.parametrize("cls", [Triad, Fqa])
def test_triad_and_fqa_equal_scipy_with_gravity_weighted_infinitely(cls):
    q_true = _hard_orientations(120, seed=4)
    acc, mag = _noisy(q_true, "NED", seed=5)
    est = cls(frame="NED").run(acc=acc, mag=mag, rate_hz=1.0)
    expected = _align_vectors(acc, mag, "NED", [np.inf, 1.0])
    assert np.max(quat.angle_between(est.quat, expected)) < 1e-9


@pytest.mark.parametrize("eigenvalue", ["closed-form", "newton"])
@pytest.mark.parametrize("weights", [(1.0, 1.0), (1.0, 0.1), (5.0, 2.0)])
def test_quest_equals_davenport_with_noise_including_half_turns(weights, eigenvalue):
    # the paper's QUEST finds λ_max by Newton-Raphson on the characteristic equation;
    # both ways give Davenport's eigenvector
    q_true = _hard_orientations(300, seed=6)
    acc, mag = _noisy(q_true, "ENU", seed=7)
    quest = Quest(mag_dip_ref_deg=DIP, weights=weights, eigenvalue=eigenvalue).run(
        acc=acc, mag=mag, rate_hz=1.0)
    dav = Davenport(mag_dip_ref_deg=DIP, weights=weights).run(acc=acc, mag=mag, rate_hz=1.0)
    assert np.max(quat.angle_between(quest.quat, dav.quat)) < 1e-9


def test_newton_eigenvalue_reaches_the_closed_form_lambda():
    # λ_max² = a1² + a2² + 2 a1 a2 cos(θ_r - θ_b) for two observations (Shuster & Oh)
    from margtrack.single_frame.quest_kernel import newton_eigenvalue

    rng = np.random.default_rng(3)
    for _ in range(200):
        a1, a2 = rng.uniform(0.1, 5.0, 2)
        r1, r2, b1, b2 = (v / np.linalg.norm(v) for v in rng.normal(size=(4, 3)))
        b = a1 * np.outer(r1, b1) + a2 * np.outer(r2, b2)
        lam, _ = newton_eigenvalue(a1 + a2, *b.ravel())
        cos_diff = r1 @ r2 * (b1 @ b2) + np.linalg.norm(np.cross(r1, r2)) * np.linalg.norm(
            np.cross(b1, b2))
        assert lam == pytest.approx(np.sqrt(a1**2 + a2**2 + 2 * a1 * a2 * cos_diff), rel=1e-12)


def test_quest_turns_the_reference_frame_exactly_near_half_turns():
    # noise-free: the rotation angle of q is known; sequential rotation happens when
    # q_w² < 0.01, i.e. beyond 2 acos(0.1) = 168.52 deg, and nowhere else
    q_true = _hard_orientations(2000, seed=8)
    acc, mag = _measure(q_true, "NED")
    est = Quest(frame="NED", mag_dip_ref_deg=DIP).run(acc=acc, mag=mag, rate_hz=1.0)
    angle = np.degrees(quat.angle_between(q_true, [1.0, 0.0, 0.0, 0.0]))
    rotated = est.outputs["sequential_rotation"] != 0
    limit = np.degrees(2 * np.arccos(0.1))
    margin = np.abs(angle - limit) > 1e-6
    np.testing.assert_array_equal(rotated[margin], (angle > limit)[margin])
    assert rotated.sum() > 100  # the branch really ran


@pytest.mark.parametrize("mag_weight", [1.0, 0.4])
def test_newton_equals_davenport_with_weights_one_and_rho_squared(mag_weight):
    q_true = _hard_orientations(200, seed=9)
    acc, mag = _noisy(q_true, "NED", seed=10)
    newton = Newton(frame="NED", mag_dip_ref_deg=DIP, mag_weight=mag_weight, tolerance=1e-20)
    est = newton.run(acc=acc, mag=mag, rate_hz=1.0)
    dav = Davenport(frame="NED", mag_dip_ref_deg=DIP, weights=(1.0, mag_weight**2))
    assert np.max(quat.angle_between(est.quat, dav.run(acc=acc, mag=mag, rate_hz=1.0).quat)) < 1e-9


def test_gauss_newton_reaches_davenport_within_its_linear_convergence():
    # With noise Gauss-Newton converges linearly (the residual's curvature is ignored) and
    # stops once Q changes by less than rounding, ~1e-14 sqrt(Q) ≈ 1e-15: the iterate is
    # then within about sqrt(1e-15 / λ) ≈ 1e-7 rad of the minimum; 1e-6 bounds it.
    q_true = _hard_orientations(200, seed=11)
    acc, mag = _noisy(q_true, "NED", seed=12)
    est = GaussNewton(frame="NED", mag_dip_ref_deg=DIP, mag_weight=0.5, tolerance=1e-20,
                      max_iterations=100).run(acc=acc, mag=mag, rate_hz=1.0)
    dav = Davenport(frame="NED", mag_dip_ref_deg=DIP, weights=(1.0, 0.25))
    dav = dav.run(acc=acc, mag=mag, rate_hz=1.0)
    assert np.max(quat.angle_between(est.quat, dav.quat)) < 1e-6
    assert np.median(quat.angle_between(est.quat, dav.quat)) < 1e-9


def test_fqa_equals_triad_with_noise_everywhere():
    q_true = _hard_orientations(500, seed=13)
    acc, mag = _noisy(q_true, "ENU", seed=14)
    fqa = Fqa(epsilon=0.2, alpha_deg=45.0).run(acc=acc, mag=mag, rate_hz=1.0)
    triad = Triad().run(acc=acc, mag=mag, rate_hz=1.0)
    assert np.max(quat.angle_between(fqa.quat, triad.quat)) < 1e-12


def test_measured_dip_equals_the_given_dip_for_noise_free_data():
    q_true = _hard_orientations(20, seed=15)
    acc, mag = _measure(q_true, "ENU")
    est = Quest()
    out = est.run(acc=acc, mag=mag, rate_hz=1.0)
    assert np.degrees(est.state.dip_rad[0]) == pytest.approx(DIP, abs=1e-12)
    assert np.max(quat.angle_between(out.quat, q_true)) < 1e-9
