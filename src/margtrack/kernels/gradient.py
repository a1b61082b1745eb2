"""Kernel of the gradient-descent filter (004, an extension of Madgwick's filter).

Quaternions are body-to-earth ``[w, x, y, z]`` (004's ``q1..q4``); Madgwick's and 004's
``^S_E q`` is numerically the same quaternion, their ``q* ⊗ d ⊗ q`` is our
``rotate_inverse(q, d)``.
"""

from __future__ import annotations

import math

from numba import njit

from margtrack.kernels._quat import exp_half, mul

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

# magnetic objectives (``mag_mode``)
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


@njit(cache=True)
def gradient_filter(
    quat_state, mag_ref, gyr, acc, mag, has_mag, dt, beta, to_frame, up, mag_mode, exact,
    gravity_m_s2, quat_out, euler_out, gravity_out, lin_acc_out, flags_out,
):
    """Run the gradient-descent filter over S sensors and N samples.

    quat_state (S, 4) in/out, in the output frame; gyr, acc (S, N, 3) rad/s and m/s²;
    mag (S, N, 3) any unit, read only if ``has_mag``; dt (N,) s (dt[0] = 0 after a reset:
    the first output is the state, renormalised); beta rad/s; ``to_frame`` (4,) the unit
    quaternion c with ``q_frame = c ⊗ q_nwu``; ``up`` (3,) up in the output frame;
    ``mag_mode``: one of the magnetic objectives below; ``mag_ref`` (S, 2) in/out, the
    fixed reference [b_x, b_z] of FULL_FIXED (b_x = 0: not measured yet);
    ``exact``: ``q ⊗ exp(ω dt/2)`` instead of 004's Euler step ``q + q̇ dt``.
    Outputs (S, N, ...): quat (output frame), euler [yaw, pitch, roll] rad, gravity
    component in the body m/s², earth-frame linear acceleration m/s², ``ignored`` flags.

    Screened input (``estimator/screening.py``): an all-zero acc or mag is "no measurement"
    (that correction is skipped); ``dt = 0`` integrates nothing and makes no correction
    step (β dt = 0), so a no-op sample leaves the orientation as it was, renormalised.

    The recursion runs in NWU (x north, y west, z up), Madgwick's frame: the objective in
    its unit-norm form (``1/2 - q3² - q4²``) is not invariant under a change of earth frame
    off the unit sphere, so the radial part of ∇f, and with it the normalised step
    ``∇f / |∇f|``, would depend on the frame. One internal frame makes every output frame
    the same rotation and the full-vector variant equal to ahrs.filters.Madgwick.
    """
    n_sensors, n_samples = acc.shape[0], acc.shape[1]
    cw, cx, cy, cz = to_frame[0], to_frame[1], to_frame[2], to_frame[3]
    ux, uy, uz = up[0], up[1], up[2]
    for s in range(n_sensors):
        w, x, y, z = mul(
            cw, -cx, -cy, -cz,
            quat_state[s, 0], quat_state[s, 1], quat_state[s, 2], quat_state[s, 3],
        )
        ow, ox, oy, oz = quat_state[s, 0], quat_state[s, 1], quat_state[s, 2], quat_state[s, 3]
        for i in range(n_samples):
            h = dt[i]
            flag = 0
            # -- correction: gradient of the stacked objectives at the prior q (NWU) -------
            g0, g1, g2, g3 = 0.0, 0.0, 0.0, 0.0
            ax, ay, az = acc[s, i, 0], acc[s, i, 1], acc[s, i, 2]
            na = math.sqrt(ax * ax + ay * ay + az * az)
            if na > 0.0:
                ax, ay, az = ax / na, ay / na, az / na
                # gravity: reference up = z, measured â (004: a_g points upward)
                g0, g1, g2, g3 = gradient_term(w, x, y, z, 0.0, 0.0, 1.0, ax, ay, az)
                if has_mag:
                    mx, my, mz = mag[s, i, 0], mag[s, i, 1], mag[s, i, 2]
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
                    if use and mag_mode <= FORWARD_MEASURED:
                        # forward component m_f = m - (m·v̂) v̂, the rejection of m from the
                        # gravity direction v̂ (004 "Definitions", "Inputs and Outputs"; the
                        # extracted reject formula garbles its operands), matched to north:
                        # v̂ is 004's gravity component a_g, the filter's own estimate
                        # R(q)ᵀ up, or (FORWARD_MEASURED) the raw accelerometer â
                        if mag_mode == FORWARD_ESTIMATED:
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
                        # full vector, reference b = [b_x, 0, b_z]: Madgwick's from the field
                        # seen in the earth frame, h = q ⊗ m̂ ⊗ q*, b_x = |h_horizontal|,
                        # b_z = h_z (his eqs. 45-46), or (FULL_FIXED) the first such b, kept
                        mx, my, mz = mx / nm, my / nm, mz / nm
                        if mag_mode == FULL_ADAPTIVE or mag_ref[s, 0] <= 0.0:
                            hx, hy, hz = _rotate(w, x, y, z, mx, my, mz)
                            dx, dz = math.sqrt(hx * hx + hy * hy), hz
                            if mag_mode == FULL_FIXED:
                                mag_ref[s, 0], mag_ref[s, 1] = dx, dz
                        else:
                            dx, dz = mag_ref[s, 0], mag_ref[s, 1]
                    if use:
                        m0, m1, m2, m3 = gradient_term(w, x, y, z, dx, 0.0, dz, mx, my, mz)
                        g0, g1, g2, g3 = g0 + m0, g1 + m1, g2 + m2, g3 + m3
                    else:
                        flag |= MAG_IGNORED | (MAG_REJECTED if nm > 0.0 else 0)
            else:
                # gyro-only step (Madgwick's: no feedback without a valid accelerometer)
                field = has_mag and (
                    mag[s, i, 0] != 0.0 or mag[s, i, 1] != 0.0 or mag[s, i, 2] != 0.0
                )
                if field:
                    flag |= ACC_IGNORED | MAG_REJECTED
                elif h > 0.0:
                    flag |= ACC_IGNORED
                # else a no-op sample (dt = 0, no acc, no field: a skipped timestamp): nothing
                # was there to be used, nothing is flagged
            gn = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2 + g3 * g3)
            if gn > GRADIENT_MIN:
                g0, g1, g2, g3 = g0 / gn, g1 / gn, g2 / gn, g3 / gn
            else:
                g0, g1, g2, g3 = 0.0, 0.0, 0.0, 0.0
            # -- propagation and fusion (004 "Gyroscope Equations"; Madgwick eq. 42) -------
            wx, wy, wz = gyr[s, i, 0], gyr[s, i, 1], gyr[s, i, 2]
            if exact:
                ew, ex, ey, ez = exp_half(wx, wy, wz, h)
                pw, px, py, pz = mul(w, x, y, z, ew, ex, ey, ez)
                step = beta * h
                pw, px, py, pz = pw - step * g0, px - step * g1, py - step * g2, pz - step * g3
            else:
                # q̇ = ½ q ⊗ (0, ω) - β ∇f/|∇f|, then q + q̇ Δt (as ahrs.filters.Madgwick)
                dw, dx_, dy_, dz_ = mul(w, x, y, z, 0.0, wx, wy, wz)
                dw, dx_, dy_, dz_ = (
                    0.5 * dw - beta * g0, 0.5 * dx_ - beta * g1,
                    0.5 * dy_ - beta * g2, 0.5 * dz_ - beta * g3,
                )
                pw, px, py, pz = w + dw * h, x + dx_ * h, y + dy_ * h, z + dz_ * h
            norm = math.sqrt(pw * pw + px * px + py * py + pz * pz)
            w, x, y, z = pw / norm, px / norm, py / norm, pz / norm
            # -- outputs in the output frame -----------------------------------------------
            ow, ox, oy, oz = mul(cw, cx, cy, cz, w, x, y, z)
            quat_out[s, i, 0] = ow
            quat_out[s, i, 1] = ox
            quat_out[s, i, 2] = oy
            quat_out[s, i, 3] = oz
            flags_out[s, i] = flag
            # Euler angles (004 "Inputs and Outputs", squares restored)
            ww, xx, yy, zz = ow * ow, ox * ox, oy * oy, oz * oz
            euler_out[s, i, 0] = math.atan2(2.0 * (ox * oy + oz * ow), xx - yy - zz + ww)
            sp = -2.0 * (ox * oz - oy * ow)
            euler_out[s, i, 1] = math.asin(min(1.0, max(-1.0, sp)))
            euler_out[s, i, 2] = math.atan2(2.0 * (oy * oz + ox * ow), -xx - yy + zz + ww)
            # gravity component a_g in the body (points up) and a_m = R a - g up in the earth
            gx, gy, gz = _rotate_inverse(ow, ox, oy, oz, ux, uy, uz)
            gravity_out[s, i, 0] = gravity_m_s2 * gx
            gravity_out[s, i, 1] = gravity_m_s2 * gy
            gravity_out[s, i, 2] = gravity_m_s2 * gz
            ex_, ey_, ez_ = _rotate(ow, ox, oy, oz, acc[s, i, 0], acc[s, i, 1], acc[s, i, 2])
            lin_acc_out[s, i, 0] = ex_ - gravity_m_s2 * ux
            lin_acc_out[s, i, 1] = ey_ - gravity_m_s2 * uy
            lin_acc_out[s, i, 2] = ez_ - gravity_m_s2 * uz
        quat_state[s, 0], quat_state[s, 1], quat_state[s, 2], quat_state[s, 3] = ow, ox, oy, oz
