"""Kernel of Bachmann's quaternion complementary filter (000, Appendix A, eqs. 13-27).

The Gauss-Newton drift correction is computed in the closed form derived in
:mod:`margtrack.methods.bachmann`: with ``R`` the rotation of ``q̂`` (body to earth),
unit measured vectors ``h`` (accelerometer) and ``b`` (magnetometer), unit references ``m``
(gravity, up) and ``n`` (field), and magnetometer weight ``ρ``, the step of eq. 23
expressed in the earth frame is

    Δv_E = R Δv_full = ½ M0⁻¹ ((R h) × m + ρ (R b) × n),   M0 = 2 I - m mᵀ - n nᵀ,

a constant matrix per sensor (eq. 23 with ``X_v = 2 [ĥ; b̂]×``). Without a magnetometer
(or on a sample whose magnetometer reads zero) it is the minimum-norm step
``Δv_E = ½ (R h) × m``. The criterion (eq. 19) is ``φ = |R h - m|² + ρ² |R b - n|²``.

Screened input (``margtrack.estimator.screening``): an all-zero accelerometer vector is no
measurement (no correction at that sample), an all-zero magnetometer vector gives the
gravity-only step, ``dt = 0`` integrates nothing. The kernel is safe for any finite input:
the only division by a data-dependent quantity is the normalisation of eq. 27, which
scales by the largest component when ``|q|²`` overflows (a rate beyond ~1e150 rad/s) and
keeps the previous orientation when the step itself is not finite.

On ``estimator/skeleton.py``: :func:`_start`, :func:`_step`, :func:`_hold` over one sensor's
row, their strided forms for the lockstep blocks, and the entry points ``run``, ``lanes``,
``start`` that ``contract.entry_points`` generates from them.

Row layout after the contract's slots (offsets ``B_*``):

- ``B_Q`` (4) ``q̂``, body to earth (the output frame, or the frame of explicit
  reference vectors);
- ``B_STEP`` (3) the held correction step ``Δv_E`` (earth frame); ``B_PHI`` its criterion
  (NaN before the first);
- ``B_SINCE`` time since a restart while its raised gain lasts, s (-1: none);
- ``B_AWAIT`` 1 from a (re)start until a usable field sample sets the heading;
- ``B_TURN`` 1 from a start until its first step turns the start onto explicit references;
- ``B_CYCLE`` samples seen since the reset (stepped or held: the correction schedule, the
  same count in every sensor's row); ``B_INDEX`` the sensor's index (its round-robin turn);
- ``B_DIP`` the field inclination measured at the first usable sample, rad (NaN: not yet);
  ``B_REF`` (3) the unit field reference ``n`` from it (NaN: not known); ``B_MINV`` (7)
  the cofactors of ``M0`` (c00, c01, c02, c11, c12, c22) and ``1 / (2 det M0)``;
  ``B_HAS_REF`` 1 when that reference is usable;
- ``B_NULL`` (``rest_null.N_REST_NULL``) the gyro null from the still start.

A restart keeps ``B_DIP`` to ``B_NULL`` and the schedule (what belongs to the sensor).
Extra outputs per sample (``x_out``): φ, the correction as an earth-frame rate (3), 1 at a
new correction, the ``degenerate`` code, then (with a gyroscope) the gyro null (3).

Coefficients (``C_*``, after the contract's): gain k, ρ, correction interval, round robin,
restart gain, whether the gyroscope is used, ``m`` (3), whether ``n`` is given, the given
``n`` (3) with its ``B_MINV``-like cofactors (7) and usability, the frame (1: NED), whether
starts are turned onto explicit references and the two turns (start without / with a
field, 4 each), and the rest null's coefficients.
"""

from __future__ import annotations

import math

from margtrack.estimator import skeleton as contract
from margtrack.estimator.jit import njit
from margtrack.estimator.quat_kernel import cross, mul
from margtrack.estimator.screen_kernel import ACC_IGNORED, MAG_IGNORED
from margtrack.estimator.triad_kernel import PARALLEL_SINE, rotate
from margtrack.methods import rest_null_kernel as rest_null
from margtrack.methods.bachmann.geometry import cofactors, set_heading, unit_or_previous

OK = 0
ZERO_ACC = 1  # no correction at this sample: the accelerometer reads zero
ZERO_MAG = 2  # gravity-only correction at this sample: the magnetometer reads zero
NO_FIELD_REFERENCE = 3  # gravity-only correction: the sensor's field reference is not known yet

#: a measured dip is limited to ±(90 - 5) deg (MIN_REFERENCE_ANGLE_DEG of the filter), rad
DIP_LIMIT_RAD = math.radians(85.0)

# -- coefficients (after the contract's screening coefficients) ---------------------------
C_GAIN = 0  # k, 1/s
C_MAG_WEIGHT = 1  # ρ
C_INTERVAL = 2  # a new correction every n-th sample
C_ROUND_ROBIN = 3  # 1: sensor s corrects at cycles c = s (mod n)
C_RESTART_GAIN = 4  # 1/s
C_USE_GYR = 5  # 1: integrate the gyroscope (0: acc/mag-only tracking)
C_GRAV = 6  # 3: unit gravity reference m
C_FIXED_REF = 9  # 1: the field reference n is given (else measured per sensor)
C_REF = 10  # 3: the given n
C_MINV = 13  # 7: its cofactors of M0 and 1 / (2 det M0)
C_HAS_REF = 20  # 1: the given n is usable
C_NED = 21  # 1: the frame is NED (for the reference from a measured dip)
C_TURN = 22  # 1: starts are turned onto explicit reference vectors
C_TURN_ARC = 23  # 4: the turn of a start from the accelerometer alone
C_TURN_TRIAD = 27  # 4: the turn of a TRIAD start
C_NULL = 31  # rest_null.N_RC: the gyro null's coefficients
N_COEF = C_NULL + rest_null.N_RC

# -- one sensor's row (after the contract's slots; module docstring) --------------------
B_Q = contract.N_CONTRACT
B_STEP = B_Q + 4
B_PHI = B_STEP + 3
B_SINCE = B_PHI + 1
B_AWAIT = B_SINCE + 1
B_TURN = B_AWAIT + 1
B_CYCLE = B_TURN + 1
B_INDEX = B_CYCLE + 1
B_DIP = B_INDEX + 1
B_REF = B_DIP + 1
B_MINV = B_REF + 3
B_HAS_REF = B_MINV + 7
B_NULL = B_HAS_REF + 1
N_ROW = B_NULL + rest_null.N_REST_NULL

# -- extra outputs per sample ---------------------------------------------------------
X_PHI = 0
X_CORR = 1  # 3
X_NEW = 4
X_CODE = 5
X_NULL = 6  # 3, with a gyroscope only
N_X = X_NULL + 3


@njit(cache=True, inline="always")
def _measure_reference(st, o, lanes, coef, ax, ay, az, bx, by, bz):
    """Measure the dip at a usable pair (both non-zero, not parallel) and set the sensor's
    field reference from it (deg and back, as ``frames.mag_reference``); no-op otherwise.
    The row's slot j is ``st[o + j * lanes]`` (``contract_lanes``; 1 for a row)."""
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    cx, cy, cz = cross(ax, ay, az, bx, by, bz)
    if not (na > 0.0 and nb > 0.0):
        return
    if not math.sqrt(cx * cx + cy * cy + cz * cz) >= PARALLEL_SINE * na * nb:
        return
    sine = -(ax * bx + ay * by + az * bz) / (na * nb)
    dip = math.asin(min(max(sine, -1.0), 1.0))
    dip = min(max(dip, -DIP_LIMIT_RAD), DIP_LIMIT_RAD)
    st[o + B_DIP * lanes] = dip
    rad = dip * (180.0 / math.pi) * (math.pi / 180.0)
    c, s = math.cos(rad), math.sin(rad)
    if coef[C_NED] > 0.5:
        nx, ny, nz = c, 0.0, s
    else:
        nx, ny, nz = 0.0, c, -s
    i_ref, i_minv = o + B_REF * lanes, o + B_MINV * lanes
    st[i_ref], st[i_ref + lanes], st[i_ref + 2 * lanes] = nx, ny, nz
    usable, c00, c01, c02, c11, c12, c22, half = cofactors(
        coef[C_GRAV], coef[C_GRAV + 1], coef[C_GRAV + 2], nx, ny, nz
    )
    for k, value in enumerate((c00, c01, c02, c11, c12, c22, half)):
        st[i_minv + k * lanes] = value
    st[o + B_HAS_REF * lanes] = 1.0 if usable else 0.0


@njit(cache=True, inline="always")
def _start(row, coef, first, qw, qx, qy, qz):
    """(Re)start at q: fresh orientation and correction, the heading awaited from the
    field; a restart (not ``first``) keeps dip and null and raises the gain."""
    _start_at(row, 0, 1, coef, first, qw, qx, qy, qz)


@njit(cache=True)
def _start_given(row, coef, first, qw, qx, qy, qz):
    """:func:`_start` at an orientation given whole (``reset(q0)``): no heading awaited, no
    turn applies."""
    _start(row, coef, first, qw, qx, qy, qz)
    row[B_AWAIT] = 0.0
    row[B_TURN] = 0.0


@njit(cache=True, inline="always")
def _start_at(st, o, lanes, coef, first, qw, qx, qy, qz):
    """:func:`_start` on the row at ``st[o + j * lanes]`` (``contract_lanes``)."""
    i_q, i_step = o + B_Q * lanes, o + B_STEP * lanes
    st[i_q], st[i_q + lanes], st[i_q + 2 * lanes], st[i_q + 3 * lanes] = qw, qx, qy, qz
    st[i_step] = st[i_step + lanes] = st[i_step + 2 * lanes] = 0.0
    st[o + B_PHI * lanes] = math.nan
    st[o + B_SINCE * lanes] = -1.0 if first else 0.0
    st[o + B_AWAIT * lanes] = 1.0
    st[o + B_TURN * lanes] = coef[C_TURN]
    if first:
        st[o + B_DIP * lanes] = math.nan
        for k in range(3):
            st[o + (B_REF + k) * lanes] = math.nan
        for k in range(7):
            st[o + (B_MINV + k) * lanes] = 0.0
        st[o + B_HAS_REF * lanes] = 0.0
        rest_null.fresh_one(st, o + B_NULL * lanes, lanes)


@njit(cache=True, inline="always")
def _step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """One screened sample of 000's Fig. 5 (module docstring); returns the flag bits."""
    return _step_at(row, 0, 1, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, 0,
                    x_out, 0, 1, False)


@njit(cache=True, inline="always")
def _rare_at(st, o, lanes, coef, dt, has_mag, a0, a1, a2, m0, m1, m2):
    """Whether a sample takes one of :func:`_step_at`'s rare branches (the start's turn onto
    explicit references, measuring the field reference, setting the heading): those run
    in ``contract_lanes``' scalar pass, the rest vectorised."""
    if st[o + B_TURN * lanes] != 0.0:
        return True
    fixed = coef[C_FIXED_REF] > 0.5
    if not fixed and has_mag and math.isnan(st[o + B_DIP * lanes]):
        return True
    has_ref = coef[C_HAS_REF] > 0.5 if fixed else st[o + B_HAS_REF * lanes] > 0.5
    return st[o + B_AWAIT * lanes] != 0.0 and has_mag and has_ref


@njit(cache=True, inline="always")
def _step_at(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, qa, qo, xa,
             xo, outs, steady):
    """:func:`_step` on the row at ``st[o + j * lanes]``, writing q to ``qa[qo + k * outs]``
    and the extra outputs to ``xa[xo + k * outs]``; ``steady`` (a constant): the caller
    knows :func:`_rare_at` is False, so the rare branches are left out of the code."""
    i_q, i_step, i_phi = o + B_Q * lanes, o + B_STEP * lanes, o + B_PHI * lanes
    qw, qx, qy, qz = st[i_q], st[i_q + lanes], st[i_q + 2 * lanes], st[i_q + 3 * lanes]
    if not steady and st[o + B_TURN * lanes] != 0.0:
        # the start in the frame of explicit reference vectors
        st[o + B_TURN * lanes] = 0.0
        t = C_TURN_ARC if not has_mag or (m0 == 0.0 and m1 == 0.0 and m2 == 0.0) else C_TURN_TRIAD
        qw, qx, qy, qz = mul(coef[t], coef[t + 1], coef[t + 2], coef[t + 3], qw, qx, qy, qz)
    # the correction schedule: sensor s's turns are cycles c with (c - phase) % n == 0
    interval = int(coef[C_INTERVAL])
    cycle = int(st[o + B_CYCLE * lanes])
    st[o + B_CYCLE * lanes] = cycle + 1.0
    new = True  # every sample with the default interval 1 (no integer division then)
    if interval != 1:
        # (max: a divisor known to be >= 1, which the vectoriser may divide by in any lane)
        interval = max(interval, 1)
        phase = int(st[o + B_INDEX * lanes]) % interval if coef[C_ROUND_ROBIN] > 0.5 else 0
        new = (cycle - phase) % interval == 0
    use_gyr = coef[C_USE_GYR] > 0.5
    if use_gyr:  # the gyro null from the still start (000 Appendix B step 1)
        nx, ny, nz = rest_null.step_at(
            st, o + B_NULL * lanes, lanes, coef, C_NULL, g0, g1, g2, a0, a1, a2, m0, m1, m2,
            has_mag, dt,
        )
        g0, g1, g2 = g0 - nx, g1 - ny, g2 - nz
        xa[xo + X_NULL * outs], xa[xo + (X_NULL + 1) * outs] = nx, ny
        xa[xo + (X_NULL + 2) * outs] = nz
    mx, my, mz = coef[C_GRAV], coef[C_GRAV + 1], coef[C_GRAV + 2]
    # the field reference: given, or measured at the sensor's first usable sample
    fixed = coef[C_FIXED_REF] > 0.5
    if not steady and not fixed and has_mag and math.isnan(st[o + B_DIP * lanes]):
        _measure_reference(st, o, lanes, coef, a0, a1, a2, m0, m1, m2)
    i_ref, i_minv = o + B_REF * lanes, o + B_MINV * lanes
    has_ref = coef[C_HAS_REF] > 0.5 if fixed else st[o + B_HAS_REF * lanes] > 0.5
    nx = coef[C_REF] if fixed else st[i_ref]
    ny = coef[C_REF + 1] if fixed else st[i_ref + lanes]
    nz = coef[C_REF + 2] if fixed else st[i_ref + 2 * lanes]
    flag = OK
    if not steady and st[o + B_AWAIT * lanes] != 0.0 and has_mag and has_ref:
        qw, qx, qy, qz, awaiting = set_heading(
            qw, qx, qy, qz, m0, m1, m2, mx, my, mz, nx, ny, nz
        )
        st[o + B_AWAIT * lanes] = 1.0 if awaiting else 0.0
    vx, vy, vz = st[i_step], st[i_step + lanes], st[i_step + 2 * lanes]
    phi = st[i_phi]
    if new:
        # steps 1-6 of 000's Fig. 5, in the earth frame (module docstring)
        na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        if na > 0.0:
            hx, hy, hz = rotate(qw, qx, qy, qz, a0 / na, a1 / na, a2 / na)
            ex, ey, ez = hx - mx, hy - my, hz - mz  # R (h - ĥ) (eq. 15)
            phi = ex * ex + ey * ey + ez * ez  # eq. 19, gravity part
            rx, ry, rz = cross(hx, hy, hz, mx, my, mz)  # R (h × ĥ)
            vx, vy, vz = 0.5 * rx, 0.5 * ry, 0.5 * rz  # minimum-norm step
            if has_mag:
                nb = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
                if nb > 0.0 and not has_ref:
                    flag = NO_FIELD_REFERENCE
                elif nb > 0.0:
                    rho = coef[C_MAG_WEIGHT]
                    c00 = coef[C_MINV] if fixed else st[i_minv]
                    c01 = coef[C_MINV + 1] if fixed else st[i_minv + lanes]
                    c02 = coef[C_MINV + 2] if fixed else st[i_minv + 2 * lanes]
                    c11 = coef[C_MINV + 3] if fixed else st[i_minv + 3 * lanes]
                    c12 = coef[C_MINV + 4] if fixed else st[i_minv + 4 * lanes]
                    c22 = coef[C_MINV + 5] if fixed else st[i_minv + 5 * lanes]
                    half_det_inv = coef[C_MINV + 6] if fixed else st[i_minv + 6 * lanes]
                    bx, by, bz = rotate(qw, qx, qy, qz, m0 / nb, m1 / nb, m2 / nb)
                    ex, ey, ez = bx - nx, by - ny, bz - nz  # R (b - b̂) (eq. 16)
                    phi += rho * rho * (ex * ex + ey * ey + ez * ez)
                    cx, cy, cz = cross(bx, by, bz, nx, ny, nz)  # R (b × b̂)
                    # ρ weights the residual only (eqs. 17-18 vs eq. 20)
                    rx += rho * cx
                    ry += rho * cy
                    rz += rho * cz
                    # Δv_E = ½ M0⁻¹ r (eq. 23 rotated to the earth frame)
                    vx = half_det_inv * (c00 * rx + c01 * ry + c02 * rz)
                    vy = half_det_inv * (c01 * rx + c11 * ry + c12 * rz)
                    vz = half_det_inv * (c02 * rx + c12 * ry + c22 * rz)
                else:
                    flag = ZERO_MAG
        else:
            flag = ZERO_ACC
            vx, vy, vz = 0.0, 0.0, 0.0
            phi = math.nan
        st[i_step], st[i_step + lanes], st[i_step + 2 * lanes] = vx, vy, vz
        st[i_phi] = phi
    gain = coef[C_GAIN]
    k = gain
    since = st[o + B_SINCE * lanes] if coef[C_RESTART_GAIN] > gain else -1.0
    if since >= 0.0:  # after a restart: the mean of the measurements since (1/t)
        since += dt
        k = 1.0 / (since + 1.0 / coef[C_RESTART_GAIN])
        if k <= gain:
            k = gain
            since = -1.0
    st[o + B_SINCE * lanes] = since
    # q̇_ε = k (0, Δv_E) ⊗ q̂, which is k q̂ ⊗ (0, Δv_full) = k Δq_full (eqs. 24-25)
    ew, ex, ey, ez = mul(0.0, vx, vy, vz, qw, qx, qy, qz)
    dw, dx, dy, dz = k * ew, k * ex, k * ey, k * ez
    if use_gyr:
        # q̇ = ½ q̂ ⊗ (0, ω) (eq. 26)
        gw, gx, gy, gz = mul(qw, qx, qy, qz, 0.0, g0, g1, g2)
        dw += 0.5 * gw
        dx += 0.5 * gx
        dy += 0.5 * gy
        dz += 0.5 * gz
    # q̂ + Δt (q̇ + q̇_ε), normalised (eq. 27); dt = 0 leaves q̂ exactly as it is
    if dt != 0.0:
        qw, qx, qy, qz = unit_or_previous(
            qw + dt * dw, qx + dt * dx, qy + dt * dy, qz + dt * dz, qw, qx, qy, qz
        )
    st[i_q], st[i_q + lanes], st[i_q + 2 * lanes], st[i_q + 3 * lanes] = qw, qx, qy, qz
    qa[qo], qa[qo + outs], qa[qo + 2 * outs], qa[qo + 3 * outs] = qw, qx, qy, qz
    two_k = 2.0 * k
    xa[xo + X_PHI * outs] = phi
    xa[xo + X_CORR * outs], xa[xo + (X_CORR + 1) * outs] = two_k * vx, two_k * vy
    xa[xo + (X_CORR + 2) * outs] = two_k * vz
    xa[xo + X_NEW * outs] = 1.0 if new else 0.0
    xa[xo + X_CODE * outs] = flag
    if flag == ZERO_ACC:
        return ACC_IGNORED
    if flag == NO_FIELD_REFERENCE:
        return MAG_IGNORED
    return 0  # ZERO_MAG: the screening's MAG_IGNORED or MAG_DISTURBED says why


@njit(cache=True, inline="always")
def _hold(row, coef, x_out):
    """Outputs of a held sample (a sensor waiting for a usable sample): the held correction
    (none before the first start), no new one. The sample counts in the schedule."""
    _hold_at(row, 0, 1, coef, x_out, 0, 1)


@njit(cache=True, inline="always")
def _hold_at(st, o, lanes, coef, xa, xo, outs):
    """:func:`_hold` on the row at ``st[o + j * lanes]``, outputs at ``xa[xo + k * outs]``."""
    st[o + B_CYCLE * lanes] += 1.0
    started = st[o + contract.K_STARTS * lanes] > 0.0
    two_k = 2.0 * coef[C_GAIN]
    xa[xo + X_PHI * outs] = st[o + B_PHI * lanes] if started else math.nan
    for k in range(3):
        xa[xo + (X_CORR + k) * outs] = two_k * st[o + (B_STEP + k) * lanes] if started else 0.0
    xa[xo + X_NEW * outs] = 0.0
    xa[xo + X_CODE * outs] = OK
    if coef[C_USE_GYR] > 0.5:
        for k in range(3):
            i_null = o + (B_NULL + rest_null.RN_NULL + k) * lanes
            xa[xo + (X_NULL + k) * outs] = st[i_null] if started else 0.0


#: the lockstep blocks compiled with LLVM's vectoriser forced to 8 lanes (8 float64 in
#: AVX-512; narrower vectors are split): its cost model leaves them scalar otherwise, 1.3
#: times slower (``jit.force_vector_width``)
LANES_VECTOR_WIDTH = 8

run, lanes, start = contract.entry_points(__name__)
