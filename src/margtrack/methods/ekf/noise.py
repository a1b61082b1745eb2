"""Evidence-driven noise of Marins' EKF measurements: linear acceleration and field disturbance.

001 gives the Gauss-Newton quaternion a fixed noise, ``R = r I₄ / h`` (approach 2). A
sample whose accelerometer is off gravity's norm, or whose field is off its reference
norm, carries a disturbance that the fit turns into an attitude error; this module
derives that error's covariance from the fit's Jacobian and adds it to 001's noise.

Disturbance of one unit vector (what the sample shows of it): a linear acceleration of
per-axis variance ``σ²`` changes ``|a|`` by about its component along gravity, so one
sample's estimate is ``σ² ≈ (|a| - g)²`` and the unit direction's components perpendicular
to it vary by ``d_a² = (|a| - g)² / g²`` each; the field likewise by
``d_m² = (|m| - m_ref)² / m_ref²`` (``m_ref`` the tracked reference norm). Such a
disturbance is not white: with a correlation time ``T`` its low-frequency density is
``2 T d²``, so a sample's share is ``s = 2 T d² / h`` (``T`` = ``acc_disturbance_s`` /
``mag_disturbance_s``; 0: none, 001 as printed).

Through the fit (:func:`rotation_covariance`): at the Gauss-Newton solution a body
rotation ``δθ`` moves the readings by ``[â]× δθ`` and ``[m̂]× δθ``, so the fit's
rotation responds to reading errors ``δy`` as ``δθ = A⁻¹ Jᵀ W δy`` with
``J = [[â]×; [m̂]×]``, ``W = diag(I₃, ρ² I₃)`` (001 eq. 20 with 000's weight ρ) and
``A = Jᵀ W J = (1 + ρ²) I - â âᵀ - ρ² m̂ m̂ᵀ``; with ``Cov δy = diag(s_a I₃, s_m I₃)``:
``C = Cov δθ = A⁻¹ (s_a (I - â âᵀ) + ρ⁴ s_m (I - m̂ m̂ᵀ)) A⁻¹`` (rad², body frame). A
tilt error is what the accelerometer's share produces, the field's share mostly turns the
heading.

In the quaternion (001's additive 4-D form): ``δq = ½ Ξ(q) δθ`` with ``Ξ(q) v = q ⊗ (0,
v)`` (orthonormal columns, ``Ξ Ξᵀ = I - q qᵀ``), so ``R = r I₄ / h + ¼ Ξ C Ξᵀ =
(r/h) q qᵀ + Ξ S Ξᵀ`` with ``S = (r/h) I₃ + C / 4``. The update (:func:`quaternion_update`)
decorrelates it: the component along ``q`` (variance r/h), then ``L⁻¹ Ξᵀ`` with
``S = L Lᵀ`` (unit variances), each a scalar update, equal to the batch update in exact
arithmetic. ``C = 0`` is 001's noise.

The gravity-only and vector readings (field unusable; approach 1) add ``s_a`` / ``s_m``
to each unit-vector component's variance.
"""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit
from margtrack.estimator.linalg_kernel import sym3_adjugate
from margtrack.methods.ekf.model import scalar_update

__all__ = ["disturbance_share", "quaternion_update", "rotation_covariance"]


@njit(cache=True, inline="always")
def disturbance_share(norm, ref_norm, correlation_s, ih):
    """``s = 2 T d² / h``, ``d = (norm - ref) / ref``: a sample's share of the disturbance of
    a unit vector's components (dimensionless²); 0 when T is 0 (ih = 1/h)."""
    if correlation_s <= 0.0 or not ref_norm > 0.0:
        return 0.0
    d = (norm - ref_norm) / ref_norm
    return 2.0 * correlation_s * d * d * ih


@njit(cache=True, inline="always")
def rotation_covariance(ax, ay, az, mx, my, mz, rho, s_a, s_m):
    """``C = A⁻¹ B A⁻¹`` (module docstring) for unit â, m̂: (ok, c00, c01, c02, c11, c12,
    c22), rad², body frame; ok False when A is singular (â along m̂)."""
    r2 = rho * rho
    d = 1.0 + r2
    # A = (1 + ρ²) I - â âᵀ - ρ² m̂ m̂ᵀ
    a00 = d - ax * ax - r2 * mx * mx
    a01 = -ax * ay - r2 * mx * my
    a02 = -ax * az - r2 * mx * mz
    a11 = d - ay * ay - r2 * my * my
    a12 = -ay * az - r2 * my * mz
    a22 = d - az * az - r2 * mz * mz
    # its inverse by the adjugate
    i00, i01, i02, i11, i12, i22, det = sym3_adjugate(a00, a01, a02, a11, a12, a22)
    if not (det > 1e-12 and det < math.inf):
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    inv = 1.0 / det
    i00, i01, i02, i11, i12, i22 = i00 * inv, i01 * inv, i02 * inv, i11 * inv, i12 * inv, i22 * inv
    # B = s_a (I - â âᵀ) + ρ⁴ s_m (I - m̂ m̂ᵀ)
    t = r2 * r2 * s_m
    b00 = s_a * (1.0 - ax * ax) + t * (1.0 - mx * mx)
    b01 = -s_a * ax * ay - t * mx * my
    b02 = -s_a * ax * az - t * mx * mz
    b11 = s_a * (1.0 - ay * ay) + t * (1.0 - my * my)
    b12 = -s_a * ay * az - t * my * mz
    b22 = s_a * (1.0 - az * az) + t * (1.0 - mz * mz)
    # M = A⁻¹ B, then C = M A⁻¹ (symmetric: the upper triangle)
    m00 = i00 * b00 + i01 * b01 + i02 * b02
    m01 = i00 * b01 + i01 * b11 + i02 * b12
    m02 = i00 * b02 + i01 * b12 + i02 * b22
    m10 = i01 * b00 + i11 * b01 + i12 * b02
    m11 = i01 * b01 + i11 * b11 + i12 * b12
    m12 = i01 * b02 + i11 * b12 + i12 * b22
    m20 = i02 * b00 + i12 * b01 + i22 * b02
    m21 = i02 * b01 + i12 * b11 + i22 * b12
    m22 = i02 * b02 + i12 * b12 + i22 * b22
    c00 = m00 * i00 + m01 * i01 + m02 * i02
    c01 = m00 * i01 + m01 * i11 + m02 * i12
    c02 = m00 * i02 + m01 * i12 + m02 * i22
    c11 = m10 * i01 + m11 * i11 + m12 * i12
    c12 = m10 * i02 + m11 * i12 + m12 * i22
    c22 = m20 * i02 + m21 * i12 + m22 * i22
    return True, c00, c01, c02, c11, c12, c22


@njit(cache=True, inline="always")
def quaternion_update(st, x, p, n, ph, w, qx, qy, qz, var, c00, c01, c02, c11, c12, c22):
    """The measured unit quaternion ``z = (w, qx, qy, qz)`` (H = I on the state's
    quaternion at ``st[x + 3:]``) with noise ``R = var I₄ + ¼ Ξ C Ξᵀ`` (module docstring),
    as four scalar updates; False at the first that failed (``scalar_update``)."""
    # along z: h = z, ν = zᵀ(z - x) = 1 - zᵀ x
    nu = 1.0 - (w * st[x + 3] + qx * st[x + 4] + qy * st[x + 5] + qz * st[x + 6])
    if not scalar_update(st, x, p, n, ph, -1, -1, w, qx, qy, qz, nu, var):
        return False
    # S = var I₃ + C/4 = L Lᵀ
    s00, s11, s22 = var + 0.25 * c00, var + 0.25 * c11, var + 0.25 * c22
    s01, s02, s12 = 0.25 * c01, 0.25 * c02, 0.25 * c12
    l00 = math.sqrt(s00)
    l10, l20 = s01 / l00, s02 / l00
    l11 = math.sqrt(s11 - l10 * l10)
    l21 = (s12 - l20 * l10) / l11
    l22 = math.sqrt(s22 - l20 * l20 - l21 * l21)
    # the columns of Ξ(z) (z ⊗ (0, e_j)), then the rows of L⁻¹ Ξᵀ by forward substitution
    e0 = (-qx, w, qz, -qy)
    e1 = (-qy, -qz, w, qx)
    e2 = (-qz, qy, -qx, w)
    r0 = (e0[0] / l00, e0[1] / l00, e0[2] / l00, e0[3] / l00)
    r1 = ((e1[0] - l10 * r0[0]) / l11, (e1[1] - l10 * r0[1]) / l11,
          (e1[2] - l10 * r0[2]) / l11, (e1[3] - l10 * r0[3]) / l11)
    r2 = ((e2[0] - l20 * r0[0] - l21 * r1[0]) / l22, (e2[1] - l20 * r0[1] - l21 * r1[1]) / l22,
          (e2[2] - l20 * r0[2] - l21 * r1[2]) / l22, (e2[3] - l20 * r0[3] - l21 * r1[3]) / l22)
    # Ξᵀ z = 0, so each innovation is -hᵀ x
    for hr in (r0, r1, r2):
        nu = -(hr[0] * st[x + 3] + hr[1] * st[x + 4] + hr[2] * st[x + 5] + hr[3] * st[x + 6])
        if not scalar_update(st, x, p, n, ph, -1, -1, hr[0], hr[1], hr[2], hr[3], nu, 1.0):
            return False
    return True
