"""The smoother's compiled passes: an error-state Kalman filter forward, Rauch-Tung-Striebel
backward, over one sensor's recording.

State: the nominal orientation ``q`` ([w, x, y, z], sensor to the earth frame) and gyro
bias ``b`` (rad/s, body axes); the filter's error state ``e = (dθ, db)``, ``dθ`` a small
rotation in the EARTH frame (``q_true = exp(dθ) ⊗ q``), so heading and inclination errors
are separate components: ``dθ · up`` the heading error, the two horizontal ones the
inclination. Covariance ``P`` (6 x 6).

- Predict over ``(t_{k-1}, t_k]``: ``q ← q ⊗ exp((ω_k - b) dt)``;
  ``F = [[I, -dt R(q)], [0, I]]`` (a bias error turns into an earth-frame rotation error
  through the orientation ``R``), ``Q = diag(q_θ dt I, q_b dt I)``.
- Accelerometer: the measured direction carried into the earth frame, ``v = R â``;
  ``v × up`` is the horizontal part of ``dθ`` (to first order), two scalar measurements
  of the horizontal components with variance ``r_acc``.
- Magnetometer: the horizontal part ``h`` of ``R m̂`` against north ``n``; the angle from
  ``h`` to ``n`` about ``up`` measures ``dθ · up`` with variance ``r_mag``.
- At rest: ``ω_k`` measures ``b`` (three scalars, variance ``r_rest``).
- Backward (Rauch, Tung and Striebel 1965, the multiplicative form): with the smoothed
  error at ``k + 1`` taken against that sample's predicted nominal state,
  ``e_s(k) = C_k e_s(k + 1)``, ``C_k = P_f(k) F_{k+1}ᵀ P_p(k + 1)⁻¹``,
  ``P_s(k) = P_f(k) + C_k (P_s(k + 1) - P_p(k + 1)) C_kᵀ``; the smoothed state is the
  filtered one corrected by ``e_s(k)``.

A sample whose ``restart`` is set starts the filter afresh from ``q_start`` (a gap or clock
reset: nothing links the orientation across it; the bias is kept and its variance grown),
and the backward pass does not smooth across it. Rows with ``use_acc`` / ``use_mag`` /
``at_rest`` false skip that update; a sample with ``use_gyr`` false holds the last rate.
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator.jit import njit
from margtrack.estimator.quat_kernel import mul
from margtrack.estimator.triad_kernel import rotate
from margtrack.methods.robust.gains import _bw_hold, _bw_step

#: coefficient slots
(C_Q_ANGLE, C_Q_BIAS, C_R_ACC, C_R_MAG, C_R_REST, C_P0_INCL, C_P0_HEAD, C_P0_BIAS, C_UP,
 C_GRAVITY, C_Q_REST, C_R_ACC_AT_REST, C_R_MAG_AT_REST) = range(13)
N_COEF = 13


@njit(cache=True)
def _rotation(q, r):
    """``r`` (3, 3) ← the rotation matrix of unit quaternion ``q`` (body to earth)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    r[0, 1] = 2.0 * (x * y - w * z)
    r[0, 2] = 2.0 * (x * z + w * y)
    r[1, 0] = 2.0 * (x * y + w * z)
    r[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    r[1, 2] = 2.0 * (y * z - w * x)
    r[2, 0] = 2.0 * (x * z - w * y)
    r[2, 1] = 2.0 * (y * z + w * x)
    r[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True)
def _left_exp(q, ex, ey, ez, out):
    """``out`` ← ``exp(e) ⊗ q`` normalised (``e`` a rotation vector, rad)."""
    angle = math.sqrt(ex * ex + ey * ey + ez * ez)
    if angle < 1e-12:
        s, c = 0.5, 1.0
    else:
        s, c = math.sin(0.5 * angle) / angle, math.cos(0.5 * angle)
    w, x, y, z = mul(c, s * ex, s * ey, s * ez, q[0], q[1], q[2], q[3])
    n = math.sqrt(w * w + x * x + y * y + z * z)
    out[0], out[1], out[2], out[3] = w / n, x / n, y / n, z / n


@njit(cache=True)
def _left_log(a, b, e):
    """``e`` ← the rotation vector of ``a ⊗ conj(b)`` (rad, the short way)."""
    w, x, y, z = mul(a[0], a[1], a[2], a[3], b[0], -b[1], -b[2], -b[3])
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    k = 2.0 if s < 1e-12 else 2.0 * math.atan2(s, w) / s
    e[0], e[1], e[2] = k * x, k * y, k * z


@njit(cache=True)
def _scalar_update(p, dx, i, sign, z, r):
    """One scalar measurement ``z = sign * e[i] + noise(r)`` into error mean ``dx`` and
    covariance ``p`` (Joseph-free form, symmetrised)."""
    inv_s = 1.0 / (p[i, i] + r)
    innov = (z - sign * dx[i]) * inv_s
    for a in range(6):
        dx[a] += sign * p[a, i] * innov
    # P ← P - P hᵀ h P / s, h = sign e_i: the column p[:, i] taken before it changes
    c0, c1, c2, c3, c4, c5 = p[0, i], p[1, i], p[2, i], p[3, i], p[4, i], p[5, i]
    col = (c0, c1, c2, c3, c4, c5)
    for a in range(6):
        ka = col[a] * inv_s
        for b in range(a, 6):
            v = p[a, b] - ka * col[b]
            p[a, b] = v
            p[b, a] = v


@njit(cache=True)
def _alone_update(p, dx, i, sign, z, r):
    """A scalar measurement ``z = sign * e[i] + noise(r)`` applied to error state ``i``
    alone (the others "considered": Schmidt's form, Joseph's covariance)."""
    s = p[i, i] + r
    k = p[i, i] / s
    dx[i] += sign * k * (z - sign * dx[i])
    keep = 1.0 - k
    for a in range(6):
        if a != i:
            p[i, a] *= keep
            p[a, i] = p[i, a]
    p[i, i] = keep * keep * p[i, i] + k * k * r


@njit(cache=True)
def _predict_cov(p_f, r, dt, q_angle, q_bias, p_p, scratch):
    """``p_p`` ← ``F p_f Fᵀ + Q`` with ``F = [[I, -dt R], [0, I]]``."""
    # G = -dt R: A' = A + G Cᵀ + C Gᵀ + G B Gᵀ, C' = C + G B, B' = B (+ Q)
    g = scratch[0]
    for a in range(3):
        for b in range(3):
            g[a, b] = -dt * r[a, b]
    gb = scratch[1]  # G B
    for a in range(3):
        for b in range(3):
            acc = 0.0
            for c in range(3):
                acc += g[a, c] * p_f[3 + c, 3 + b]
            gb[a, b] = acc
    for a in range(3):  # C' = C + G B   (C = upper-right block, rows θ, cols b)
        for b in range(3):
            p_p[a, 3 + b] = p_f[a, 3 + b] + gb[a, b]
            p_p[3 + b, a] = p_p[a, 3 + b]
            p_p[3 + a, 3 + b] = p_f[3 + a, 3 + b]
    for a in range(3):
        for b in range(a, 3):
            acc = p_f[a, b]
            for c in range(3):
                acc += g[a, c] * p_f[b, 3 + c] + p_f[a, 3 + c] * g[b, c] + gb[a, c] * g[b, c]
            p_p[a, b] = acc
            p_p[b, a] = acc
    for a in range(3):
        p_p[a, a] += q_angle * dt
        p_p[3 + a, 3 + a] += q_bias * dt


@njit(cache=True)
def _solve_spd(p, m, out, low, y):
    """``out`` (6, 6) ← ``m p⁻¹`` for symmetric positive definite ``p`` (Cholesky; ``low``
    (6, 6) and ``y`` (6,) are scratch; ``low``'s diagonal holds the reciprocals of the
    factor's, so the 6 + 72 divisions of the solves are multiplications)."""
    for j in range(6):
        d = p[j, j]
        for c in range(j):
            d -= low[j, c] * low[j, c]
        inv_d = 1.0 / math.sqrt(max(d, 1e-300))
        low[j, j] = inv_d
        for i in range(j + 1, 6):
            v = p[i, j]
            for c in range(j):
                v -= low[i, c] * low[j, c]
            low[i, j] = v * inv_d
    # rows of out solve out_row p = m_row  <=>  p out_rowᵀ = m_rowᵀ
    for row in range(6):
        for i in range(6):
            v = m[row, i]
            for c in range(i):
                v -= low[i, c] * y[c]
            y[i] = v * low[i, i]
        for i in range(5, -1, -1):
            v = y[i]
            for c in range(i + 1, 6):
                v -= low[c, i] * out[row, c]
            out[row, i] = v * low[i, i]


@njit(cache=True)
def _pack(p, out):
    """The upper triangle of the symmetric (6, 6) ``p``, row by row, into ``out`` (21,)."""
    i = 0
    for a in range(6):
        for c in range(a, 6):
            out[i] = p[a, c]
            i += 1


@njit(cache=True)
def _unpack(packed, p):
    """:func:`_pack`'s inverse: the symmetric (6, 6) ``p`` from its 21 values."""
    i = 0
    for a in range(6):
        for c in range(a, 6):
            p[a, c] = packed[i]
            p[c, a] = packed[i]
            i += 1


@njit(cache=True)
def measurements(flags, gyr, acc, mag, mag_offset, no_gyr, no_acc, no_mag, rest, use_gyr,
                 use_acc, use_mag, at_rest, mag_out):
    """One pass over a sensor's (N,) samples: which measurements the filter uses (a flag in
    ``no_*`` or a non-finite value: not that one), ``at_rest`` (a ``rest`` flag), and the
    field with the accepted hard-iron offset ``mag_offset`` (N, 3; nan: none) taken off,
    into ``mag_out``. ``mag`` None: no field."""
    for k in range(flags.shape[0]):
        f = flags[k]
        use_gyr[k] = (f & no_gyr) == 0 and math.isfinite(gyr[k, 0] + gyr[k, 1] + gyr[k, 2])
        use_acc[k] = (f & no_acc) == 0 and math.isfinite(acc[k, 0] + acc[k, 1] + acc[k, 2])
        at_rest[k] = (f & rest) != 0
        ok = mag is not None and (f & no_mag) == 0
        for a in range(3):
            if mag is None:
                mag_out[k, a] = 0.0
            else:
                o = mag_offset[k, a]
                mag_out[k, a] = mag[k, a] - o if math.isfinite(o) else mag[k, a]
                ok = ok and math.isfinite(mag_out[k, a])
        use_mag[k] = ok


@njit(cache=True)
def lowpassed_acc(q6, acc, use_acc, restart, b0, a1, a2, out):
    """``out`` (N, 3) ← the accelerometer (N, 3) low-passed with zero phase in the level
    frame of ``robust``'s 6-D orientation ``q6`` (N, 4) and carried back into the body.

    Gravity is fixed in that frame, so the low-pass (the second-order Butterworth
    ``(b0, a1, a2)``, forwards and then backwards) keeps it whole while it cuts the linear
    acceleration above its cut-off; ``q6``'s own slow errors are undone by carrying back
    with the same ``q6``. Each stretch between restarts (``restart``: ``q6`` jumps there)
    is filtered alone, each pass starting in the steady state of its first sample; a
    sample not used (``use_acc`` False) enters as the last used one (before the first used
    one: that one)."""
    n = acc.shape[0]
    start = 0
    while start < n:
        end = start + 1
        while end < n and not restart[end]:
            end += 1
        first = start
        while first < end - 1 and not use_acc[first]:
            first += 1
        x0 = x1 = x2 = 0.0
        if use_acc[first]:
            x0, x1, x2 = rotate(q6[first, 0], q6[first, 1], q6[first, 2], q6[first, 3],
                                acc[first, 0], acc[first, 1], acc[first, 2])
        s10, s20 = _bw_hold(b0, a1, a2, x0)
        s11, s21 = _bw_hold(b0, a1, a2, x1)
        s12, s22 = _bw_hold(b0, a1, a2, x2)
        for k in range(start, end):  # into the level frame, forwards (into ``out``)
            if use_acc[k]:
                x0, x1, x2 = rotate(q6[k, 0], q6[k, 1], q6[k, 2], q6[k, 3], acc[k, 0],
                                    acc[k, 1], acc[k, 2])
            out[k, 0], s10, s20 = _bw_step(b0, a1, a2, s10, s20, x0)
            out[k, 1], s11, s21 = _bw_step(b0, a1, a2, s11, s21, x1)
            out[k, 2], s12, s22 = _bw_step(b0, a1, a2, s12, s22, x2)
        last = end - 1
        s10, s20 = _bw_hold(b0, a1, a2, out[last, 0])
        s11, s21 = _bw_hold(b0, a1, a2, out[last, 1])
        s12, s22 = _bw_hold(b0, a1, a2, out[last, 2])
        for k in range(last, start - 1, -1):  # backwards, and back into the body
            y0, s10, s20 = _bw_step(b0, a1, a2, s10, s20, out[k, 0])
            y1, s11, s21 = _bw_step(b0, a1, a2, s11, s21, out[k, 1])
            y2, s12, s22 = _bw_step(b0, a1, a2, s12, s22, out[k, 2])
            out[k, 0], out[k, 1], out[k, 2] = rotate(q6[k, 0], -q6[k, 1], -q6[k, 2],
                                                     -q6[k, 3], y0, y1, y2)
        start = end


@njit(cache=True)
def forward(t, gyr, acc, mag, use_gyr, use_acc, use_mag, at_rest, restart, q_start, b0, coefs,
            q_f, b_f, q_p, p_f):
    """The filter over one sensor's (N,) samples; fills the filtered states ``q_f`` (N, 4),
    ``b_f`` (N, 3), ``p_f`` (N, 21: the covariance's upper triangle, :func:`_pack`) and
    the predicted orientation ``q_p`` (N, 4). The predicted bias is the last filtered one
    and the predicted covariance is not kept: :func:`backward` recomputes it from ``p_f``
    (the same call on the same numbers, so the same bits)."""
    n = t.size
    q_angle, q_bias, q_rest = coefs[C_Q_ANGLE], coefs[C_Q_BIAS], coefs[C_Q_REST]
    r_acc, r_mag, r_rest = coefs[C_R_ACC], coefs[C_R_MAG], coefs[C_R_REST]
    r_acc_at_rest, r_mag_at_rest = coefs[C_R_ACC_AT_REST], coefs[C_R_MAG_AT_REST]
    g = coefs[C_GRAVITY]  # m/s², the accelerometer's norm at rest
    up_sign = coefs[C_UP]  # +1: up is +z (ENU), -1: up is -z (NED)
    north_x, north_y = (0.0, 1.0) if up_sign > 0 else (1.0, 0.0)
    r = np.empty((3, 3))
    q = np.empty(4)
    b = b0.copy()
    p = np.zeros((6, 6))
    p_prev = np.empty((6, 6))
    dx = np.zeros(6)
    w = np.zeros(3)
    scratch = np.empty((2, 3, 3))
    for k in range(n):
        if k == 0 or restart[k]:
            q[:] = q_start[k]
            p_bias = p[3:, 3:].copy() if k > 0 else np.zeros((3, 3))
            p[:, :] = 0.0
            p[0, 0] = p[1, 1] = coefs[C_P0_INCL]
            p[2, 2] = coefs[C_P0_HEAD]
            for a in range(3):
                for c in range(3):
                    p[3 + a, 3 + c] = p_bias[a, c]
                p[3 + a, 3 + a] += coefs[C_P0_BIAS] if k == 0 else q_bias * (t[k] - t[k - 1])
        else:
            dt = t[k] - t[k - 1]
            if use_gyr[k]:
                w[0], w[1], w[2] = gyr[k, 0], gyr[k, 1], gyr[k, 2]
            _rotation(q, r)
            p_prev[:, :] = p
            _predict_cov(p_prev, r, dt, q_rest if at_rest[k] else q_angle, q_bias, p, scratch)
            # q ← q ⊗ exp((ω - b) dt)
            wx, wy, wz = (w[0] - b[0]) * dt, (w[1] - b[1]) * dt, (w[2] - b[2]) * dt
            angle = math.sqrt(wx * wx + wy * wy + wz * wz)
            if angle < 1e-12:
                s, c = 0.5, 1.0
            else:
                s, c = math.sin(0.5 * angle) / angle, math.cos(0.5 * angle)
            q[0], q[1], q[2], q[3] = mul(q[0], q[1], q[2], q[3], c, s * wx, s * wy, s * wz)
        q_p[k] = q
        _rotation(q, r)
        dx[:] = 0.0
        if use_acc[k]:
            # the acceleration itself, not its direction: a moving sensor's horizontal
            # acceleration in the earth frame averages to zero (its velocity stays bounded)
            # where the directions of single samples do not
            ax, ay, az = acc[k, 0] / g, acc[k, 1] / g, acc[k, 2] / g
            vx = r[0, 0] * ax + r[0, 1] * ay + r[0, 2] * az
            vy = r[1, 0] * ax + r[1, 1] * ay + r[1, 2] * az
            # v × up, up = (0, 0, up_sign): (vy up_sign, -vx up_sign, 0)
            ra = r_acc_at_rest if at_rest[k] else r_acc
            _scalar_update(p, dx, 0, 1.0, vy * up_sign, ra)
            _scalar_update(p, dx, 1, 1.0, -vx * up_sign, ra)
        if use_mag[k]:
            mx, my, mz = mag[k, 0], mag[k, 1], mag[k, 2]
            hx = r[0, 0] * mx + r[0, 1] * my + r[0, 2] * mz
            hy = r[1, 0] * mx + r[1, 1] * my + r[1, 2] * mz
            if hx * hx + hy * hy > 0.0:
                # angle from h to north about up: atan2((h × n) · up, h · n)
                cross_z = (hx * north_y - hy * north_x) * up_sign
                angle = math.atan2(cross_z, hx * north_x + hy * north_y)
                _alone_update(p, dx, 2, up_sign, angle,
                              r_mag_at_rest if at_rest[k] else r_mag)
        if at_rest[k] and use_gyr[k]:
            for a in range(3):
                _scalar_update(p, dx, 3 + a, 1.0, gyr[k, a] - b[a], r_rest)
        _left_exp(q, dx[0], dx[1], dx[2], q)
        for a in range(3):
            b[a] += dx[3 + a]
        q_f[k] = q
        b_f[k] = b
        _pack(p, p_f[k])


@njit(cache=True)
def backward(t, restart, at_rest, coefs, q_f, b_f, q_p, p_f, q_s, b_s, bias_var_s):
    """The Rauch-Tung-Striebel pass over :func:`forward`'s states: the smoothed
    orientation ``q_s`` (N, 4), bias ``b_s`` (N, 3) and its variance (N, 3)."""
    n = t.size
    q_angle, q_bias, q_rest = coefs[C_Q_ANGLE], coefs[C_Q_BIAS], coefs[C_Q_REST]
    p_pred = np.empty((6, 6))
    scratch = np.empty((2, 3, 3))
    r = np.empty((3, 3))
    m = np.empty((6, 6))
    gain = np.empty((6, 6))
    e_next = np.empty(6)
    e = np.empty(3)
    pf = np.empty((6, 6))  # P_f(k), unpacked
    p_s = np.empty((6, 6))
    _unpack(p_f[n - 1], p_s)
    diff = np.empty((6, 6))
    tmp = np.empty((6, 6))
    low = np.zeros((6, 6))
    y = np.empty(6)
    q_s[n - 1] = q_f[n - 1]
    b_s[n - 1] = b_f[n - 1]
    for a in range(3):
        bias_var_s[n - 1, a] = p_s[3 + a, 3 + a]
    for k in range(n - 2, -1, -1):
        if restart[k + 1]:
            q_s[k] = q_f[k]
            b_s[k] = b_f[k]
            _unpack(p_f[k], p_s)
            for a in range(3):
                bias_var_s[k, a] = p_s[3 + a, 3 + a]
            continue
        dt = t[k + 1] - t[k]
        _rotation(q_f[k], r)
        q_theta = q_rest if at_rest[k + 1] else q_angle
        _unpack(p_f[k], pf)
        _predict_cov(pf, r, dt, q_theta, q_bias, p_pred, scratch)
        # m = P_f(k) Fᵀ, F = [[I, -dt R], [0, I]]: Fᵀ = [[I, 0], [-dt Rᵀ, I]]
        for a in range(6):
            for c in range(3):
                v = pf[a, c]
                for j in range(3):
                    v -= dt * pf[a, 3 + j] * r[c, j]
                m[a, c] = v
                m[a, 3 + c] = pf[a, 3 + c]
        _solve_spd(p_pred, m, gain, low, y)
        # the smoothed error at k + 1 against its predicted nominal state
        _left_log(q_s[k + 1], q_p[k + 1], e)
        for a in range(3):
            e_next[a] = e[a]
            e_next[3 + a] = b_s[k + 1, a] - b_f[k, a]  # the bias predicted at k + 1
        ex = ey = ez = 0.0
        for c in range(6):
            ex += gain[0, c] * e_next[c]
            ey += gain[1, c] * e_next[c]
            ez += gain[2, c] * e_next[c]
        _left_exp(q_f[k], ex, ey, ez, q_s[k])
        for a in range(3):
            v = b_f[k, a]
            for c in range(6):
                v += gain[3 + a, c] * e_next[c]
            b_s[k, a] = v
        # P_s(k) = P_f(k) + C (P_s(k+1) - P_p(k+1)) Cᵀ
        for a in range(6):
            for c in range(6):
                diff[a, c] = p_s[a, c] - p_pred[a, c]
        for a in range(6):
            for c in range(6):
                v = 0.0
                for j in range(6):
                    v += gain[a, j] * diff[j, c]
                tmp[a, c] = v
        for a in range(6):
            for c in range(a, 6):
                v = pf[a, c]
                for j in range(6):
                    v += tmp[a, j] * gain[c, j]
                p_s[a, c] = v
                p_s[c, a] = v
        for a in range(3):
            bias_var_s[k, a] = p_s[3 + a, 3 + a]
