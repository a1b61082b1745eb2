# ruff: noqa: F405  (names from gradient_layout's star import)
"""Kernel of the gradient-descent filter (004, an extension of Madgwick's filter), on
``kernels/contract.py``.

Quaternions are body-to-earth ``[w, x, y, z]`` (004's ``q1..q4``); Madgwick's and 004's
``^S_E q`` is numerically the same quaternion, their ``q* ⊗ d ⊗ q`` is our
``rotate_inverse(q, d)``.

Row layout after the contract's slots (the constants, in ``kernels/gradient_layout.py``,
are row indices from ``contract.N_CONTRACT`` on):

- ``G_Q`` (4): the orientation in NWU, where the recursion runs (see :func:`_step`);
- ``G_MAG_REF`` (2): [b_x, b_z], the unit field reference of ``FULL_FIXED`` in north/up
  components (b_x = 0: not measured yet); kept across restarts;
- ``G_ACC_HELD`` (3): m/s², the accelerometer sample held for the live path
  (``filters/_async.py``); after a step, the sample it used as screened (zeros: none);
  kept across restarts;
- ``G_MAG_HELD`` (3): field unit, the same for the magnetometer (written only when a field
  is given and ``use_mag`` is on); kept across restarts.

Coefficients (``coef``): ``C_BETA`` rad/s, ``C_MAG_MODE`` (one of the objectives below),
``C_EXACT`` (1: exact gyro step, 0: Euler), ``C_GRAVITY`` m/s², ``C_USE_MAG`` (0: the
entry points drop a given field before the screening), ``C_TO_FRAME`` (4) the unit
quaternion c with ``q_frame = c ⊗ q_nwu``, ``C_UP`` (3) up in the output frame.

Extra outputs (``x_out``): ``X_EULER`` (3) [yaw, pitch, roll] rad, ``X_GRAVITY`` (3) the
gravity component in the body m/s², ``X_LIN_ACC`` (3) the earth-frame linear acceleration
m/s², ``X_IGNORED`` (1) the filter's ``ignored`` bits below (method detail; :func:`_step`
returns them as ``Flag`` bits).

``run`` and ``run_lanes`` keep per sample only what those outputs are computed from
(``x_run``: ``L_ACC`` (3) the screened accelerometer sample, ``L_IGNORED`` the bits):
:func:`expand` computes them with the same formulas from the output orientations, when
they are read (``estimator.compiled``: ``Estimate.outputs`` is lazy).

Entry points: ``run``, ``run_lanes``, ``update``, ``update_one``, ``start`` (``contract``'s
templates with :func:`_start`, :func:`_step` (or :func:`_step_lean`), :func:`_hold`),
:func:`expand`, and :func:`steps` (the step alone, for tests).
"""

from __future__ import annotations

import math

from margtrack.kernels import contract, contract_lanes, screen
from margtrack.kernels._quat import exp_half, mul
from margtrack.kernels.contract import N_SCOEF
from margtrack.kernels.gradient_layout import *  # noqa: F403 (the layout, as this module's)
from margtrack.kernels.gradient_objective import gradient_term, rotate, rotate_inverse
from margtrack.kernels.gradient_objective import objective_jacobian as objective_jacobian
from margtrack.kernels.jit import njit, to_fixed_tuple


@njit(cache=True)
def _outputs(coef, ow, ox, oy, oz, a0, a1, a2, x_out):
    """Euler angles, gravity component and linear acceleration of the output-frame
    orientation o and the (screened) accelerometer sample (004 "Inputs and Outputs")."""
    g = coef[C_GRAVITY]
    ux, uy, uz = coef[C_UP], coef[C_UP + 1], coef[C_UP + 2]
    # Euler angles (004 "Inputs and Outputs", squares restored)
    ww, xx, yy, zz = ow * ow, ox * ox, oy * oy, oz * oz
    x_out[X_EULER] = math.atan2(2.0 * (ox * oy + oz * ow), xx - yy - zz + ww)
    sp = -2.0 * (ox * oz - oy * ow)
    x_out[X_EULER + 1] = math.asin(min(1.0, max(-1.0, sp)))
    x_out[X_EULER + 2] = math.atan2(2.0 * (oy * oz + ox * ow), -xx - yy + zz + ww)
    # gravity component a_g in the body (points up) and a_m = R a - g up in the earth
    gx, gy, gz = rotate_inverse(ow, ox, oy, oz, ux, uy, uz)
    x_out[X_GRAVITY] = g * gx
    x_out[X_GRAVITY + 1] = g * gy
    x_out[X_GRAVITY + 2] = g * gz
    ex, ey, ez = rotate(ow, ox, oy, oz, a0, a1, a2)
    x_out[X_LIN_ACC] = ex - g * ux
    x_out[X_LIN_ACC + 1] = ey - g * uy
    x_out[X_LIN_ACC + 2] = ez - g * uz


@njit(cache=True)
def _start(row, coef, first, qw, qx, qy, qz):
    """(Re)start at q (output frame): the NWU orientation ``c* ⊗ q``. The field reference
    and the held samples belong to the sensors and the field: kept (a fresh row has none)."""
    _start_at(row, 0, 1, coef, first, qw, qx, qy, qz)


@njit(cache=True)
def _start_at(st, o, lanes, coef, first, qw, qx, qy, qz):
    """:func:`_start` on the row whose slot j is ``st[o + j * lanes]`` (``contract_lanes``)."""
    c = C_TO_FRAME
    qw, qx, qy, qz = mul(coef[c], -coef[c + 1], -coef[c + 2], -coef[c + 3], qw, qx, qy, qz)
    i = o + G_Q * lanes
    st[i], st[i + lanes], st[i + 2 * lanes], st[i + 3 * lanes] = qw, qx, qy, qz


@njit(cache=True)
def _advance(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, qa, qo, qs):
    """One screened sample: correction, propagation and fusion; returns the ``ignored``
    bits (:func:`_step` returns them as ``Flag`` bits).

    The row's slot j is ``st[o + j * lanes]`` (``(row, 0, 1)`` for one sensor's row, a lane of
    interleaved rows in ``contract_lanes``); the new output orientation goes to
    ``qa[qo + k * qs]``, k = 0..3.

    rad/s, m/s², any field unit; an all-zero acc or field is "no measurement" (that
    correction is skipped); ``dt = 0`` integrates nothing and makes no correction step
    (β dt = 0), so a no-op sample leaves the orientation as it was, renormalised. As flags
    the bits are ``Flag.ACC_IGNORED`` for the filter's ACC_IGNORED and ``Flag.MAG_IGNORED``
    for its MAG_REJECTED (a zero field is the screening's sentinel, flagged there with its
    reason).

    The recursion runs in NWU (x north, y west, z up), Madgwick's frame: the objective in
    its unit-norm form (``1/2 - q3² - q4²``) is not invariant under a change of earth frame
    off the unit sphere, so the radial part of ∇f, and with it the normalised step
    ``∇f / |∇f|``, would depend on the frame. One internal frame makes every output frame
    the same rotation and the full-vector variant equal to ahrs.filters.Madgwick.
    """
    i_q, i_ref = o + G_Q * lanes, o + G_MAG_REF * lanes
    w, x, y, z = st[i_q], st[i_q + lanes], st[i_q + 2 * lanes], st[i_q + 3 * lanes]
    mode = coef[C_MAG_MODE]
    bits = 0
    # -- correction: gradient of the stacked objectives at the prior q (NWU) ---------------
    s0, s1, s2, s3 = 0.0, 0.0, 0.0, 0.0
    ax, ay, az = a0, a1, a2
    na = math.sqrt(ax * ax + ay * ay + az * az)
    if na > 0.0:
        ax, ay, az = ax / na, ay / na, az / na
        # gravity: reference up = z, measured â (004: a_g points upward)
        s0, s1, s2, s3 = gradient_term(w, x, y, z, 0.0, 0.0, 1.0, ax, ay, az)
        if has_mag:
            mx, my, mz = m0, m1, m2
            nm = math.sqrt(mx * mx + my * my + mz * mz)
            if not FIELD_SAFE[0] < nm < FIELD_SAFE[1]:
                # squares over- or underflowed (a field unit far from µT): only the
                # direction is used, so scale by the largest component first
                big = max(abs(mx), abs(my), abs(mz))
                if big > 0.0:
                    mx, my, mz = mx / big, my / big, mz / big
                    nm = math.sqrt(mx * mx + my * my + mz * mz)
            use = nm > 0.0
            dx, dz = 1.0, 0.0
            if use and mode <= FORWARD_MEASURED:
                # forward component m_f = m - (m·v̂) v̂, the rejection of m from the gravity
                # direction v̂ (004 "Definitions", "Inputs and Outputs"; the extracted
                # reject formula garbles its operands), matched to north: v̂ is 004's
                # gravity component a_g, the filter's own estimate R(q)ᵀ up, or
                # (FORWARD_MEASURED) the raw accelerometer â
                if mode == FORWARD_ESTIMATED:
                    vx, vy, vz = rotate_inverse(w, x, y, z, 0.0, 0.0, 1.0)
                else:
                    vx, vy, vz = ax, ay, az
                p = mx * vx + my * vy + mz * vz
                mx, my, mz = mx - p * vx, my - p * vy, mz - p * vz
                nf = math.sqrt(mx * mx + my * my + mz * mz)
                use = nf > FORWARD_MIN * nm
                if use:
                    mx, my, mz = mx / nf, my / nf, mz / nf
            elif use:
                # full vector, reference b = [b_x, 0, b_z]: Madgwick's from the field seen
                # in the earth frame, h = q ⊗ m̂ ⊗ q*, b_x = |h_horizontal|, b_z = h_z (his
                # eqs. 45-46), or (FULL_FIXED) the first such b, kept
                mx, my, mz = mx / nm, my / nm, mz / nm
                if mode == FULL_ADAPTIVE or st[i_ref] <= 0.0:
                    hx, hy, hz = rotate(w, x, y, z, mx, my, mz)
                    dx, dz = math.sqrt(hx * hx + hy * hy), hz
                    if mode == FULL_FIXED:
                        st[i_ref], st[i_ref + lanes] = dx, dz
                else:
                    dx, dz = st[i_ref], st[i_ref + lanes]
            if use:
                t0, t1, t2, t3 = gradient_term(w, x, y, z, dx, 0.0, dz, mx, my, mz)
                s0, s1, s2, s3 = s0 + t0, s1 + t1, s2 + t2, s3 + t3
            else:
                bits |= MAG_IGNORED | (MAG_REJECTED if nm > 0.0 else 0)
    elif has_mag and (m0 != 0.0 or m1 != 0.0 or m2 != 0.0):
        # gyro-only step (Madgwick's: no feedback without a valid accelerometer); the
        # given field is not used without it
        bits |= ACC_IGNORED | MAG_REJECTED
    elif dt > 0.0:
        bits |= ACC_IGNORED
    # else a no-op sample (dt = 0, no acc, no field: a skipped timestamp): nothing was
    # there to be used, nothing is flagged
    sn = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2 + s3 * s3)
    if sn > GRADIENT_MIN:
        s0, s1, s2, s3 = s0 / sn, s1 / sn, s2 / sn, s3 / sn
    else:
        s0, s1, s2, s3 = 0.0, 0.0, 0.0, 0.0
    # -- propagation and fusion (004 "Gyroscope Equations"; Madgwick eq. 42) ---------------
    beta = coef[C_BETA]
    if coef[C_EXACT] > 0.5:
        ew, ex, ey, ez = exp_half(g0, g1, g2, dt)
        pw, px, py, pz = mul(w, x, y, z, ew, ex, ey, ez)
        step = beta * dt
        pw, px, py, pz = pw - step * s0, px - step * s1, py - step * s2, pz - step * s3
    else:
        # q̇ = ½ q ⊗ (0, ω) - β ∇f/|∇f|, then q + q̇ Δt (as ahrs.filters.Madgwick)
        dw, dx_, dy_, dz_ = mul(w, x, y, z, 0.0, g0, g1, g2)
        dw, dx_, dy_, dz_ = (
            0.5 * dw - beta * s0, 0.5 * dx_ - beta * s1,
            0.5 * dy_ - beta * s2, 0.5 * dz_ - beta * s3,
        )
        pw, px, py, pz = w + dw * dt, x + dx_ * dt, y + dy_ * dt, z + dz_ * dt
    norm = math.sqrt(pw * pw + px * px + py * py + pz * pz)
    w, x, y, z = pw / norm, px / norm, py / norm, pz / norm
    st[i_q], st[i_q + lanes], st[i_q + 2 * lanes], st[i_q + 3 * lanes] = w, x, y, z
    i_acc, i_mag = o + G_ACC_HELD * lanes, o + G_MAG_HELD * lanes
    st[i_acc], st[i_acc + lanes], st[i_acc + 2 * lanes] = a0, a1, a2
    if has_mag:
        st[i_mag], st[i_mag + lanes], st[i_mag + 2 * lanes] = m0, m1, m2
    # -- the orientation in the output frame ---------------------------------------------------
    c = C_TO_FRAME
    qa[qo], qa[qo + qs], qa[qo + 2 * qs], qa[qo + 3 * qs] = mul(
        coef[c], coef[c + 1], coef[c + 2], coef[c + 3], w, x, y, z
    )
    return bits


@njit(cache=True)
def _flags(bits):
    """``Flag`` bits of the filter's ``ignored`` bits (:func:`_step`)."""
    return (screen.ACC_IGNORED if bits & ACC_IGNORED else 0) | (
        screen.MAG_IGNORED if bits & MAG_REJECTED else 0
    )


@njit(cache=True)
def _step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """:func:`_advance` and the extra outputs of the new orientation (``update``)."""
    bits = _advance(row, 0, 1, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, 0, 1)
    _outputs(coef, q_out[0], q_out[1], q_out[2], q_out[3], a0, a1, a2, x_out)
    x_out[X_IGNORED] = bits
    return _flags(bits)


@njit(cache=True)
def _step_lean(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_run):
    """:func:`_advance` keeping only what the extra outputs are computed from (``run``):
    x_run (N_LEAN,) the screened accelerometer sample and the ``ignored`` bits."""
    return _step_lean_at(row, 0, 1, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag,
                         q_out, 0, x_run, 0, 1, False)


@njit(cache=True)
def _step_lean_at(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, qa, qo,
                  xa, xo, outs, steady):
    """:func:`_step_lean` on the row at ``st[o + j * lanes]``, writing output k of q to
    ``qa[qo + k * outs]`` and of x_run to ``xa[xo + k * outs]`` (``contract_lanes``; the
    step has no rare branch, so ``steady`` changes nothing)."""
    bits = _advance(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, qa, qo,
                    outs)
    xa[xo + L_ACC * outs], xa[xo + (L_ACC + 1) * outs], xa[xo + (L_ACC + 2) * outs] = a0, a1, a2
    xa[xo + L_IGNORED * outs] = bits
    return _flags(bits)


@njit(cache=True)
def _hold(row, coef, x_out):
    """Outputs of the held orientation (no accelerometer: the linear acceleration is
    ``-g up``, as for a gyro-only step); no ``ignored`` bits."""
    k = contract.K_Q
    _outputs(coef, row[k], row[k + 1], row[k + 2], row[k + 3], 0.0, 0.0, 0.0, x_out)
    x_out[X_IGNORED] = 0.0


@njit(cache=True)
def _hold_lean(row, coef, x_run):
    """:func:`_hold` for ``run``: no accelerometer sample, no ``ignored`` bits."""
    _hold_lean_at(row, 0, 1, coef, x_run, 0, 1)


@njit(cache=True)
def _rare_at(st, o, lanes, coef, dt, has_mag, a0, a1, a2, m0, m1, m2):
    """No sample takes a rare branch of the step (``contract_lanes``)."""
    return False


@njit(cache=True)
def _hold_lean_at(st, o, lanes, coef, xa, xo, outs):
    """:func:`_hold_lean` writing output k to ``xa[xo + k * outs]`` (``contract_lanes``)."""
    for k in range(N_LEAN):
        xa[xo + k * outs] = 0.0


@njit(cache=True)
def expand(coefs, q, x_run, x_out):
    """The extra outputs of a ``run``: x_out (S, N, N_OUT) from its orientations q (S, N, 4)
    and x_run (S, N, N_LEAN), the same formulas on the same values as :func:`_step` and
    :func:`_hold` (bit for bit): the hot loop keeps 4 values per sample instead of
    computing 10 with two ``atan2`` and an ``asin``, and this runs only when they are read.
    """
    coef = coefs[contract.N_SCOEF :]
    for s in range(q.shape[0]):
        for i in range(q.shape[1]):
            qi, li, xi = q[s, i], x_run[s, i], x_out[s, i]
            _outputs(coef, qi[0], qi[1], qi[2], qi[3], li[L_ACC], li[L_ACC + 1], li[L_ACC + 2],
                     xi)
            xi[X_IGNORED] = li[L_IGNORED]


@njit(cache=True)
def _has(coefs, has):
    """The ``has`` bits with a given field dropped when ``use_mag`` is off (then the
    screening does not judge it and a start levels on gravity alone)."""
    return has if coefs[contract.N_SCOEF + C_USE_MAG] > 0.5 else has & ~1


@njit(cache=True, nogil=True, _nrt=False)
def series(rows, coefs, dts, ks, tflags, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples on the shared clock's values (``contract.series``)."""
    contract.series(_start, _step_lean, _hold_lean, rows, coefs, dts, ks, tflags, gyr, acc, mag,
                    _has(coefs, has), q_out, x_out, flags_out)


@njit(cache=True, nogil=True)
def run(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples (``contract.run_series`` with :func:`series`); x_out
    (S, N, N_LEAN) for :func:`expand`."""
    contract.run_series(series, rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out,
                        flags_out)


@njit(cache=True, error_model="numpy", _nrt=False)
def lanes_block(st, rows, s0, coefs, dts, ks, tflags, gyr, acc, mag, has, q_out, x_out,
                flags_out, frame_major, s_in):
    """One block of sensors in lockstep, vectorised across them (``contract_lanes.block``)."""
    # (plain global names: numba sees them as the constants to_fixed_tuple needs)
    scoef, coef = to_fixed_tuple(coefs, N_SCOEF), to_fixed_tuple(coefs[N_SCOEF:], N_COEF)
    contract_lanes.block(_start_at, _step_lean_at, _hold_lean_at, _rare_at, N_ROW, N_LEAN, st, rows,
                         s0, scoef, coef, dts, ks, tflags, gyr, acc, mag, _has(coefs, has), q_out,
                         x_out, flags_out, frame_major, s_in)


#: slots per lane of :func:`lanes_block`'s buffer
LANES_WIDTH = N_ROW + contract_lanes.N_B + N_LEAN


@njit(cache=True, nogil=True)
def run_lanes(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """:func:`run` by blocks of sensors in lockstep (``contract_lanes.run_blocks``); the same
    results."""
    contract_lanes.run_blocks(lanes_block, LANES_WIDTH, rows, clock, coefs, t, gyr, acc, mag, has,
                              q_out, x_out, flags_out, False, 0)


@njit(cache=True, nogil=True)
def run_lanes_frames(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out, s_in):
    """:func:`run_lanes` on frame-major inputs (N, S', 3), the rows' sensors from ``s_in``."""
    contract_lanes.run_blocks(lanes_block, LANES_WIDTH, rows, clock, coefs, t, gyr, acc, mag, has,
                              q_out, x_out, flags_out, True, s_in)


@njit(cache=True)
def sample(row, coef, scoef, clk, imu, has, q_out, x_out):
    """One screened sample of one sensor (``contract.sample``), compiled once for
    :func:`update` and :func:`update_one`."""
    return contract.sample(_start, _step, _hold, row, coef, scoef, clk, imu, has, q_out, x_out)


@njit(cache=True)
def update(rows, clock, coefs, dt, gyr, acc, mag, has, q_out, x_out, flags_out):
    """One sample of S sensors (``contract.update_samples``)."""
    contract.update_samples(sample, rows, clock, coefs, dt, gyr, acc, mag,
                            _has(coefs, has), q_out, x_out, flags_out)


@njit(cache=True)
def update_one(rows, clock, coefs, dt, g, a, m, has, out):
    """One sample of one sensor (``contract.update_one``); returns the flags."""
    return contract.update_one(sample, rows, clock, coefs, dt, g, a, m,
                               _has(coefs, has), out)


@njit(cache=True)
def start(rows, coefs, quat0):
    """Start S sensors at quat0 (S, 4) (``contract.start_rows``)."""
    contract.start_rows(_start, rows, coefs, quat0)


@njit(cache=True)
def steps(row, coef, dt, gyr, acc, mag, has_mag, q_out, x_out, flags_out):
    """:func:`_step` alone over N already screened samples of one sensor, for tests.

    row (N_ROW,) in/out (started); coef the method's coefficients; dt (N,) s; gyr, acc,
    mag (N, 3); outputs q_out (N, 4), x_out (N, N_OUT), flags_out (N,). No screening, no
    clock, no restarts: any interval and any sample reaches the step as given.
    """
    for i in range(dt.shape[0]):
        flags_out[i] = _step(
            row, coef, dt[i], gyr[i, 0], gyr[i, 1], gyr[i, 2], acc[i, 0], acc[i, 1], acc[i, 2],
            mag[i, 0], mag[i, 1], mag[i, 2], has_mag, q_out[i], x_out[i],
        )
