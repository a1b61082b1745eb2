"""Gauss-Newton and Newton fits (001 eqs. 20-26): Jacobian, Hessian, convergence, outputs."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.single_frame.gauss_newton import GaussNewton, GaussNewtonParams, Newton
from margtrack.single_frame.gauss_newton_kernel import (
    criterion,
    gauss_newton_solve,
    gauss_newton_step,
    newton_solve,
)

pytestmark = pytest.mark.kernel

DIP = 60.0
UP = frames.up("NED")
FIELD = frames.mag_reference("NED", DIP)


def _unit(v):
    return v / np.linalg.norm(v)


def _problem(seed: int, noise: bool = True):
    rng = np.random.default_rng(seed)
    q = quat.normalize(rng.normal(size=4))
    g = quat.rotate_inverse(q, UP) + (rng.normal(scale=0.05, size=3) if noise else 0.0)
    m = quat.rotate_inverse(q, FIELD) + (rng.normal(scale=0.05, size=3) if noise else 0.0)
    return q, _unit(g), _unit(m), rng


def _f(n, g, m):
    """M(n) y0 of 001 eqs. 20-21 with R(n) of eq. 6 for any 4-vector n: (6,)."""
    def rot(v):
        return quat.multiply(quat.multiply(n, np.r_[0.0, v]), quat.conjugate(n))[1:]

    return np.r_[rot(g), rot(m)]


def _residual(n, g, m, rho):
    eps = np.r_[UP, FIELD] - _f(n, g, m)
    eps[3:] *= rho  # magnetic rows weighted (000 eq. 17)
    return eps


def _jacobian_fd(n, g, m, rho, h=1e-6):
    # J = -∂(M y0)/∂n (001 eq. 23) = ∂ε/∂n, central differences
    cols = [(_residual(n + h * e, g, m, rho) - _residual(n - h * e, g, m, rho)) / (2 * h)
            for e in np.eye(4)]
    return np.array(cols).T


def _q_of(n, g, m, rho):
    eps = _residual(n, g, m, rho)
    return eps @ eps


def test_criterion_is_001_eq_20():
    _, g, m, rng = _problem(1)
    n = rng.normal(size=4)
    assert criterion(*g, *m, *UP, *FIELD, *n, 0.7) == pytest.approx(_q_of(n, g, m, 0.7), rel=1e-13)


@pytest.mark.parametrize("rho", [1.0, 0.3])
def test_gauss_newton_step_is_001_eq_22_with_a_finite_difference_jacobian(rho):
    _, g, m, rng = _problem(2)
    n = rng.normal(size=4)
    ok, *n_new, q = gauss_newton_step(*g, *m, *UP, *FIELD, *n, rho)
    J = _jacobian_fd(n, g, m, rho)
    eps = _residual(n, g, m, rho)
    expected = n - np.linalg.solve(J.T @ J, J.T @ eps)
    assert ok
    np.testing.assert_allclose(n_new, expected, rtol=1e-7, atol=1e-8)
    assert q == pytest.approx(eps @ eps, rel=1e-13)


def _jacobian_exact(n, g, m, rho):
    """J = ∂ε/∂n from ∂(n ⊗ v ⊗ n*)/∂n_k = e_k ⊗ v ⊗ n* + n ⊗ v ⊗ e_k*, in numpy."""
    def column(e):
        def d(v):
            pv = np.r_[0.0, v]
            return -(quat.multiply(quat.multiply(e, pv), quat.conjugate(n))
                     + quat.multiply(quat.multiply(n, pv), quat.conjugate(e)))[1:]
        return np.r_[d(g), rho * d(m)]
    return np.array([column(e) for e in np.eye(4)]).T


def test_gauss_newton_update_in_closed_form_solves_the_formed_normal_equations():
    """The step's closed form (Woodbury on JᵀJ = 4(c I - U Uᵀ)) against numpy's solve of
    the normal equations formed from the exact Jacobian: random vectors that do not fit one
    rotation, guesses of any norm and field weights from 0.1 to 3."""
    rng = np.random.default_rng(11)
    worst = 0.0
    for _ in range(200):
        g, m = _unit(rng.normal(size=3)), _unit(rng.normal(size=3))
        n = rng.normal(size=4) * rng.uniform(0.3, 3.0)
        rho = rng.uniform(0.1, 3.0)
        ok, *n_new, _ = gauss_newton_step(*g, *m, *UP, *FIELD, *n, rho)
        J = _jacobian_exact(n, g, m, rho)
        expected = n - np.linalg.solve(J.T @ J, J.T @ _residual(n, g, m, rho))
        assert ok
        worst = max(worst, np.abs(np.array(n_new) - expected).max() / np.abs(expected).max())
    assert worst < 1e-9


@pytest.mark.parametrize("rho", [1.0, 0.0])
def test_gauss_newton_update_is_singular_for_parallel_vectors_or_no_field_weight(rho):
    """JᵀJ is singular when the body vectors are parallel (its 2 x 2 Woodbury block has
    determinant ρ² D, D = 0) or ρ = 0 (the field's rows vanish): no update, n unchanged."""
    g = _unit(np.array([0.2, -0.4, 0.9]))
    m = g if rho > 0.0 else _unit(np.array([0.5, 0.1, -0.3]))
    n = np.array([0.9, 0.1, -0.3, 0.2])
    ok, *n_new, _ = gauss_newton_step(*g, *m, *UP, *FIELD, *n, rho)
    assert not ok
    np.testing.assert_array_equal(n_new, n)
    J = _jacobian_exact(n, g, m, rho)  # numpy agrees: a rank below 4
    assert np.linalg.matrix_rank(J.T @ J, tol=1e-9 * np.abs(J.T @ J).max()) < 4


def test_newton_uses_the_true_hessian_and_001_eq_26_as_printed_is_minus_half_of_it():
    q, g, m, rng = _problem(3)
    # 20 deg off, where the full Newton step decreases Q (no halving)
    n = quat.multiply(quat.from_axis_angle(rng.normal(size=3), np.radians(20.0)), q)
    rho, h = 0.8, 1e-4
    eye = np.eye(4)
    grad = np.array([(_q_of(n + h * e, g, m, rho) - _q_of(n - h * e, g, m, rho)) / (2 * h)
                     for e in eye])
    hess = np.array([[(_q_of(n + h * a + h * b, g, m, rho) - _q_of(n + h * a - h * b, g, m, rho)
                       - _q_of(n - h * a + h * b, g, m, rho) + _q_of(n - h * a - h * b, g, m, rho))
                      / (4 * h * h) for b in eye] for a in eye])
    # eq. 25: ∇Q = -2 (∂M y0)ᵀ ε = 2 Jᵀ ε
    J = _jacobian_fd(n, g, m, rho)
    eps = _residual(n, g, m, rho)
    np.testing.assert_allclose(grad, 2.0 * J.T @ eps, rtol=1e-6, atol=1e-9)
    # eq. 26 as printed: [∂²M y0] ε - (∂M y0)ᵀ(∂M y0), the second derivatives by differences
    def r(dn):
        return _residual(n + dn, g, m, rho)

    d2 = np.array([[(r(h * a + h * b) - r(h * a - h * b) - r(h * b - h * a) + r(-h * a - h * b))
                    / (4 * h * h) for b in eye] for a in eye])  # ∂²ε/∂n_a∂n_b = -∂²(M y0)
    printed = -(d2 @ eps) - J.T @ J
    np.testing.assert_allclose(printed, -0.5 * hess, rtol=1e-5, atol=1e-7)
    # Newton's first step from n uses H (not the printed matrix)
    ok, w, x, y, z, _, _ = newton_solve(*g, *m, *UP, *FIELD, *n, rho, 0.0, 1)
    step = n - np.linalg.solve(hess, grad)
    assert ok
    np.testing.assert_allclose([w, x, y, z], quat.canonical(step / np.linalg.norm(step)),
                               atol=1e-6)


@pytest.mark.parametrize("solve", [gauss_newton_solve, newton_solve])
def test_noise_free_fit_converges_from_60_deg_in_a_few_iterations(solve):
    q, g, m, rng = _problem(4, noise=False)
    guess = quat.multiply(quat.from_axis_angle(rng.normal(size=3), np.radians(60.0)), q)
    ok, *n, iterations, crit = solve(*g, *m, *UP, *FIELD, *guess, 1.0, 1e-24, 20)
    assert ok and iterations <= 6 and crit <= 1e-24
    assert quat.angle_between(n, q) < 1e-11


def test_tolerance_and_iteration_cap_decide_where_it_stops():
    q, g, m, rng = _problem(5, noise=False)
    guess = quat.multiply(quat.from_axis_angle(rng.normal(size=3), np.radians(40.0)), q)
    *_, its, crit = gauss_newton_solve(*g, *m, *UP, *FIELD, *guess, 1.0, 1e-10, 20)
    *_, its_before, crit_before = gauss_newton_solve(*g, *m, *UP, *FIELD, *guess, 1.0, 1e-10,
                                                     its - 1)
    assert crit <= 1e-10 < crit_before  # stopped at the first iterate below the tolerance
    assert its_before == its - 1
    _, *n1, its1, _ = gauss_newton_solve(*g, *m, *UP, *FIELD, *guess, 1.0, 0.0, 1)
    _, *step, _ = gauss_newton_step(*g, *m, *UP, *FIELD, *guess, 1.0)
    assert its1 == 1
    np.testing.assert_allclose(n1, quat.canonical(np.array(step) / np.linalg.norm(step)),
                               atol=1e-15)


def test_kernel_level_solver_can_be_called_from_another_kernel():
    @njit
    def fit_many(acc, mag, up, field, guess, out):
        for i in range(acc.shape[0]):
            _, w, x, y, z, _, _ = gauss_newton_solve(
                acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2],
                up[0], up[1], up[2], field[0], field[1], field[2],
                guess[i, 0], guess[i, 1], guess[i, 2], guess[i, 3], 1.0, 1e-20, 20)
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = w, x, y, z

    rng = np.random.default_rng(6)
    q = quat.normalize(rng.normal(size=(20, 4)))
    acc, mag = quat.rotate_inverse(q, UP), quat.rotate_inverse(q, FIELD)
    guess = quat.multiply(quat.from_axis_angle(rng.normal(size=(20, 3)), 0.3), q)
    out = np.empty((20, 4))
    fit_many(acc, mag, UP, FIELD, guess, out)
    assert np.max(quat.angle_between(out, q)) < 1e-10


@pytest.mark.parametrize("cls", [GaussNewton, Newton])
def test_outputs_report_iterations_and_the_criterion(cls):
    rng = np.random.default_rng(7)
    q = quat.normalize(rng.normal(size=(50, 4)))
    acc = quat.rotate_inverse(q, 9.81 * UP) + rng.normal(scale=0.2, size=(50, 3))
    mag = quat.rotate_inverse(q, FIELD) + rng.normal(scale=0.02, size=(50, 3))
    est = cls(frame="NED", mag_dip_ref_deg=DIP, mag_weight=0.5).run(acc=acc, mag=mag, rate_hz=1.0)
    its, crit = est.outputs["iterations"], est.outputs["criterion"]
    assert its.dtype == np.int32 and np.all((its >= 0) & (its <= 10))
    # the criterion at the converged unit quaternion is the residual of the LS fit
    for i in range(0, 50, 7):
        expected = _q_of(est.quat[i], _unit(acc[i]), _unit(mag[i]), 0.5)
        assert crit[i] == pytest.approx(expected, rel=1e-3)


def test_tracking_needs_one_iteration_from_the_previous_estimate():
    # 001 5.1: small errors between samples, one step suffices (vs the converged fit)
    t = np.arange(200) * 0.01
    q = quat.from_rotvec(np.c_[0.3 * t, np.sin(t), 0.5 * t])
    acc, mag = quat.rotate_inverse(q, 9.81 * UP), quat.rotate_inverse(q, FIELD)
    one = GaussNewton(frame="NED", mag_dip_ref_deg=DIP, max_iterations=1).run(acc=acc, mag=mag, t=t)
    assert np.all(one.outputs["iterations"][1:] <= 1)
    # noise-free Gauss-Newton converges quadratically: one step from an error e0 (here the
    # motion between samples, <= 0.012 rad) leaves about e0² (1.5e-4)
    e0 = np.max(quat.angle_between(q[1:], q[:-1]))
    assert np.max(quat.angle_between(one.quat, q)) < e0**2


def test_reset_q0_is_the_first_initial_guess():
    q, g, m, _ = _problem(8, noise=False)
    guess = quat.multiply(quat.from_axis_angle([1.0, 0.0, 0.0], 0.2), q)
    est = GaussNewton(frame="NED", mag_dip_ref_deg=DIP, max_iterations=1)
    est.reset(guess)
    out = est.run(acc=9.81 * g[None], mag=m[None], rate_hz=1.0)
    _, w, x, y, z, its, _ = gauss_newton_solve(*g, *m, *UP, *FIELD, *guess, 1.0, 1e-10, 1)
    np.testing.assert_allclose(out.quat[0], [w, x, y, z], atol=1e-15)
    assert out.outputs["iterations"][0] == its == 1


@pytest.mark.parametrize("cls", [GaussNewton, Newton])
def test_a_jump_of_180_deg_in_heading_restarts_from_triad(cls):
    q1 = quat.from_euler([0.2, 0.3, -0.1])
    q2 = quat.from_euler([0.2 + np.pi, 0.3, -0.1])
    q = np.array([q1, q2])
    acc, mag = quat.rotate_inverse(q, 9.81 * UP), quat.rotate_inverse(q, FIELD)
    est = cls(frame="NED", mag_dip_ref_deg=DIP, mag_weight=0.2, tolerance=1e-20).run(
        acc=acc, mag=mag, rate_hz=1.0)
    assert np.max(quat.angle_between(est.quat, q)) < 1e-10


def test_gauss_newton_safeguard_keeps_an_ill_conditioned_sample_from_diverging():
    # acceleration nearly antiparallel to the field, references 18 deg apart from the
    # measured angle: the plain eq. 22 iteration blows the criterion up by 10³
    g = _unit(np.array([0.02, 0.0, -1.0]))
    m = _unit(np.array([0.0, 0.005, 1.0]))
    n = np.array([0.9, 0.1, 0.3, 0.2])
    q0 = criterion(*g, *m, *UP, *FIELD, *n, 1.0)
    raw = []
    for _ in range(5):
        _, *n, q = gauss_newton_step(*g, *m, *UP, *FIELD, *n, 1.0)
        raw.append(q)
    assert max(raw) > 1000 * q0
    ok, *n, _, crit = gauss_newton_solve(*g, *m, *UP, *FIELD, 0.9, 0.1, 0.3, 0.2, 1.0,
                                           1e-10, 30)
    assert ok and np.all(np.isfinite(n)) and crit < q0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"mag_weight": 0.0}, "parameter mag_weight must be a finite number, > 0"),
        ({"tolerance": -1.0}, "parameter tolerance must be a finite number, >= 0"),
        ({"max_iterations": 0}, "parameter max_iterations must be a finite number, >= 1 and <= 1"),
        ({"max_iterations": 1001}, "parameter max_iterations must be a finite number"),
        ({"max_iterations": 2.5}, "parameter max_iterations must be a whole number"),
        ({"mag_dip_ref_deg": 95.0}, "parameter mag_dip_ref_deg must be a finite number, >= -90"),
    ],
)
def test_gauss_newton_parameters_are_validated(kwargs, message):
    with pytest.raises(ValueError, match=message):
        GaussNewtonParams(**kwargs)
