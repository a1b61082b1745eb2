"""Kernel of Marins' 7-state quaternion EKF, both approaches (001 sections 3-4).

State per sensor: ``x = [ω (3), q (4)]``: the body angular rate ``[p, q, r]`` in rad/s and
the quaternion, here in margtrack's order ``[w, x, y, z]`` (001 lists the scalar ``d``
last), body-to-earth, Hamilton, and the full 7x7 covariance ``P``.

Process model (001 eqs. 9-15): ``ω̇ = (-ω + w_r)/τ`` per axis with white ``w_r`` of density
``σ`` (rad/s/√Hz), and ``q̇ = q ⊗ (0, ω) / (2|q|)`` (the quaternion product of eq. 7 with
eq. 8's normalisation in the denominator, as eqs. 12-15 write it). Eqs. 12-15 keep ``|q|``
constant (``q ⊗ (0, ω)`` is orthogonal to ``q``), so for a known rate history their flow
is ``q ⊗ exp(φ / (2|q|))`` with ``φ`` the integral of the rate.

Discretisation over a sample interval ``h`` (:func:`transition`, :func:`process_noise`):

- rate, exact: ``ω⁺ = a ω`` with ``a = exp(-h/τ)``;
- quaternion, the exact flow of eqs. 12-15 along the model's noise-free rate, whose
  integral is ``φ = c ω``, ``c = τ (1 - a)``: ``q⁺ = q ⊗ exp(c ω / (2|q|))`` (exact when τ
  is equal on the three axes; otherwise the rate axis turns within the interval and this
  is exact to second order in the angle);
- noise, exact for the linear part: the per-axis covariances of the rate increment and of
  its integral over the interval (Van Loan), ``Var Δω = σ²(1 - a²)/(2τ)``,
  ``Cov(Δφ, Δω) = σ²(1 - a)²/2``, ``Var Δφ = σ² τ (x - 2(1 - e⁻ˣ) + (1 - e⁻²ˣ)/2)`` with
  ``x = h/τ``; the quaternion's share is linearised, ``Δq = G Δφ`` with
  ``G = ∂q⁺/∂φ``.

The Jacobian ``F = ∂x⁺/∂x`` of that map is exact (tests compare it with finite
differences): ``F_ωω = diag(a)``, ``F_qω = G diag(c)``,
``F_qq = R(E) - (q⁺ ⊗ (0, θ/2)) qᵀ/|q|²`` with ``E = exp(θ/2)``, ``θ = c ω/|q|`` and
``R(E) q = q ⊗ E``.

Measurements:

- approach 2 (001 4.3, the paper's choice): ``z = [gyro, q_GN]``, ``H = I₇``, with ``q_GN``
  the Gauss-Newton quaternion (001 eqs. 20-23, :func:`margtrack.methods.ekf.fit.fit`, the
  shared ``gauss_newton_solve`` inlined) started from
  the predicted quaternion, its sign chosen nearest the prediction (002's closing remark);
- approach 1 (001 4.1): ``z = [gyro, â, m̂]``, the unit accelerometer and magnetometer
  vectors, ``h(x) = [ω, R(q)ᵀ u/|q|², R(q)ᵀ m_ref/|q|²]`` (eq. 19's form, with ``u`` up and
  ``m_ref`` the unit reference field) and its Jacobian (:func:`vector_measurement`).
  Eq. 19 as printed is ``(R h)₁``, the first component of ``h`` turned from body to
  earth; a body-frame reading of an earth vector is ``Rᵀ h`` (with eq. 6's ``R`` and eq.
  20's ``M`` mapping body to earth), so the ``cd`` and ``bd`` terms change sign here.

With ``acc_disturbance_s`` or ``mag_disturbance_s`` above 0 (the field's is on by
default; both 0: 001's fixed noise, and this step as printed) the measurement noise
follows the sample's evidence: the accelerometer's distance from gravity's norm and the
field's from its reference norm, carried through the Gauss-Newton fit's Jacobian into the
quaternion's covariance (:mod:`margtrack.methods.ekf.noise`).

The measurement noise is diagonal, so the update is applied one measured component at a
time (:func:`margtrack.methods.ekf.model.scalar_update`: equal to the batch update in
exact arithmetic, the vector rows linearised at the prediction; symmetric and positive
definite by construction; it replaced the Joseph form of the batch update, equal to it to
rounding, at a third of the cost); then ``q`` is normalised (001 Fig. 3). The covariance
algebra uses the structure of F and H (:mod:`margtrack.methods.ekf.model`).

With ``bias_states`` (:mod:`margtrack.methods.ekf.bias_kernel`) the state is ``[ω, q, b]``: the
gyroscope measures ``ω + b`` and ``b`` is a random walk (003's augmented state); the
rest of the model is this one.

Screened samples (``margtrack.estimator.screening``) and degenerate pairs:

- a zero magnetometer (no usable field): the gyroscope and the gravity direction alone,
  approach 1's accelerometer rows ``z = [gyro, â]``. In approach 2 their noise is twice
  the angular noise of the Gauss-Newton quaternion (a component error ε is a rotation of
  2ε, so a unit vector's component variance would be ``4 quat_var / h``; it is
  ``16 quat_var / h``): the screening drops the field mostly in fast motion, where the
  accelerometer is far from gravity too (the factor's effect on BROAD and on a clipped
  field: docs/methods.md);
- a zero accelerometer, a pair along one line, or a failed Gauss-Newton fit: the
  gyroscope alone (``H = [I₃ 0]``);
- the gyroscope measurement is limited to ±``MAX_RATE_RAD_S`` per axis (the screening
  replaces absurd rates first; this keeps every product finite on its own), and an
  update that would leave a zero or non-finite quaternion is undone (``NOT_PD``).

On ``estimator/skeleton.py``: :func:`_start`, :func:`_step`, :func:`_hold` over one sensor's
row and the entry points ``run``, ``start`` that ``contract.entry_points`` generates from
them. The step is written once for a state of ``n`` = 7 or 10 numbers
(:mod:`margtrack.methods.ekf.step`: ``start_n``, ``step_n``, ``hold_n``, compiled with
``n`` constant; the layouts below are
defined there and re-exported here). Row layout after the
contract's slots (offsets ``E_*``, the same for both sizes up to ``E_X``):

- ``E_DIP`` the dip measured at the sensor's first valid sample, rad (NaN: not yet, or
  given); ``E_FIELD`` (3) the unit field reference from it; ``E_MAG_NORM`` the field's
  reference norm of the evidence-driven noise (``mag_disturbance_s``; 0: none yet);
- ``E_NULL`` (``rest_null.N_REST_NULL``) the gyro null from the still start;
- ``E_DT``, ``E_GEN``, ``E_K`` (19): the interval-dependent constants (per axis ``a``,
  ``c``, Var Δω, Cov(Δφ, Δω), Var Δφ, the bias increment's variance; the field reference's
  gain) of the interval ``E_DT`` and the coefficient generation ``E_GEN`` they were
  computed for: recomputed
  only when the generation changes or the interval moves by more than ``DT_REUSE_REL``
  (relative; timestamps' rounding moves it at every sample);
- ``E_X`` (n) the state ``[ω, q(, b)]`` (q body to earth in the output frame, any
  non-zero norm in a state set by hand); then (offsets from n, :func:`offsets`) its
  covariance (n²), row-major, both triangles; the scratch ``P h`` of an update (n, not
  state); with the bias: the gyro bias of the raw rate (null + b, 3) and its sd (3).

A restart keeps ``E_DIP``, ``E_FIELD``, ``E_MAG_NORM`` and ``E_NULL`` (what is known of the
sensor) and, with the bias, ``b`` and its covariance block; it starts the rest afresh.
Extra outputs per sample (``x_out``, offsets :func:`out_offsets`): the rate state (3), the
covariance diagonal (n), the Gauss-Newton iterations, the ``degenerate`` code, the gyro
null (3) and, with the bias, the bias of the raw rate (3) and its sd (3). Coefficients:
``C_*``.
"""

from __future__ import annotations

from margtrack.estimator import skeleton as contract
from margtrack.estimator.jit import njit
from margtrack.estimator.triad_kernel import (
    FASTMATH,
    OK,
    PARALLEL,
    SOLVER_FAILED,
    ZERO_ACC,
    ZERO_MAG,
)
from margtrack.methods.ekf.model import (
    axis_noise,
    exp_jacobian,
    process_noise,
    transition,
    vector_measurement,
)
from margtrack.methods.ekf.step import (
    C_ACC_DIST_S,
    C_ACC_VAR,
    C_APPROACH,
    C_BIAS_WALK_VAR,
    C_DIP,
    C_FIELD,
    C_GEN,
    C_GN_MAX_IT,
    C_GN_TOL,
    C_GRAVITY2,
    C_GYR_VAR,
    C_INIT_BIAS_VAR,
    C_INIT_QUAT_VAR,
    C_INIT_RATE_VAR,
    C_MAG_DIST_S,
    C_MAG_VAR,
    C_MAG_WEIGHT,
    C_NORTH,
    C_NULL,
    C_QUAT_VAR,
    C_RATE_VAR,
    C_TAU,
    C_UP,
    E_DIP,
    E_DT,
    E_FIELD,
    E_GEN,
    E_K,
    E_MAG_NORM,
    E_NULL,
    E_P,
    E_PH,
    E_X,
    MAX_RATE_RAD_S,
    N_COEF,
    N_OUT,
    N_ROW,
    NOT_PD,
    X_CODE,
    X_COV,
    X_ITER,
    X_NULL,
    X_RATE,
    N,
    hold_n,
    offsets,
    out_offsets,
    start_n,
    step_n,
)

__all__ = [
    "C_ACC_DIST_S",
    "C_ACC_VAR",
    "C_APPROACH",
    "C_BIAS_WALK_VAR",
    "C_DIP",
    "C_FIELD",
    "C_GEN",
    "C_GN_MAX_IT",
    "C_GN_TOL",
    "C_GRAVITY2",
    "C_GYR_VAR",
    "C_INIT_BIAS_VAR",
    "C_INIT_QUAT_VAR",
    "C_INIT_RATE_VAR",
    "C_MAG_DIST_S",
    "C_MAG_VAR",
    "C_MAG_WEIGHT",
    "C_NORTH",
    "C_NULL",
    "C_QUAT_VAR",
    "C_RATE_VAR",
    "C_TAU",
    "C_UP",
    "E_DIP",
    "E_DT",
    "E_FIELD",
    "E_GEN",
    "E_K",
    "E_MAG_NORM",
    "E_NULL",
    "E_P",
    "E_PH",
    "E_X",
    "FASTMATH",
    "MAX_RATE_RAD_S",
    "NOT_PD",
    "N_COEF",
    "N_OUT",
    "N_ROW",
    "OK",
    "PARALLEL",
    "SOLVER_FAILED",
    "X_CODE",
    "X_COV",
    "X_ITER",
    "X_NULL",
    "X_RATE",
    "ZERO_ACC",
    "ZERO_MAG",
    "N",
    "axis_noise",
    "exp_jacobian",
    "hold_n",
    "offsets",
    "out_offsets",
    "process_noise",
    "run",
    "start",
    "start_n",
    "step_n",
    "transition",
    "vector_measurement",
]


# -- the 7-state filter (001) ------------------------------------------------------------
@njit(cache=True, inline="always")
def _start(row, coef, first, qw, qx, qy, qz):
    start_n(row, coef, first, qw, qx, qy, qz, N)


@njit(cache=True, inline="always")
def _step(row, coef, h, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """:func:`step_n` for the 7-state filter (compiled once for n = 7 and called)."""
    return step_n(row, coef, h, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out, N)


@njit(cache=True, inline="always")
def _hold(row, coef, x_out):
    hold_n(row, coef, x_out, N)


N_X = N_OUT  # what ``run`` writes per sample

run, lanes, start = contract.entry_points(__name__)
