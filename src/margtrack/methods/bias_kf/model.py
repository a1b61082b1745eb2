"""The model of Ang's bias Kalman filter (003 eqs. 10-51): its matrices, measurements, updates.

The pieces :mod:`margtrack.methods.bias_kf.step` assembles into one filter step: ``Q̃`` and
``Φ_Q`` (eqs. 23-27), the quaternion noise of an angle covariance (eqs. 31, 46), the TRIAD
measurement and its error covariance (eqs. 10-13, 38, 45), margtrack's decoupled
tilt/heading measurement and tilt gate, and the reduced Kalman update of the partial
measurements (:mod:`margtrack.methods.bias_kf.partial`). The prediction and the full
update (eqs. 48-51) are :mod:`margtrack.methods.bias_kf.cov`. The matrix helpers write
into buffers the caller provides (the filter keeps them in its state row); the tests use
``fill_phi_q``, ``fill_qtilde`` and ``fill_quat_noise`` to build the dense matrices the
hand-derived algebra is checked against.

Convention notes (derived, the extracted text of 003 differs):

- eq. 21 prints ``Ω̃ = [[0, -Ωᵀ], [Ω, +Ω×]]``; with ``q`` body-to-earth (eq. 38 builds
  ``q`` from ``C^T``, the body-to-world matrix) the kinematics are ``q̇ = ½ q ⊗ (0, Ω)``,
  whose matrix is ``[[0, -Ωᵀ], [Ω, -Ω×]]``. The sign of ``Ω×`` is flipped here.
- eq. 24 lists ``Q̃`` with the scalar row last (Lefferts' vector-first layout) although
  eq. 14 puts ``q0`` first; here the scalar row comes first, so ``Q̃ b = q ⊗ (0, b)``.
- eq. 28 prints ``Φ_B = -½ Φ_Q Q̃``; integrating eq. 22 over one period gives
  ``Φ_B = -½ T Φ_Q Q̃`` (the ``T`` makes ``Φ_B b`` dimensionless).
"""

from __future__ import annotations

import math

from numpy.lib.stride_tricks import as_strided

from margtrack.estimator.jit import njit
from margtrack.estimator.linalg_kernel import add_kalman_gain, cholesky
from margtrack.estimator.quat_kernel import cross, mul, normalized
from margtrack.estimator.triad_kernel import (
    OK,
    PARALLEL,
    PARALLEL_SINE,
    reference_triad,
    rotate,
    triad_unit,
    unit_pair,
)

__all__ = [
    "fill_decoupled_cov",
    "fill_phi_q",
    "fill_qtilde",
    "fill_quat_noise",
    "fill_triad_cov",
]

@njit(cache=True, inline="always")
def _mat(vec, offset, rows, cols):
    """The (rows, cols) row-major matrix at ``vec[offset:]``: a view, built in place (a
    ``reshape`` costs a helper call, about ten times the arithmetic it would serve)."""
    item = vec.strides[0]
    return as_strided(vec[offset : offset + rows * cols], shape=(rows, cols),
                      strides=(cols * item, item))


@njit(cache=True)
def fill_qtilde(w, x, y, z, out):
    """Q̃ (4, 3) with ``Q̃ b = q ⊗ (0, b)`` (003 eqs. 23-24, scalar row first)."""
    out[0, 0], out[0, 1], out[0, 2] = -x, -y, -z
    out[1, 0], out[1, 1], out[1, 2] = w, -z, y
    out[2, 0], out[2, 1], out[2, 2] = z, w, -x
    out[3, 0], out[3, 1], out[3, 2] = -y, x, w


@njit(cache=True)
def fill_phi_q(tx, ty, tz, out):
    """Φ_Q (4, 4) = cos(|Θ|/2) I + sin(|Θ|/2)/|Θ| Θ̃ (003 eq. 27), ``Θ = Ω T`` rad.

    ``Φ_Q q = q ⊗ exp(Θ/2)``: the exact transition for a rate constant over the period,
    an orthogonal matrix (Θ̃ is skew), so it keeps unit norm.
    """
    angle = math.sqrt(tx * tx + ty * ty + tz * tz)
    c = math.cos(0.5 * angle)
    s = 0.5 - angle * angle / 48.0 if angle < 1e-6 else math.sin(0.5 * angle) / angle
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = c, -s * tx, -s * ty, -s * tz
    out[1, 0], out[1, 1], out[1, 2], out[1, 3] = s * tx, c, s * tz, -s * ty
    out[2, 0], out[2, 1], out[2, 2], out[2, 3] = s * ty, -s * tz, c, s * tx
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = s * tz, s * ty, -s * tx, c


@njit(cache=True)
def fill_quat_noise(w, x, y, z, cov3, qt, out, along_var=-1.0):
    """Covariance (4, 4) of ``q ⊗ exp(θ/2) - q`` for a body-frame error angle θ ~ N(0, cov3).

    First order: ``¼ Q̃ Ξ Q̃ᵀ`` (003 eqs. 31 and 46), singular along ``q`` itself. Along
    ``q`` the error is ``cos(|θ|/2) - 1 ≈ -|θ|²/8``, second order and never positive;
    ``along_var`` sets the variance given to that direction: < 0 uses its Gaussian second
    moment ``E|θ|⁴/64 = ((tr Ξ)² + 2 tr Ξ²)/64`` (capped at 1), which keeps ``P`` positive
    definite (process noise, initial covariance). The measurement uses 1, the largest
    second moment that component can have: it carries no orientation information and is
    biased (always <= 0), and a tiny variance there lets it leak into the state through
    cross-covariances (on static data the bias estimate then sits several σ off).
    ``qt`` is a (4, 3) buffer.
    """
    fill_qtilde(w, x, y, z, qt)
    tr = cov3[0, 0] + cov3[1, 1] + cov3[2, 2]
    tr2 = 0.0
    for i in range(3):
        for j in range(3):
            tr2 += cov3[i, j] * cov3[j, i]
    # |cos(|θ|/2) - 1| <= 1 for the angles <= π a sign-aligned quaternion can differ by,
    # so its second moment never exceeds 1 (the Gaussian moment does for huge Ξ)
    along = min((tr * tr + 2.0 * tr2) / 64.0, 1.0) if along_var < 0.0 else along_var
    q = (w, x, y, z)
    for i in range(4):
        for j in range(i, 4):
            acc = 0.0
            for a in range(3):
                row = qt[i, 0] * cov3[0, a] + qt[i, 1] * cov3[1, a] + qt[i, 2] * cov3[2, a]
                acc += row * qt[j, a]
            value = 0.25 * acc + along * q[i] * q[j]
            out[i, j] = value
            out[j, i] = value


@njit(cache=True)
def fill_triad_cov(zx, zy, zz, nx, ny, nz, var_g, var_n, out):
    """TRIAD error-angle covariance (3, 3), body frame, rad² (003 eq. 45; Shuster & Oh 1981).

    ``z`` unit up (accelerometer) and ``n`` unit field, body frame; ``var_g``, ``var_n`` the
    variances of a component of each unit vector normal to it (eqs. 41, 44).
    ``Ξθ = σ_G² I + [(σ_N² - σ_G²) z zᵀ + σ_G² (z·n)(z nᵀ + n zᵀ)] / |z × n|²``.
    """
    cx, cy, cz = cross(zx, zy, zz, nx, ny, nz)
    inv = 1.0 / (cx * cx + cy * cy + cz * cz)
    d = zx * nx + zy * ny + zz * nz
    z = (zx, zy, zz)
    n = (nx, ny, nz)
    for i in range(3):
        for j in range(3):
            v = inv * ((var_n - var_g) * z[i] * z[j] + var_g * d * (z[i] * n[j] + n[i] * z[j]))
            out[i, j] = v + (var_g if i == j else 0.0)


@njit(cache=True, inline="always")
def triad_at(ax, ay, az, mx, my, mz, ux, uy, uz, nx, ny, nz):
    """TRIAD (003 eqs. 10-13) as a quaternion, with the unit body vectors it used.

    ``u``, ``n`` the unit earth up and north. Returns (flag, w, x, y, z, ẑ (3), n̂ (3));
    the quaternion is ``from_matrix`` of ``R = M_ref M_meaᵀ`` (body to earth, i.e.
    ``(ᵂC_B)ᵀ`` in the reference frame's axes) by the largest of four branches, so every
    orientation works (eq. 38 is only the ``q0 > 0`` branch and divides by zero at half
    turns). Scalars in and out: the filter's step inlines it without array views.
    """
    flag, ax, ay, az, mx, my, mz = unit_pair(ax, ay, az, mx, my, mz)  # eqs. 10-11
    if flag != OK:
        return flag, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0
    s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z = reference_triad(ux, uy, uz, nx, ny, nz)
    w, x, y, z = triad_unit(ax, ay, az, mx, my, mz, s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z)
    return OK, w, x, y, z, ax, ay, az, mx, my, mz


@njit(cache=True)
def _triad(ax, ay, az, mx, my, mz, up, north):
    """:func:`triad_at` with the earth up and north as arrays (3,)."""
    return triad_at(ax, ay, az, mx, my, mz, up[0], up[1], up[2], north[0], north[1], north[2])


@njit(cache=True, inline="always")
def _up_in_body(w, x, y, z, ux, uy, uz):
    """``R(q)ᵀ u``: the earth vector ``u`` in body coordinates (``q`` body to earth)."""
    return (
        (1.0 - 2.0 * (y * y + z * z)) * ux + 2.0 * (x * y + w * z) * uy
        + 2.0 * (x * z - w * y) * uz,
        2.0 * (x * y - w * z) * ux + (1.0 - 2.0 * (x * x + z * z)) * uy
        + 2.0 * (y * z + w * x) * uz,
        2.0 * (x * z + w * y) * ux + 2.0 * (y * z - w * x) * uy
        + (1.0 - 2.0 * (x * x + y * y)) * uz,
    )


@njit(cache=True, inline="always")
def _tilt_rotation(ax, ay, az, zx, zy, zz, fx, fy, fz):
    """Shortest rotation ``r`` taking the unit ``â`` to the unit ``ẑ`` (body frame), [w, x, y, z].

    Its axis ``â × ẑ`` is normal to ``ẑ``. For ``â = -ẑ`` any axis normal to ``ẑ`` turns it
    by π: the unit ``f`` given (normal to ``ẑ``) is used.
    """
    d = ax * zx + ay * zy + az * zz
    if 1.0 + d > 1e-12:
        rx, ry, rz = cross(ax, ay, az, zx, zy, zz)
        return normalized(1.0 + d, rx, ry, rz)
    return 0.0, fx, fy, fz


@njit(cache=True, inline="always")
def _decoupled(qw, qx, qy, qz, ax, ay, az, nx, ny, nz, zx, zy, zz, ref, r0):
    """Tilt from the accelerometer, heading from the field levelled by the predicted tilt.

    ``q⁻`` the predicted orientation, ``â``, ``n̂`` unit body accelerometer and field,
    ``ẑ`` the predicted body up; ``ref[r0:r0 + 6]`` the reference triad's ``s1, s2``
    (``triad.reference_triad`` of the earth's up and north). Returns (flag, w, x, y, z,
    |ẑ × n̂|²): ``q_A = TRIAD(ẑ, n̂)`` (:func:`_levelled_heading`) has the predicted tilt and
    the heading of the field projected on the plane normal to ``ẑ``; ``q = q_A ⊗ r`` with
    ``r`` the shortest rotation taking ``â`` to ``ẑ``, so ``q`` maps ``â`` to up. ``r``'s
    axis ``â × ẑ`` is normal to ``ẑ``, i.e. horizontal in the earth frame: the tilt
    correction leaves the heading alone. PARALLEL if ``ẑ`` and ``n̂`` are (nearly) parallel.
    """
    flag, hw, hx, hy, hz, c2, ex, ey, ez = _levelled_heading(qw, qx, qy, qz, nx, ny, nz,
                                                             zx, zy, zz, ref, r0)
    if flag != OK:
        return flag, 1.0, 0.0, 0.0, 0.0, c2
    rw, rx, ry, rz = _tilt_rotation(ax, ay, az, zx, zy, zz, ex, ey, ez)
    w, x, y, z = mul(hw, hx, hy, hz, rw, rx, ry, rz)
    return OK, w, x, y, z, c2


@njit(cache=True, inline="always")
def _levelled_heading(qw, qx, qy, qz, nx, ny, nz, zx, zy, zz, ref, r0):
    """``TRIAD(ẑ, n̂)``: the predicted tilt with the heading of the unit field ``n̂``.

    ``ẑ = R(q⁻)ᵀ s1`` is the predicted body up of the unit ``q⁻`` and ``ref[r0:r0 + 6]``
    the reference triad's ``s1`` (earth up) and ``s2 = s1 × north / |.|``. TRIAD maps
    ``ẑ`` to ``s1`` and ``r₂ = ẑ × n̂ / |.|`` to ``s2``; ``q⁻`` already maps ``ẑ`` to
    ``s1``, so ``TRIAD(ẑ, n̂) = h ⊗ q⁻`` with ``h`` the turn about ``s1`` taking
    ``e₂ = R(q⁻) r₂`` (horizontal) to ``s2``: ``h ∝ (1 + e₂·s2, (e₂ × s2)·s1 s1)``, a half
    turn about ``s1`` when ``e₂ = -s2``. The same quaternion as ``triad.triad_unit`` up to
    rounding and sign, without its matrix, its four branches and four of its roots and
    divisions. Returns (flag, w, x, y, z, |ẑ × n̂|², r₂); PARALLEL if ``ẑ`` and ``n̂`` are
    (nearly) parallel (the field then has no horizontal direction).
    """
    cx, cy, cz = cross(zx, zy, zz, nx, ny, nz)
    c2 = cx * cx + cy * cy + cz * cz
    if c2 < PARALLEL_SINE * PARALLEL_SINE:
        return PARALLEL, 1.0, 0.0, 0.0, 0.0, c2, 0.0, 0.0, 0.0
    inv = 1.0 / math.sqrt(c2)
    cx, cy, cz = cx * inv, cy * inv, cz * inv
    ux, uy, uz = ref[r0], ref[r0 + 1], ref[r0 + 2]
    sx, sy, sz = ref[r0 + 3], ref[r0 + 4], ref[r0 + 5]
    ex, ey, ez = rotate(qw, qx, qy, qz, cx, cy, cz)
    cos_psi = ex * sx + ey * sy + ez * sz
    tx, ty, tz = cross(ex, ey, ez, sx, sy, sz)
    sin_psi = tx * ux + ty * uy + tz * uz
    hw, hv = 1.0 + cos_psi, sin_psi
    n2 = hw * hw + hv * hv
    if n2 > 1e-30:
        n = 1.0 / math.sqrt(n2)
        hw, hv = hw * n, hv * n
    else:  # e₂ = -s2: half a turn
        hw, hv = 0.0, 1.0
    w, x, y, z = mul(hw, hv * ux, hv * uy, hv * uz, qw, qx, qy, qz)
    return OK, w, x, y, z, c2, cx, cy, cz


@njit(cache=True)
def fill_decoupled_cov(zx, zy, zz, var_g, var_h, out):
    """Error-angle covariance (3, 3) of the decoupled measurement, body frame, rad².

    ``σ_G² (I - ẑẑᵀ) + σ_H² ẑẑᵀ``: the tilt (normal to the up ``ẑ``) from the
    accelerometer, variance ``var_g`` per axis; the heading (about ``ẑ``) from the field
    only, ``var_h = σ_N² / |ẑ × n̂|²`` (eq. 45 without the ``σ_G²`` terms that carry the
    accelerometer's tilt error into TRIAD's heading).
    """
    z = (zx, zy, zz)
    for i in range(3):
        for j in range(3):
            out[i, j] = (var_h - var_g) * z[i] * z[j] + (var_g if i == j else 0.0)


@njit(cache=True, inline="always")
def _joseph(p, zmat, zh, kv, gain, n, m):
    """``P = Z - Z Hᵀ Kᵀ + K V Kᵀ`` (003 eq. 51, Joseph form) from Z = (I - K H) P, Z Hᵀ
    (n, m) and K V (n, m), written to the upper triangle and mirrored: exactly symmetric."""
    for r in range(n):
        for c in range(r, n):
            acc = zmat[r, c]
            for k in range(m):
                acc += (kv[r, k] - zh[r, k]) * gain[c, k]
            p[r, c] = acc
    for r in range(n):
        for c in range(r):
            p[r, c] = p[c, r]


@njit(cache=True)
def _reduced_update(p, hq, m, v, innov, chol, y, gain, hp, zmat, zh, kv, dx):
    """Kalman update with ``H = [Hq 0]``, ``Hq`` the first ``m`` rows of ``hq`` (3, 4).

    The partial measurements (tilt only, heading only) observe ``m`` < 3 directions of
    the quaternion: ``hq`` holds them as unit rows ``(q ⊗ (0, a_k))ᵀ`` for body axes
    ``a_k``, ``v`` (m, m) their covariance, ``innov`` (m,) the innovation along them. The
    directions not measured get no update at all (rather than a large variance, which
    would still shrink their covariance a little at every sample). Fills ``dx = K ν`` and
    ``P`` in Joseph form (:func:`_joseph`); False (nothing changed) if the
    innovation covariance is not positive definite. The rest are buffers.
    """
    n = p.shape[0]
    for r in range(m):  # H P (m, n)
        for c in range(n):
            acc = 0.0
            for k in range(4):
                acc += hq[r, k] * p[k, c]
            hp[r, c] = acc
    for r in range(m):  # S = H P Hᵀ + V
        for c in range(r + 1):
            acc = v[r, c]
            for k in range(4):
                acc += hp[r, k] * hq[c, k]
            zmat[r, c] = acc
    if not cholesky(zmat, m, chol):
        return False
    for r in range(n):
        dx[r] = 0.0
    add_kalman_gain(chol, m, hp, innov, dx, y, gain)  # K = P Hᵀ S⁻¹ (eq. 49), dx = K ν (eq. 50)
    for r in range(n):  # Z = (I - KH) P, K V
        for c in range(n):
            acc = p[r, c]
            for k in range(m):
                acc -= gain[r, k] * hp[k, c]
            zmat[r, c] = acc
        for c in range(m):
            acc = 0.0
            for k in range(m):
                acc += gain[r, k] * v[k, c]
            kv[r, c] = acc
    for r in range(n):  # Z Hᵀ
        for c in range(m):
            acc = 0.0
            for k in range(4):
                acc += zmat[r, k] * hq[c, k]
            zh[r, c] = acc
    _joseph(p, zmat, zh, kv, gain, n, m)
    return True


@njit(cache=True)
def _normal_axes(zx, zy, zz):
    """Two unit axes normal to the unit ``ẑ`` and to each other (6 numbers)."""
    # cross with the coordinate axis least aligned with ẑ
    if abs(zx) <= abs(zy) and abs(zx) <= abs(zz):
        ex, ey, ez = 1.0, 0.0, 0.0
    elif abs(zy) <= abs(zz):
        ex, ey, ez = 0.0, 1.0, 0.0
    else:
        ex, ey, ez = 0.0, 0.0, 1.0
    ax, ay, az = cross(zx, zy, zz, ex, ey, ez)
    inv = 1.0 / math.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax * inv, ay * inv, az * inv
    bx, by, bz = cross(zx, zy, zz, ax, ay, az)
    return ax, ay, az, bx, by, bz


@njit(cache=True)
def _fill_direction(qt, ax, ay, az, hq, row):
    """``hq[row] = (Q̃ a)ᵀ``: the quaternion direction ``q ⊗ (0, a)`` of body axis ``a``."""
    for k in range(4):
        hq[row, k] = qt[k, 0] * ax + qt[k, 1] * ay + qt[k, 2] * az


@njit(cache=True, inline="always")
def _gate_weight(ratio, exponent):
    """``ratio ** exponent``, as ``ratio √ratio`` for the default exponent 1.5 (a fifth of
    ``pow``'s time; equal to its last bit or two)."""
    if exponent == 1.5:
        return ratio * math.sqrt(ratio)
    return ratio**exponent


@njit(cache=True, inline="always")
def _acc_variance(white_g, corr_a, acc_norm_corr_s, na, g_abs):
    """``σ_G²`` of the unit gravity direction (eqs. 41-43, ``acc_norm_correlation_s``).

    ``white_g = (σ_W²/T + σ_C²)/g²`` (eqs. 41-43) and ``corr_a = 2τ_a/T``: the filter
    derives both once per sample interval ``T``; ``na`` = |a|, ``g_abs`` = g.
    """
    var_g = white_g
    if acc_norm_corr_s > 0.0:  # time-correlated body acceleration
        var_g += (na / g_abs - 1.0) ** 2 * corr_a
    return var_g


@njit(cache=True, inline="always")
def _mag_variance(white_n, h, nm, sin_dip, ref_norm, ref_sin_dip, norm_corr_s, dip_corr_s):
    """``σ_N²`` of the unit field direction (eq. 44 and the disturbance terms).

    ``white_n = mag_var / T``, with ``mag_var`` the field's squared white-noise density
    relative to the reference field's norm (1/Hz): the sensor's noise ``σ_M`` is
    ``√mag_var · |m₀|`` in the data's unit, so eq. 44's ``σ_M²/|m|²`` is
    ``mag_var (|m₀|/|m|)²`` and nothing depends on the magnetometer's unit (a weakened
    field is trusted less, a stronger one more, as with an absolute noise density).
    """
    var_n = white_n * (ref_norm / nm) ** 2  # eq. 44
    if norm_corr_s > 0.0 or dip_corr_s > 0.0:  # magnetic disturbance: field norm and dip
        var_n += (
            (nm / ref_norm - 1.0) ** 2 * (2.0 * norm_corr_s)
            + (sin_dip - ref_sin_dip) ** 2 * (2.0 * dip_corr_s)
        ) / h
    return var_n
