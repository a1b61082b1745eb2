"""Kernel of Davenport's q-method, and the Wahba-problem pieces QUEST and Newton share.

Wahba's problem (002 eq. 9) with body vectors b_i, earth references r_i and weights a_i:
maximise the gain ``g(q) = Σ a_i r_i · R(q) b_i = qᵀ K q`` (002 eq. 10) over unit q.
For our q (body to earth, scalar first) and ``B = Σ a_i r_i b_iᵀ``::

    K = [[σ, zᵀ], [z, S - σ I]],  σ = tr B,  S = B + Bᵀ,  z = Σ a_i b_i × r_i

(Shuster's K with the scalar moved first; the identity also holds for non-unit q, which
Newton's Hessian uses). The optimal q is the eigenvector of K's largest eigenvalue; here
it comes from a cyclic Jacobi eigen-decomposition of the 4 x 4 symmetric K, exact to
rounding, the reference the other methods are tested against.
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator.jit import njit
from margtrack.estimator.lowpass import prefilter_sensor
from margtrack.estimator.triad_kernel import FASTMATH, OK, ZERO_ACC, level, unit_pair

#: Jacobi sweeps before giving up (each sweep squares the off-diagonal size; 4-6 suffice)
MAX_SWEEPS = 12


@njit(cache=True, inline="always")
def field_from_dip(sin_dip, cos_dip, ux, uy, uz, nx, ny, nz):
    """Unit earth field reference ``cos(dip)·north - sin(dip)·up`` (dip positive down)."""
    return cos_dip * nx - sin_dip * ux, cos_dip * ny - sin_dip * uy, cos_dip * nz - sin_dip * uz


@njit(cache=True, inline="always")
def measured_dip(ax, ay, az, mx, my, mz):
    """Dip (rad, positive down) of unit field m̂ seen with unit up â: ``asin(-â·m̂)``."""
    d = -(ax * mx + ay * my + az * mz)
    return math.asin(min(1.0, max(-1.0, d)))


@njit(cache=True, inline="always")
def profile(a1, r1x, r1y, r1z, b1x, b1y, b1z, a2, r2x, r2y, r2z, b2x, b2y, b2z):
    """Attitude profile of two weighted pairs: the 10 entries of K, upper triangle.

    Returns ``(k00, k01, k02, k03, k11, k12, k13, k22, k23, k33)`` (scalar first).
    """
    b11 = a1 * r1x * b1x + a2 * r2x * b2x
    b12 = a1 * r1x * b1y + a2 * r2x * b2y
    b13 = a1 * r1x * b1z + a2 * r2x * b2z
    b21 = a1 * r1y * b1x + a2 * r2y * b2x
    b22 = a1 * r1y * b1y + a2 * r2y * b2y
    b23 = a1 * r1y * b1z + a2 * r2y * b2z
    b31 = a1 * r1z * b1x + a2 * r2z * b2x
    b32 = a1 * r1z * b1y + a2 * r2z * b2y
    b33 = a1 * r1z * b1z + a2 * r2z * b2z
    sigma = b11 + b22 + b33
    # z = Σ a b × r, from the antisymmetric part of B = Σ a r bᵀ
    zx, zy, zz = b32 - b23, b13 - b31, b21 - b12
    return (
        sigma, zx, zy, zz,
        2.0 * b11 - sigma, b12 + b21, b13 + b31,
        2.0 * b22 - sigma, b23 + b32,
        2.0 * b33 - sigma,
    )


@njit(cache=True, fastmath=FASTMATH)
def largest_eigenvector(k, v):
    """Unit eigenvector (w >= 0) of the largest eigenvalue of symmetric ``k`` (4, 4).

    Cyclic Jacobi rotations (Golub & Van Loan 8.5) until the off-diagonal part vanishes to
    rounding; ``k`` is overwritten (its diagonal ends as the eigenvalues), ``v`` (4, 4) is
    workspace. Returns ``(w, x, y, z, λ_max)``.
    """
    for r in range(4):
        for c in range(4):
            v[r, c] = 1.0 if r == c else 0.0
    for _ in range(MAX_SWEEPS):
        off = 0.0
        total = 0.0
        for p in range(4):
            total += k[p, p] * k[p, p]
            for q in range(p + 1, 4):
                off += k[p, q] * k[p, q]
        if off <= 1e-36 * (total + off):
            break
        for p in range(3):
            for q in range(p + 1, 4):
                apq = k[p, q]
                if apq == 0.0:
                    continue
                theta = (k[q, q] - k[p, p]) / (2.0 * apq)
                if abs(theta) > 1e150:
                    t = 0.5 / theta
                else:
                    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                    if theta < 0.0:
                        t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for r in range(4):  # k ← k J
                    krp, krq = k[r, p], k[r, q]
                    k[r, p] = c * krp - s * krq
                    k[r, q] = s * krp + c * krq
                for r in range(4):  # k ← Jᵀ k
                    kpr, kqr = k[p, r], k[q, r]
                    k[p, r] = c * kpr - s * kqr
                    k[q, r] = s * kpr + c * kqr
                for r in range(4):  # v ← v J
                    vrp, vrq = v[r, p], v[r, q]
                    v[r, p] = c * vrp - s * vrq
                    v[r, q] = s * vrp + c * vrq
    best = 0
    for p in range(1, 4):
        if k[p, p] > k[best, best]:
            best = p
    w, x, y, z = v[0, best], v[1, best], v[2, best], v[3, best]
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return w / n, x / n, y / n, z / n, k[best, best]


@njit(cache=True, inline="always")
def fill_symmetric(k, e):
    """Write the 10 upper-triangle entries ``e`` (as from :func:`profile`) into k (4, 4)."""
    k00, k01, k02, k03, k11, k12, k13, k22, k23, k33 = e
    k[0, 0], k[0, 1], k[0, 2], k[0, 3] = k00, k01, k02, k03
    k[1, 0], k[1, 1], k[1, 2], k[1, 3] = k01, k11, k12, k13
    k[2, 0], k[2, 1], k[2, 2], k[2, 3] = k02, k12, k22, k23
    k[3, 0], k[3, 1], k[3, 2], k[3, 3] = k03, k13, k23, k33


@njit(cache=True)
def reference_field(acc, mag, dip_rad, dip_state, ux, uy, uz, nx, ny, nz):
    """Unit earth field reference for one sensor's series: ``(hx, hy, hz, sin dip, cos dip)``.

    ``dip_rad`` is the parameter (NaN: measure); dip_state (1,) the sensor's measured dip,
    set here from the first valid sample of acc, mag (N, 3) if still NaN. All NaN when no
    dip is known and no sample is valid (then no sample needs the reference).
    """
    dip = dip_rad
    if math.isnan(dip):
        dip = dip_state[0]
        if math.isnan(dip):
            for i in range(acc.shape[0]):
                flag, ax, ay, az, mx, my, mz = unit_pair(
                    acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2]
                )
                if flag == OK:
                    dip = measured_dip(ax, ay, az, mx, my, mz)
                    dip_state[0] = dip
                    break
    sin_dip, cos_dip = math.sin(dip), math.cos(dip)
    hx, hy, hz = field_from_dip(sin_dip, cos_dip, ux, uy, uz, nx, ny, nz)
    return hx, hy, hz, sin_dip, cos_dip


@njit(cache=True, fastmath=FASTMATH)
def _davenport_sensor(acc, mag, ux, uy, uz, hx, hy, hz, a1, a2, quat_state, k_work, v_work,
                      quat_out, flags):
    """Davenport over one sensor's (N, 3) series; quat_state (4,) in/out.

    A zero accelerometer holds the previous orientation; a zero or parallel field levels
    it onto the measured gravity (``triad.level``), heading kept.
    """
    pw, px, py, pz = quat_state[0], quat_state[1], quat_state[2], quat_state[3]
    for i in range(acc.shape[0]):
        flag, ax, ay, az, mx, my, mz = unit_pair(
            acc[i, 0], acc[i, 1], acc[i, 2], mag[i, 0], mag[i, 1], mag[i, 2]
        )
        flags[i] = flag
        if flag == OK:
            fill_symmetric(k_work, profile(a1, ux, uy, uz, ax, ay, az, a2, hx, hy, hz, mx, my, mz))
            pw, px, py, pz, _ = largest_eigenvector(k_work, v_work)
        elif flag != ZERO_ACC:
            pw, px, py, pz = level(pw, px, py, pz, ax, ay, az, ux, uy, uz)
        quat_out[i, 0], quat_out[i, 1], quat_out[i, 2], quat_out[i, 3] = pw, px, py, pz
    quat_state[0], quat_state[1], quat_state[2], quat_state[3] = pw, px, py, pz


@njit(cache=True)
def davenport_run(
    acc, mag, dt, up, north, dip_rad, acc_weight, mag_weight,
    acc_cutoff_hz, mag_cutoff_hz, order,
    quat_state, dip_state, lowpass_history, lowpass_ready, quat_out, flags,
):
    """Davenport's q-method for S sensors and N samples, with the optional prefilter.

    acc, mag (S, N, 3) any units; dt (N,) s; up, north (3,) unit earth vectors; dip_rad:
    reference dip (positive down), or NaN to measure it from each sensor's first valid
    sample (kept in dip_state (S,)); acc_weight, mag_weight: a_i of Wahba's loss;
    prefilter cut-offs (0 = off) and order; quat_state (S, 4), lowpass_history
    (S, 2, 4, 3), lowpass_ready (S, 2): state, in/out. Fills quat_out (S, N, 4) (w >= 0)
    and flags (S, N) int8 (see ``unit_pair``). A zero accelerometer repeats the previous
    orientation; a zero or parallel field levels it (inclination from the accelerometer,
    heading kept).
    """
    ux, uy, uz = up[0], up[1], up[2]
    nx, ny, nz = north[0], north[1], north[2]
    k_work, v_work = np.empty((4, 4)), np.empty((4, 4))
    filtering = acc_cutoff_hz > 0.0 or mag_cutoff_hz > 0.0
    n = acc.shape[1] if filtering else 0
    acc_f, mag_f = np.empty((n, 3)), np.empty((n, 3))
    for s in range(acc.shape[0]):
        if filtering:
            prefilter_sensor(acc[s], mag[s], dt, acc_cutoff_hz, mag_cutoff_hz, order,
                             lowpass_history[s], lowpass_ready[s], acc_f, mag_f)
            hx, hy, hz, _, _ = reference_field(acc_f, mag_f, dip_rad, dip_state[s:s + 1],
                                               ux, uy, uz, nx, ny, nz)
            _davenport_sensor(acc_f, mag_f, ux, uy, uz, hx, hy, hz, acc_weight, mag_weight,
                              quat_state[s], k_work, v_work, quat_out[s], flags[s])
        else:
            lowpass_ready[s, 0] = lowpass_ready[s, 1] = False
            hx, hy, hz, _, _ = reference_field(acc[s], mag[s], dip_rad, dip_state[s:s + 1],
                                               ux, uy, uz, nx, ny, nz)
            _davenport_sensor(acc[s], mag[s], ux, uy, uz, hx, hy, hz, acc_weight, mag_weight,
                              quat_state[s], k_work, v_work, quat_out[s], flags[s])
