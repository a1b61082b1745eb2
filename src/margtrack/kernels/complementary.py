"""Kernel of Bachmann's quaternion complementary filter (000, Appendix A, eqs. 13-27).

The Gauss-Newton drift correction is computed in the closed form derived in
:mod:`margtrack.filters.complementary`: with ``R`` the rotation of ``q̂`` (body to earth),
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
"""

from __future__ import annotations

import math

from numba import njit

from margtrack.kernels._quat import cross, mul

OK = 0
ZERO_ACC = 1  # no correction at this sample: the accelerometer reads zero
ZERO_MAG = 2  # gravity-only correction at this sample: the magnetometer reads zero
NO_FIELD_REFERENCE = 3  # gravity-only correction: the sensor's field reference is not known yet

#: the heading is set from a field sample only when the field seen in the earth frame is
#: at least this far from vertical (sine of 5 deg: MIN_REFERENCE_ANGLE_DEG of the filter)
HEADING_MIN_SINE = 0.08715574274765817


@njit(cache=True, inline="always")
def _rotate(w, x, y, z, vx, vy, vz):
    """q ⊗ (0, v) ⊗ q* for unit q: ``v + 2 w (u × v) + 2 u × (u × v)``, u = (x, y, z)."""
    tx, ty, tz = cross(x, y, z, vx, vy, vz)
    tx, ty, tz = 2.0 * tx, 2.0 * ty, 2.0 * tz
    cx, cy, cz = cross(x, y, z, tx, ty, tz)
    return vx + w * tx + cx, vy + w * ty + cy, vz + w * tz + cz


@njit(cache=True, inline="always")
def _unit_or_previous(w, x, y, z, pw, px, py, pz):
    """q / |q| (eq. 27's normalisation), safe for any finite or non-finite q.

    When ``|q|²`` overflows the components are first divided by the largest one; when q
    is zero or not finite the previous unit quaternion p is returned (the step is not
    representable: the sample is not integrated).
    """
    n2 = w * w + x * x + y * y + z * z
    if n2 > 0.0 and n2 < math.inf:
        scale = 1.0 / math.sqrt(n2)
        return w * scale, x * scale, y * scale, z * scale
    big = max(max(abs(w), abs(x)), max(abs(y), abs(z)))
    if big > 0.0 and big < math.inf:
        w, x, y, z = w / big, x / big, y / big, z / big
        scale = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)  # >= 1/2: no overflow
        return w * scale, x * scale, y * scale, z * scale
    return pw, px, py, pz


@njit(cache=True)
def _set_heading(qw, qx, qy, qz, bx, by, bz, mx, my, mz, nx, ny, nz):
    """q̂ turned about the unit gravity reference m so that the field b (body) seen in the
    earth frame has the horizontal direction of the reference n; returns (q, still
    awaiting): unchanged and True when b is zero or seen within 5 deg of vertical."""
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    if not nb > 0.0:
        return qw, qx, qy, qz, True
    ex, ey, ez = _rotate(qw, qx, qy, qz, bx / nb, by / nb, bz / nb)
    d = ex * mx + ey * my + ez * mz
    ex, ey, ez = ex - d * mx, ey - d * my, ez - d * mz  # horizontal part of R b
    d = nx * mx + ny * my + nz * mz
    hx, hy, hz = nx - d * mx, ny - d * my, nz - d * mz  # horizontal part of n
    if ex * ex + ey * ey + ez * ez < HEADING_MIN_SINE * HEADING_MIN_SINE:
        return qw, qx, qy, qz, True
    cx, cy, cz = cross(ex, ey, ez, hx, hy, hz)
    angle = math.atan2(cx * mx + cy * my + cz * mz, ex * hx + ey * hy + ez * hz)
    c, s = math.cos(0.5 * angle), math.sin(0.5 * angle)
    qw, qx, qy, qz = mul(c, s * mx, s * my, s * mz, qw, qx, qy, qz)  # earth-frame turn
    return qw, qx, qy, qz, False


@njit(cache=True)
def bachmann(
    quat_state,
    step_state,
    phi_state,
    gyr,
    acc,
    mag,
    dt,
    grav_ref,
    mag_ref,
    gain,
    mag_weight,
    interval,
    phase,
    cycle0,
    boost_state,
    boost_gain,
    awaiting_state,
    quat_out,
    phi_out,
    corr_out,
    new_out,
    flags_out,
):
    """Run S filters over N samples; state arrays are updated in place.

    quat_state (S, 4) in/out: ``q̂`` before sample 0, replaced by the last one.
    step_state (S, 3) in/out: the held correction step ``Δv_E`` (earth frame).
    phi_state (S,) in/out: criterion of the held correction.
    gyr (S, N, 3) rad/s, or (S, 0, 3) for accelerometer/magnetometer-only tracking.
    acc (S, N, 3) any unit; mag (S, N, 3) any unit, or (S, 0, 3) without magnetometer.
    dt (N,) s; dt[0] = 0 leaves the first output at the state (the correction is still
    computed there). grav_ref (3,) unit ``m``; mag_ref (S, 3) unit ``n`` per sensor.
    gain ``k`` 1/s; mag_weight ``ρ``; interval: a new correction every ``interval``
    cycles, at cycles ``c`` with ``(c - phase[s]) % interval == 0``; phase (S,) in
    [0, interval); cycle0: cycle number of sample 0. A NaN row of mag_ref (field
    reference not known yet) gives gravity-only steps.
    boost_state (S,) in/out: time since a restart, s (negative: none under way). While
    it is under way the gain is ``1 / (t + 1 / boost_gain)`` (t counted up by each dt
    before the step), the gain that makes the correction the mean of the measurements
    since the restart, until that falls to k (then boost_state becomes -1). Nothing
    happens when boost_gain <= k.
    awaiting_state (S,) bool in/out: True until a usable field sample sets the heading:
    at the first field sample (non-zero, known reference, seen at least 5 deg from
    vertical) q̂ is turned about the gravity reference so that the field seen in the
    earth frame points to the reference's heading, and the flag clears. (A start from
    the accelerometer alone leaves the heading arbitrary, which ``ρ k`` would take
    minutes to correct; after a TRIAD start the turn is zero.)
    Outputs (S, N, ...): quat_out q̂; phi_out φ of the held correction; corr_out the
    applied correction as earth-frame rate ``ω_ε = 2 k Δv_E`` (rad/s, k as applied);
    new_out 1 where a new correction was computed; flags_out (at new ones) OK,
    ZERO_ACC, ZERO_MAG or NO_FIELD_REFERENCE.
    Returns the number of sensors whose state quaternion was zero or not finite (left
    untouched, outputs not written; the caller raises).
    """
    n_sensors, n_samples = acc.shape[0], acc.shape[1]
    use_gyr = gyr.shape[1] > 0
    use_mag = mag.shape[1] > 0
    mx, my, mz = grav_ref[0], grav_ref[1], grav_ref[2]
    start_gain = boost_gain > gain
    bad = 0
    for s in range(n_sensors):
        nx, ny, nz = mag_ref[s, 0], mag_ref[s, 1], mag_ref[s, 2]
        has_ref = not (math.isnan(nx) or math.isnan(ny) or math.isnan(nz))
        # M0 = 2 I - m mᵀ - n nᵀ and its inverse by cofactors (symmetric)
        a00 = 2.0 - mx * mx - nx * nx
        a01 = -mx * my - nx * ny
        a02 = -mx * mz - nx * nz
        a11 = 2.0 - my * my - ny * ny
        a12 = -my * mz - ny * nz
        a22 = 2.0 - mz * mz - nz * nz
        c00 = a11 * a22 - a12 * a12
        c01 = a02 * a12 - a01 * a22
        c02 = a01 * a12 - a02 * a11
        c11 = a00 * a22 - a02 * a02
        c12 = a01 * a02 - a00 * a12
        c22 = a00 * a11 - a01 * a01
        det = a00 * c00 + a01 * c01 + a02 * c02  # 2 sin² γ
        if not det > 1e-12:  # no reference, or one along gravity: gravity-only steps
            has_ref = False
            det = 1.0
        half_det_inv = 0.5 / det
        qw, qx, qy, qz = quat_state[s, 0], quat_state[s, 1], quat_state[s, 2], quat_state[s, 3]
        n2 = qw * qw + qx * qx + qy * qy + qz * qz
        if not (n2 > 0.0 and n2 < math.inf):  # a state set by hand: refused by the caller
            bad += 1
            continue
        vx, vy, vz = step_state[s, 0], step_state[s, 1], step_state[s, 2]
        phi = phi_state[s]
        since = boost_state[s] if start_gain else -1.0
        offset = interval - phase[s]
        awaiting = awaiting_state[s] and use_mag and has_ref
        for i in range(n_samples):
            new = (cycle0 + i + offset) % interval == 0
            flag = OK
            if awaiting:
                qw, qx, qy, qz, awaiting = _set_heading(
                    qw, qx, qy, qz, mag[s, i, 0], mag[s, i, 1], mag[s, i, 2],
                    mx, my, mz, nx, ny, nz,
                )
            if new:
                # steps 1-6 of 000's Fig. 5, in the earth frame (module docstring)
                ax, ay, az = acc[s, i, 0], acc[s, i, 1], acc[s, i, 2]
                na = math.sqrt(ax * ax + ay * ay + az * az)
                if na > 0.0:
                    hx, hy, hz = _rotate(qw, qx, qy, qz, ax / na, ay / na, az / na)
                    ex, ey, ez = hx - mx, hy - my, hz - mz  # R (h - ĥ) (eq. 15)
                    phi = ex * ex + ey * ey + ez * ez  # eq. 19, gravity part
                    rx, ry, rz = cross(hx, hy, hz, mx, my, mz)  # R (h × ĥ)
                    vx, vy, vz = 0.5 * rx, 0.5 * ry, 0.5 * rz  # minimum-norm step
                    if use_mag:
                        bx, by, bz = mag[s, i, 0], mag[s, i, 1], mag[s, i, 2]
                        nb = math.sqrt(bx * bx + by * by + bz * bz)
                        if nb > 0.0 and not has_ref:
                            flag = NO_FIELD_REFERENCE
                        elif nb > 0.0:
                            bx, by, bz = _rotate(qw, qx, qy, qz, bx / nb, by / nb, bz / nb)
                            ex, ey, ez = bx - nx, by - ny, bz - nz  # R (b - b̂) (eq. 16)
                            phi += mag_weight * mag_weight * (ex * ex + ey * ey + ez * ez)
                            cx, cy, cz = cross(bx, by, bz, nx, ny, nz)  # R (b × b̂)
                            # ρ weights the residual only (eqs. 17-18 vs eq. 20)
                            rx += mag_weight * cx
                            ry += mag_weight * cy
                            rz += mag_weight * cz
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
            h = dt[i]
            k = gain
            if since >= 0.0:  # after a restart: the mean of the measurements since (1/t)
                since += h
                k = 1.0 / (since + 1.0 / boost_gain)
                if k <= gain:
                    k = gain
                    since = -1.0
            # q̇_ε = k (0, Δv_E) ⊗ q̂, which is k q̂ ⊗ (0, Δv_full) = k Δq_full (eqs. 24-25)
            ew, ex, ey, ez = mul(0.0, vx, vy, vz, qw, qx, qy, qz)
            dw, dx, dy, dz = k * ew, k * ex, k * ey, k * ez
            if use_gyr:
                # q̇ = ½ q̂ ⊗ (0, ω) (eq. 26)
                gw, gx, gy, gz = mul(qw, qx, qy, qz, 0.0, gyr[s, i, 0], gyr[s, i, 1], gyr[s, i, 2])
                dw += 0.5 * gw
                dx += 0.5 * gx
                dy += 0.5 * gy
                dz += 0.5 * gz
            # q̂ + Δt (q̇ + q̇_ε), normalised (eq. 27); dt = 0 leaves q̂ exactly as it is
            if h != 0.0:
                qw, qx, qy, qz = _unit_or_previous(
                    qw + h * dw, qx + h * dx, qy + h * dy, qz + h * dz, qw, qx, qy, qz
                )
            quat_out[s, i, 0] = qw
            quat_out[s, i, 1] = qx
            quat_out[s, i, 2] = qy
            quat_out[s, i, 3] = qz
            phi_out[s, i] = phi
            two_k = 2.0 * k
            corr_out[s, i, 0] = two_k * vx
            corr_out[s, i, 1] = two_k * vy
            corr_out[s, i, 2] = two_k * vz
            new_out[s, i] = new
            flags_out[s, i] = flag
        quat_state[s, 0], quat_state[s, 1], quat_state[s, 2], quat_state[s, 3] = qw, qx, qy, qz
        step_state[s, 0], step_state[s, 1], step_state[s, 2] = vx, vy, vz
        phi_state[s] = phi
        boost_state[s] = since
        if awaiting_state[s] and use_mag and has_ref:
            awaiting_state[s] = awaiting
    return bad
