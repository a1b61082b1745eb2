"""Partial corrections of Ang's bias filter: the tilt alone, or the heading alone.

margtrack's input policy for :mod:`margtrack.methods.bias_kf.kernel`: a sample without a usable
field (the screening's zero sentinel) or with a field parallel to up has no TRIAD
quaternion (003 eqs. 10-13), nor has one without an accelerometer; it still corrects what
the other vector observes, by a Kalman update with ``H = [Hq 0]`` over the quaternion
directions ``q ⊗ (0, a)`` of the observed body axes ``a`` (``bias_kf_model._reduced_update``):

- tilt only: the measurement ``m = q⁻ ⊗ r``, ``r`` the shortest rotation taking the
  measured up to the predicted up ``ẑ``, observed along the two body axes normal to ``ẑ``
  with ``σ_G²`` per axis (eqs. 41-43; the tilt gate applies as in the full update);
- heading only: ``TRIAD(ẑ, m̂)``, the field levelled by the predicted up, observed about
  ``ẑ`` with ``σ_N² / |ẑ × m̂|²``.

The directions not observed get no update at all. The small matrices of the update live
in ``N_SCRATCH`` slots of the filter's row at ``row[s0:]``.
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit
from margtrack.estimator.quat_kernel import mul, normalized
from margtrack.estimator.triad_kernel import OK
from margtrack.methods.bias_kf.cov import tilt_d2
from margtrack.methods.bias_kf.model import (
    _fill_direction,
    _gate_weight,
    _levelled_heading,
    _mat,
    _normal_axes,
    _reduced_update,
    _tilt_rotation,
    fill_qtilde,
)

__all__ = ["N_SCRATCH", "heading_only", "tilt_only"]

# scratch offsets (relative to s0), matrices row-major
P_QT = 0  # (4, 3) Q̃(q⁻)
P_HQ = P_QT + 12  # (3, 4) observed directions
P_VR = P_HQ + 12  # (3, 3) their covariance
P_INNOV = P_VR + 9  # (3,)
P_DX = P_INNOV + 3  # (7,)
P_CHOL = P_DX + 7  # (3, 3) the reduced update's buffers
P_Y = P_CHOL + 9  # (3, 7)
P_GAIN = P_Y + 21  # (7, 3)
P_HP = P_GAIN + 21  # (3, 7)
P_ZMAT = P_HP + 21  # (7, 7)
P_ZH = P_ZMAT + 49  # (7, 3)
P_KV = P_ZH + 21  # (7, 3)
N_SCRATCH = P_KV + 21


@njit(cache=True)
def _update(row, p0, s0, m_rows, qw, qx, qy, qz, bx, by, bz):
    """The reduced update of the ``m_rows`` directions filled in the scratch; returns (ok,
    q, b) corrected (unchanged if the innovation covariance is not positive definite)."""
    dx = row[s0 + P_DX : s0 + P_DX + 7]
    ok = _reduced_update(
        _mat(row, p0, 7, 7), _mat(row, s0 + P_HQ, 3, 4), m_rows, _mat(row, s0 + P_VR, 3, 3),
        row[s0 + P_INNOV : s0 + P_INNOV + 3], _mat(row, s0 + P_CHOL, 3, 3),
        _mat(row, s0 + P_Y, 3, 7), _mat(row, s0 + P_GAIN, 7, 3), _mat(row, s0 + P_HP, 3, 7),
        _mat(row, s0 + P_ZMAT, 7, 7), _mat(row, s0 + P_ZH, 7, 3), _mat(row, s0 + P_KV, 7, 3),
        dx,
    )
    if ok:
        qw, qx, qy, qz = normalized(qw + dx[0], qx + dx[1], qy + dx[2], qz + dx[3])
        bx, by, bz = bx + dx[4], by + dx[5], bz + dx[6]
    return ok, qw, qx, qy, qz, bx, by, bz


# _nrt=True: its views of the row (``_mat``) need numba's reference counting, also
# when a kernel compiled without it (a method's ``series``) calls it
@njit(cache=True, _nrt=True)
def tilt_only(row, p0, s0, qw, qx, qy, qz, bx, by, bz, ux, uy, uz, ax, ay, az, var_g,
              gate, gate_exponent):  # fmt: skip
    """Correct the tilt alone: returns (ok, q, b) after the update (``P`` in place).

    ``q⁻`` unit body to earth, ``b`` rad/s, ``ẑ = (ux, uy, uz)`` the unit predicted up and
    ``â`` the unit accelerometer, body frame; ``var_g`` = σ_G² rad² before the tilt gate
    ``gate`` (inf: off) with its exponent. ``ok`` False: not positive definite, nothing
    changed.
    """
    ex, ey, ez, fx, fy, fz = _normal_axes(ux, uy, uz)
    rw, rx, ry, rz = _tilt_rotation(ax, ay, az, ux, uy, uz, ex, ey, ez)
    if gate < math.inf:
        mw, mx, my, mz = mul(qw, qx, qy, qz, rw, rx, ry, rz)
        d2 = tilt_d2(row, p0, qw, qx, qy, qz, mw, mx, my, mz, ux, uy, uz, var_g)
        if d2 > gate:
            var_g *= _gate_weight(d2 / gate, gate_exponent)
    qt = _mat(row, s0 + P_QT, 4, 3)
    hq = _mat(row, s0 + P_HQ, 3, 4)
    fill_qtilde(qw, qx, qy, qz, qt)
    _fill_direction(qt, ex, ey, ez, hq, 0)
    _fill_direction(qt, fx, fy, fz, hq, 1)
    row[s0 + P_INNOV] = ex * rx + ey * ry + ez * rz  # δq = ½ Q̃ θ: r's vector part
    row[s0 + P_INNOV + 1] = fx * rx + fy * ry + fz * rz
    v = s0 + P_VR
    row[v], row[v + 1], row[v + 3], row[v + 4] = 0.25 * var_g, 0.0, 0.0, 0.25 * var_g
    return _update(row, p0, s0, 2, qw, qx, qy, qz, bx, by, bz)


# _nrt=True: its views of the row (``_mat``) need numba's reference counting, also
# when a kernel compiled without it (a method's ``series``) calls it
@njit(cache=True, _nrt=True)
def heading_only(row, p0, s0, qw, qx, qy, qz, bx, by, bz, ux, uy, uz, nx, ny, nz, var_n,
                 ref, r0):  # fmt: skip
    """Correct the heading alone: returns (ok, q, b) after the update (``P`` in place).

    As :func:`tilt_only`, with ``n̂`` the unit field (body frame), ``var_n`` = σ_N² rad²
    and ``ref[r0:r0 + 9]`` the reference triad. A field parallel to ``ẑ`` corrects
    nothing (``ok`` True, nothing changed).
    """
    lev = _levelled_heading(qw, qx, qy, qz, nx, ny, nz, ux, uy, uz, ref, r0)
    if lev[0] != OK:
        return True, qw, qx, qy, qz, bx, by, bz
    _, ex, ey, ez = mul(qw, -qx, -qy, -qz, lev[1], lev[2], lev[3], lev[4])
    if lev[1] * qw + lev[2] * qx + lev[3] * qy + lev[4] * qz < 0.0:
        ex, ey, ez = -ex, -ey, -ez  # sign nearest q⁻
    qt = _mat(row, s0 + P_QT, 4, 3)
    fill_qtilde(qw, qx, qy, qz, qt)
    _fill_direction(qt, ux, uy, uz, _mat(row, s0 + P_HQ, 3, 4), 0)
    row[s0 + P_INNOV] = ux * ex + uy * ey + uz * ez
    row[s0 + P_VR] = 0.25 * var_n / lev[5]
    return _update(row, p0, s0, 1, qw, qx, qy, qz, bx, by, bz)
