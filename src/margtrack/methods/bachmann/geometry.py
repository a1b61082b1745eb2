"""Earth-frame geometry of Bachmann's filter (000, Appendix A): the normalisation of
eq. 27, the heading set from the field, and the cofactors of M0 (vectors are rotated by
``triad.rotate``).

Quaternions are body to earth ``[w, x, y, z]``; vectors are 3 floats. Used by
:mod:`margtrack.methods.bachmann.kernel` (its module docstring has the derivation).
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit
from margtrack.estimator.linalg_kernel import sym3_adjugate
from margtrack.estimator.quat_kernel import cross, mul
from margtrack.estimator.triad_kernel import rotate

#: the heading is set from a field sample only when the field seen in the earth frame is
#: at least this far from vertical (sine of 5 deg: MIN_REFERENCE_ANGLE_DEG of the filter)
HEADING_MIN_SINE = 0.08715574274765817


@njit(cache=True, inline="always")
def unit_or_previous(w, x, y, z, pw, px, py, pz):
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
def set_heading(qw, qx, qy, qz, bx, by, bz, mx, my, mz, nx, ny, nz):
    """q̂ turned about the unit gravity reference m so that the field b (body) seen in the
    earth frame has the horizontal direction of the reference n; returns (q, still
    awaiting): unchanged and True when b is zero or seen within 5 deg of vertical."""
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    if not nb > 0.0:
        return qw, qx, qy, qz, True
    ex, ey, ez = rotate(qw, qx, qy, qz, bx / nb, by / nb, bz / nb)
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
def cofactors(mx, my, mz, nx, ny, nz):
    """``M0 = 2 I - m mᵀ - n nᵀ`` by cofactors: (usable, c00, c01, c02, c11, c12, c22,
    1 / (2 det M0)); not usable (and the scale 1/2) when n is NaN or det <= 1e-12 (a
    reference along gravity: gravity-only steps)."""
    a00 = 2.0 - mx * mx - nx * nx
    a01 = -mx * my - nx * ny
    a02 = -mx * mz - nx * nz
    a11 = 2.0 - my * my - ny * ny
    a12 = -my * mz - ny * nz
    a22 = 2.0 - mz * mz - nz * nz
    c00, c01, c02, c11, c12, c22, det = sym3_adjugate(a00, a01, a02, a11, a12, a22)  # det: 2 sin² γ
    usable = not (math.isnan(nx) or math.isnan(ny) or math.isnan(nz))
    if not det > 1e-12:
        usable = False
        det = 1.0
    return usable, c00, c01, c02, c11, c12, c22, 0.5 / det
