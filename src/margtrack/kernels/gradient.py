"""Kernel of the gradient-descent filter (004, an extension of Madgwick's filter), on
``kernels/contract.py``.

Quaternions are body-to-earth ``[w, x, y, z]`` (004's ``q1..q4``); Madgwick's and 004's
``^S_E q`` is numerically the same quaternion, their ``q* ⊗ d ⊗ q`` is our
``rotate_inverse(q, d)``.

Row layout after the contract's slots (the constants are row indices, from
``contract.N_CONTRACT`` on):

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

Entry points: ``run``, ``update``, ``update_one``, ``start`` (``contract``'s templates with
:func:`_start`, :func:`_step`, :func:`_hold`), and :func:`steps` (the step alone, for tests).
"""

from __future__ import annotations

import math

from margtrack.kernels import contract, screen
from margtrack.kernels._quat import exp_half, mul
from margtrack.kernels.jit import njit

#: ``ignored`` flag bits: no accelerometer correction (zero vector, the screening's "no
#: measurement"; the sample is gyro-only, without a magnetometer term either)
ACC_IGNORED = 1
#: ... the accelerometer was used but no magnetometer term (zero vector, or its forward
#: component vanishes)
MAG_IGNORED = 2
#: ... a non-zero field that the filter itself did not use: its forward component vanished
#: (with MAG_IGNORED) or there was no accelerometer to go with it (with ACC_IGNORED); the
#: screening's zero sentinel is not this (it flags those samples itself)
MAG_REJECTED = 4

# Below this |∇f| the estimate fits the measurements to rounding (|f| ~ 1e-16); the
# normalised step ∇f/|∇f| would then point in a direction set by rounding noise (and a
# reset to the measured orientation followed by the same sample would step at random), so
# no correction is made. Real data never comes this close (ahrs, which has no such floor,
# gives the same results on BROAD to 1e-15).
GRADIENT_MIN = 1e-12

# magnetic objectives (``C_MAG_MODE``)
FORWARD_ESTIMATED = 0
FORWARD_MEASURED = 1
FULL_ADAPTIVE = 2
FULL_FIXED = 3

# The field's norm is computed directly inside this range and after scaling by its largest
# component outside it (where the squares would over- or underflow): any field unit works.
FIELD_SAFE = (1e-150, 1e150)

# Below this |m_f| / |m| the magnetometer is (almost) parallel to the measured gravity and
# its forward component no longer defines a horizontal direction (sin of about 0.6 deg).
FORWARD_MIN = 1e-2


@njit(cache=True, inline="always")
def objective(w, x, y, z, dx, dy, dz, sx, sy, sz):
    """f(q, d, s) = q* ⊗ d ⊗ q - s = rotate_inverse(q, d) - s (004 "General Optimization").

    004's expanded f (after Madgwick) has two sign slips in the extracted text: the z terms
    of row 2 read ``q1q2 - q3q4`` and the x terms of row 3 ``q1q3 - q2q4``; rotating by a
    unit q gives ``q1q2 + q3q4`` and ``q1q3 + q2q4``, which is also what 004's own
    Jacobian differentiates. Uses the unit-norm form ``1/2 - q3² - q4²`` as 004 does.
    """
    f1 = (
        2.0 * dx * (0.5 - y * y - z * z)
        + 2.0 * dy * (w * z + x * y)
        + 2.0 * dz * (x * z - w * y)
        - sx
    )
    f2 = (
        2.0 * dx * (x * y - w * z)
        + 2.0 * dy * (0.5 - x * x - z * z)
        + 2.0 * dz * (w * x + y * z)
        - sy
    )
    f3 = (
        2.0 * dx * (w * y + x * z)
        + 2.0 * dy * (y * z - w * x)
        + 2.0 * dz * (0.5 - x * x - y * y)
        - sz
    )
    return f1, f2, f3


@njit(cache=True, inline="always")
def jacobian(w, x, y, z, dx, dy, dz):
    """J = ∂f/∂[q1, q2, q3, q4] (3 x 4, row-major 12-tuple) of :func:`objective`.

    Derived from f; it equals 004's J except the last entry, which the extracted text
    gives as ``2x_x q2 - 2x_y q3 - 3`` (OCR slip): ∂f3/∂q4 = ``2 d_x q2 + 2 d_y q3``.
    """
    return (
        2.0 * dy * z - 2.0 * dz * y,
        2.0 * dy * y + 2.0 * dz * z,
        -4.0 * dx * y + 2.0 * dy * x - 2.0 * dz * w,
        -4.0 * dx * z + 2.0 * dy * w + 2.0 * dz * x,
        -2.0 * dx * z + 2.0 * dz * x,
        2.0 * dx * y - 4.0 * dy * x + 2.0 * dz * w,
        2.0 * dx * x + 2.0 * dz * z,
        -2.0 * dx * w - 4.0 * dy * z + 2.0 * dz * y,
        2.0 * dx * y - 2.0 * dy * x,
        2.0 * dx * z - 2.0 * dy * w - 4.0 * dz * x,
        2.0 * dx * w + 2.0 * dy * z - 4.0 * dz * y,
        2.0 * dx * x + 2.0 * dy * y,
    )


@njit(cache=True, inline="always")
def gradient_term(w, x, y, z, dx, dy, dz, sx, sy, sz):
    """∇f = Jᵀ f (004 "General Optimization Algorithm") for one reference direction."""
    f1, f2, f3 = objective(w, x, y, z, dx, dy, dz, sx, sy, sz)
    j = jacobian(w, x, y, z, dx, dy, dz)
    return (
        j[0] * f1 + j[4] * f2 + j[8] * f3,
        j[1] * f1 + j[5] * f2 + j[9] * f3,
        j[2] * f1 + j[6] * f2 + j[10] * f3,
        j[3] * f1 + j[7] * f2 + j[11] * f3,
    )


@njit(cache=True)
def objective_jacobian(q, d, s, f_out, j_out):
    """Array form of :func:`objective` and :func:`jacobian` for tests: f_out (3,), j_out (3, 4)."""
    f = objective(q[0], q[1], q[2], q[3], d[0], d[1], d[2], s[0], s[1], s[2])
    j = jacobian(q[0], q[1], q[2], q[3], d[0], d[1], d[2])
    for r in range(3):
        f_out[r] = f[r]
        for c in range(4):
            j_out[r, c] = j[4 * r + c]


@njit(cache=True, inline="always")
def _rotate(w, x, y, z, vx, vy, vz):
    """rotate(q, v) = R(q) v (body to earth)."""
    return (
        (1.0 - 2.0 * (y * y + z * z)) * vx
        + 2.0 * (x * y - w * z) * vy
        + 2.0 * (x * z + w * y) * vz,
        2.0 * (x * y + w * z) * vx
        + (1.0 - 2.0 * (x * x + z * z)) * vy
        + 2.0 * (y * z - w * x) * vz,
        2.0 * (x * z - w * y) * vx
        + 2.0 * (y * z + w * x) * vy
        + (1.0 - 2.0 * (x * x + y * y)) * vz,
    )


@njit(cache=True, inline="always")
def _rotate_inverse(w, x, y, z, vx, vy, vz):
    """rotate_inverse(q, v) = R(q)ᵀ v (earth to body)."""
    return _rotate(w, -x, -y, -z, vx, vy, vz)



# -- row slots (after the contract's) ----------------------------------------------------
G_Q = contract.N_CONTRACT  # 4: orientation, body to NWU
G_MAG_REF = G_Q + 4  # 2: fixed field reference [b_x, b_z] (b_x = 0: none yet)
G_ACC_HELD = G_MAG_REF + 2  # 3: held accelerometer sample, m/s²
G_MAG_HELD = G_ACC_HELD + 3  # 3: held magnetometer sample, field unit
N_ROW = G_MAG_HELD + 3

# -- coefficients ---------------------------------------------------------------------------
C_BETA = 0  # rad/s
C_MAG_MODE = 1  # FORWARD_ESTIMATED ... FULL_FIXED
C_EXACT = 2  # 1: q ⊗ exp(ω dt/2); 0: q + q̇ dt
C_GRAVITY = 3  # m/s²
C_USE_MAG = 4  # 0: a given field is dropped by the entry points
C_TO_FRAME = 5  # 4: c, q_frame = c ⊗ q_nwu
C_UP = 9  # 3: up in the output frame
N_COEF = 12

# -- extra outputs ----------------------------------------------------------------------------
X_EULER = 0  # 3: [yaw, pitch, roll], rad
X_GRAVITY = 3  # 3: gravity component, body, m/s²
X_LIN_ACC = 6  # 3: linear acceleration, output frame, m/s²
X_IGNORED = 9  # 1: ``ignored`` bits
N_OUT = 10


@njit(cache=True, inline="always")
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
    gx, gy, gz = _rotate_inverse(ow, ox, oy, oz, ux, uy, uz)
    x_out[X_GRAVITY] = g * gx
    x_out[X_GRAVITY + 1] = g * gy
    x_out[X_GRAVITY + 2] = g * gz
    ex, ey, ez = _rotate(ow, ox, oy, oz, a0, a1, a2)
    x_out[X_LIN_ACC] = ex - g * ux
    x_out[X_LIN_ACC + 1] = ey - g * uy
    x_out[X_LIN_ACC + 2] = ez - g * uz


@njit(cache=True, inline="always")
def _start(row, coef, first, qw, qx, qy, qz):
    """(Re)start at q (output frame): the NWU orientation ``c* ⊗ q``. The field reference
    and the held samples belong to the sensors and the field: kept (a fresh row has none)."""
    c = C_TO_FRAME
    w, x, y, z = mul(coef[c], -coef[c + 1], -coef[c + 2], -coef[c + 3], qw, qx, qy, qz)
    row[G_Q], row[G_Q + 1], row[G_Q + 2], row[G_Q + 3] = w, x, y, z


@njit(cache=True, inline="always")
def _step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out):
    """One screened sample: correction, propagation and fusion; returns ``Flag`` bits.

    rad/s, m/s², any field unit; an all-zero acc or field is "no measurement" (that
    correction is skipped); ``dt = 0`` integrates nothing and makes no correction step
    (β dt = 0), so a no-op sample leaves the orientation as it was, renormalised. Returns
    ``Flag.ACC_IGNORED`` for the filter's ACC_IGNORED and ``Flag.MAG_IGNORED`` for its
    MAG_REJECTED (a zero field is the screening's sentinel, flagged there with its reason).

    The recursion runs in NWU (x north, y west, z up), Madgwick's frame: the objective in
    its unit-norm form (``1/2 - q3² - q4²``) is not invariant under a change of earth frame
    off the unit sphere, so the radial part of ∇f, and with it the normalised step
    ``∇f / |∇f|``, would depend on the frame. One internal frame makes every output frame
    the same rotation and the full-vector variant equal to ahrs.filters.Madgwick.
    """
    w, x, y, z = row[G_Q], row[G_Q + 1], row[G_Q + 2], row[G_Q + 3]
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
                    vx, vy, vz = _rotate_inverse(w, x, y, z, 0.0, 0.0, 1.0)
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
                if mode == FULL_ADAPTIVE or row[G_MAG_REF] <= 0.0:
                    hx, hy, hz = _rotate(w, x, y, z, mx, my, mz)
                    dx, dz = math.sqrt(hx * hx + hy * hy), hz
                    if mode == FULL_FIXED:
                        row[G_MAG_REF], row[G_MAG_REF + 1] = dx, dz
                else:
                    dx, dz = row[G_MAG_REF], row[G_MAG_REF + 1]
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
    row[G_Q], row[G_Q + 1], row[G_Q + 2], row[G_Q + 3] = w, x, y, z
    row[G_ACC_HELD], row[G_ACC_HELD + 1], row[G_ACC_HELD + 2] = a0, a1, a2
    if has_mag:
        row[G_MAG_HELD], row[G_MAG_HELD + 1], row[G_MAG_HELD + 2] = m0, m1, m2
    # -- outputs in the output frame ---------------------------------------------------------
    c = C_TO_FRAME
    ow, ox, oy, oz = mul(coef[c], coef[c + 1], coef[c + 2], coef[c + 3], w, x, y, z)
    q_out[0], q_out[1], q_out[2], q_out[3] = ow, ox, oy, oz
    _outputs(coef, ow, ox, oy, oz, a0, a1, a2, x_out)
    x_out[X_IGNORED] = bits
    return (screen.ACC_IGNORED if bits & ACC_IGNORED else 0) | (
        screen.MAG_IGNORED if bits & MAG_REJECTED else 0
    )


@njit(cache=True, inline="always")
def _hold(row, coef, x_out):
    """Outputs of the held orientation (no accelerometer: the linear acceleration is
    ``-g up``, as for a gyro-only step); no ``ignored`` bits."""
    k = contract.K_Q
    _outputs(coef, row[k], row[k + 1], row[k + 2], row[k + 3], 0.0, 0.0, 0.0, x_out)
    x_out[X_IGNORED] = 0.0


@njit(cache=True, inline="always")
def _has(coefs, has):
    """The ``has`` bits with a given field dropped when ``use_mag`` is off (then the
    screening does not judge it and a start levels on gravity alone)."""
    return has if coefs[contract.N_SCOEF + C_USE_MAG] > 0.5 else has & ~1


@njit(cache=True)
def run(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples (``contract.run_series``)."""
    contract.run_series(_start, _step, _hold, rows, clock, coefs, t, gyr, acc, mag,
                        _has(coefs, has), q_out, x_out, flags_out)


@njit(cache=True, parallel=True)
def run_many(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples, shared among threads (``contract.run_series_parallel``)."""
    contract.run_series_parallel(_start, _step, _hold, rows, clock, coefs, t, gyr, acc, mag,
                                 _has(coefs, has), q_out, x_out, flags_out)


@njit(cache=True)
def update(rows, clock, coefs, dt, gyr, acc, mag, has, q_out, x_out, flags_out):
    """One sample of S sensors (``contract.update_samples``)."""
    contract.update_samples(_start, _step, _hold, rows, clock, coefs, dt, gyr, acc, mag,
                            _has(coefs, has), q_out, x_out, flags_out)


@njit(cache=True)
def update_one(rows, clock, coefs, dt, g, a, m, has, out):
    """One sample of one sensor (``contract.update_one``); returns the flags."""
    return contract.update_one(_start, _step, _hold, rows, clock, coefs, dt, g, a, m,
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
