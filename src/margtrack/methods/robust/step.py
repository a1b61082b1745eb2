# ruff: noqa: F405  (names from robust_layout's star import)
"""One sample of margtrack's robust filter (``methods/robust/kernel.py``) on a strided row.

The row's slot j is ``st[o + j * lanes]``: ``(row, 0, 1)`` for one sensor's row, a lane of
interleaved rows in ``estimator/lockstep.py``. The same code serves both, so a sensor
gets the same arithmetic in either (bit for bit).

``steady=True`` (a constant) is the lockstep pass: the caller has checked
(``robust._rare_at``) that this sample takes none of the rare branches (no interval, the
first accelerometer samples since a start, an all-zero accelerometer, gains not cached
for this interval, no field reference yet), so the step leaves them out of its code. Its
other branches compute both sides and store through ``jit.keep`` / ``jit.select`` (the
new value or the old), the heading's in :func:`_heading_steady`: a store in a branch is a
masked store in lockstep, slow on AMD's cores.
One sensor alone keeps the branches (``lanes == 1``). Its angles come from ``_fastmath``
(a library call inside a branch would stop the vectoriser). Everything is computed in
ENU.
"""

from __future__ import annotations

import math

from margtrack.estimator.fastmath import atan2, sincos
from margtrack.estimator.jit import keep, njit, select
from margtrack.estimator.quat_kernel import exp_half, mul, normalized
from margtrack.methods.robust import hard_iron
from margtrack.methods.robust.gains import (
    _bw_hold,
    _bw_step,
    gains_at,
    gains_steady_at,
    gains_values_at,
)
from margtrack.methods.robust.layout import *  # noqa: F403 (the layout)

H = math.sqrt(0.5)  # ENU <-> NED: q_ned = (0, h, h, 0) ⊗ q_enu, and back the same way


@njit(cache=True, inline="always")
def rotate(w, x, y, z, vx, vy, vz):
    """q ⊗ v ⊗ q* for unit q."""
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (
        vx + w * tx + y * tz - z * ty,
        vy + w * ty + z * tx - x * tz,
        vz + w * tz + x * ty - y * tx,
    )


@njit(cache=True, inline="always")
def _wrap(angle):
    """An angle in (-3 pi, 3 pi) wrapped to [-pi, pi] (the differences and sums of two
    wrapped angles here); the same as ``atan2(sin, cos)`` to rounding, at a fraction of
    its cost."""
    return select(angle > math.pi, angle - 2.0 * math.pi,
                  select(angle < -math.pi, angle + 2.0 * math.pi, angle))


@njit(cache=True, inline="always")
def to_output_frame(ned, w, x, y, z):
    """q (ENU) in the output frame: to NED when ``ned``. Both computed, one selected
    (``jit.select``): a branch here made each output's store a masked store in lockstep."""
    nw, nx, ny, nz = mul(0.0, H, H, 0.0, w, x, y, z)
    return select(ned, nw, w), select(ned, nx, x), select(ned, ny, y), select(ned, nz, z)


@njit(cache=True, inline="always")
def outputs_at(st, o, lanes, ned, q6w, q6x, q6y, q6z, xa, xo, outs):
    """Extra output k to ``xa[xo + k * outs]``: the 6-D quaternion (ENU in; to NED when
    ``ned``), the bias, its deviation and the accepted hard-iron offset (nan: none)."""
    q6w, q6x, q6y, q6z = to_output_frame(ned, q6w, q6x, q6y, q6z)
    xa[xo + X_QUAT6 * outs], xa[xo + (X_QUAT6 + 1) * outs] = q6w, q6x
    xa[xo + (X_QUAT6 + 2) * outs], xa[xo + (X_QUAT6 + 3) * outs] = q6y, q6z
    i_b, i_sd = o + R_BIAS * lanes, o + R_BIAS_SD * lanes
    xa[xo + X_BIAS * outs] = st[i_b]
    xa[xo + (X_BIAS + 1) * outs] = st[i_b + lanes]
    xa[xo + (X_BIAS + 2) * outs] = st[i_b + 2 * lanes]
    xa[xo + X_BIAS_SD * outs] = st[i_sd]
    xa[xo + (X_BIAS_SD + 1) * outs] = st[i_sd + lanes]
    xa[xo + (X_BIAS_SD + 2) * outs] = st[i_sd + 2 * lanes]
    h0, h1, h2 = hard_iron.offset_outputs_at(st, o, lanes)
    xa[xo + X_MAG_OFFSET * outs], xa[xo + (X_MAG_OFFSET + 1) * outs] = h0, h1
    xa[xo + (X_MAG_OFFSET + 2) * outs] = h2


@njit(cache=True, inline="always")
def _bias_update(st, o, lanes, k, p, gain, u, live):
    """Bias axis k after a Kalman update with this gain on the measurement residual u, if
    ``live`` (``jit.keep``: in lockstep computed whatever ``live``, the old value kept)."""
    i_b = o + (R_BIAS + k) * lanes
    keep(st, i_b, live, st[i_b] + gain * u, lanes)
    keep(st, o + (R_BIAS_VAR + k) * lanes, live, p, lanes)


@njit(cache=True, inline="always")
def _rest(st, o, lanes, coef, k_rest, step, g0, g1, g2, a0, a1, a2, acc_ok):
    """Rest detection (small deviation from slow means, small rate) and, at rest, the
    bias update from the gyro's slow mean; returns whether at rest."""
    bias_max = coef[C_BIAS_MAX]
    i_g, i_a = o + R_GYR_REST * lanes, o + R_ACC_REST * lanes
    gr0 = st[i_g] + k_rest * (g0 - st[i_g])
    gr1 = st[i_g + lanes] + k_rest * (g1 - st[i_g + lanes])
    gr2 = st[i_g + 2 * lanes] + k_rest * (g2 - st[i_g + 2 * lanes])
    st[i_g], st[i_g + lanes], st[i_g + 2 * lanes] = gr0, gr1, gr2
    dev_g = (g0 - gr0) ** 2 + (g1 - gr1) ** 2 + (g2 - gr2) ** 2
    # (& on the comparisons, not and, here and below: no branches in the lockstep pass)
    still = (
        (dev_g < coef[C_REST_GYR] ** 2)
        & (abs(gr0) < bias_max)
        & (abs(gr1) < bias_max)
        & (abs(gr2) < bias_max)
    )
    i_still = o + R_STILL * lanes
    if acc_ok:
        ar0 = st[i_a] + k_rest * (a0 - st[i_a])
        ar1 = st[i_a + lanes] + k_rest * (a1 - st[i_a + lanes])
        ar2 = st[i_a + 2 * lanes] + k_rest * (a2 - st[i_a + 2 * lanes])
        st[i_a], st[i_a + lanes], st[i_a + 2 * lanes] = ar0, ar1, ar2
        dev_a = (a0 - ar0) ** 2 + (a1 - ar1) ** 2 + (a2 - ar2) ** 2
        still = still & (dev_a < coef[C_REST_ACC] ** 2)
        st[i_still] = st[i_still] + step if still else 0.0
    elif not still:
        st[i_still] = 0.0  # without an accelerometer the gyro alone can end rest
    rest = still & (st[i_still] >= coef[C_REST_MIN_T])
    if lanes > 1 or rest:  # (lockstep: every lane computes, the rest keep their values)
        # at rest the gyro reads its bias: a Kalman update per axis (Ang's bias states, 003)
        # (written out: a loop inside a branch stops the vectoriser)
        r = coef[C_BIAS_REST_NOISE] ** 2
        i_b, i_v = o + R_BIAS * lanes, o + R_BIAS_VAR * lanes
        p0, p1, p2 = st[i_v], st[i_v + lanes], st[i_v + 2 * lanes]
        k0, k1, k2 = p0 / (p0 + r), p1 / (p1 + r), p2 / (p2 + r)
        _bias_update(st, o, lanes, 0, (1.0 - k0) * p0, k0, gr0 - st[i_b], rest)
        _bias_update(st, o, lanes, 1, (1.0 - k1) * p1, k1, gr1 - st[i_b + lanes], rest)
        _bias_update(st, o, lanes, 2, (1.0 - k2) * p2, k2, gr2 - st[i_b + 2 * lanes], rest)
    return rest


@njit(cache=True, inline="always")
def _motion_bias(st, o, lanes, k, r, u, v, live):
    """Bias axis k from the horizontal correction rate u, weighted by how much of the
    axis lies in the horizontal plane (1 - v²), if ``live``."""
    horizontal = 1.0 - v * v
    live = live & (horizontal > 1e-3)
    if lanes > 1 or live:
        p = st[o + (R_BIAS_VAR + k) * lanes]
        gain = p * horizontal / (p * horizontal + r)
        _bias_update(st, o, lanes, k, (1.0 - gain * horizontal) * p, -gain, u, live)


@njit(cache=True, inline="always")
def _incline(st, o, lanes, coef, b0, a1, a2, step, x0, x1, x2, rest, steady):
    """The low-passed accelerometer in I must point up: q_acc corrected by the shortest
    arc (004); in motion the applied correction rate is a bias measurement. (b0, a1, a2):
    the Butterworth coefficients of the interval."""
    i_g, i_c = o + R_Q_GYR * lanes, o + R_Q_ACC * lanes
    gw, gx, gy, gz = st[i_g], st[i_g + lanes], st[i_g + 2 * lanes], st[i_g + 3 * lanes]
    cw, cx, cy, cz = st[i_c], st[i_c + lanes], st[i_c + 2 * lanes], st[i_c + 3 * lanes]
    bw, lp = o + R_ACC_LP_BW * lanes, o + R_ACC_LP * lanes
    i_stage = o + R_LP_STAGE * lanes
    if not steady and st[i_stage] == LP_FIRST:
        # start the low-pass steady at the first sample
        for k in range(3):
            st[bw + 2 * k * lanes], st[bw + (2 * k + 1) * lanes] = _bw_hold(
                b0, a1, a2, st[lp + k * lanes]
            )
        st[i_stage] = LP_FILTER
    ex, ey, ez = rotate(gw, gx, gy, gz, x0, x1, x2)
    l0, st[bw], st[bw + lanes] = _bw_step(b0, a1, a2, st[bw], st[bw + lanes], ex)
    l1, st[bw + 2 * lanes], st[bw + 3 * lanes] = _bw_step(
        b0, a1, a2, st[bw + 2 * lanes], st[bw + 3 * lanes], ey
    )
    l2, st[bw + 4 * lanes], st[bw + 5 * lanes] = _bw_step(
        b0, a1, a2, st[bw + 4 * lanes], st[bw + 5 * lanes], ez
    )
    st[lp], st[lp + lanes], st[lp + 2 * lanes] = l0, l1, l2
    lx, ly, lz = rotate(cw, cx, cy, cz, l0, l1, l2)
    norm = math.sqrt(lx * lx + ly * ly + lz * lz)
    level = norm > 0.0  # (lockstep: every lane computes, stores through jit.keep)
    if lanes > 1 or level:
        lx, ly, lz = lx / norm, ly / norm, lz / norm
        # shortest arc taking (lx, ly, lz) to up = [0, 0, 1] (004)
        if lz > -0.999999:
            # (abs: positive here; it lets LLVM take the sqrt instruction for libm's call,
            # which sets errno on a negative argument and so cannot be vectorised)
            sq = math.sqrt(abs(2.0 * (1.0 + lz)))
            rw, rx, ry = 0.5 * sq, ly / sq, -lx / sq
        else:
            rw, rx, ry = 0.0, 1.0, 0.0
        cw, cx, cy, cz = mul(rw, rx, ry, 0.0, cw, cx, cy, cz)
        cw, cx, cy, cz = normalized(cw, cx, cy, cz)
        keep(st, i_c, level, cw, lanes)
        keep(st, i_c + lanes, level, cx, lanes)
        keep(st, i_c + 2 * lanes, level, cy, lanes)
        keep(st, i_c + 3 * lanes, level, cz, lanes)
        moving = level & (not rest)
        if lanes > 1 or moving:
            # the applied correction rate (level frame), seen in the body, is minus the
            # horizontal bias error: a bias measurement in motion
            q6w, q6x, q6y, q6z = mul(cw, cx, cy, cz, gw, gx, gy, gz)
            ux, uy, uz = rotate(q6w, -q6x, -q6y, -q6z, 2.0 * rx / step, 2.0 * ry / step, 0.0)
            # only the horizontal components are observed
            vx, vy, vz = rotate(q6w, -q6x, -q6y, -q6z, 0.0, 0.0, 1.0)
            r = coef[C_BIAS_MOTION_NOISE] ** 2
            _motion_bias(st, o, lanes, 0, r, ux, vx, moving)
            _motion_bias(st, o, lanes, 1, r, uy, vy, moving)
            _motion_bias(st, o, lanes, 2, r, uz, vz, moving)


@njit(cache=True, inline="always")
def _heading(st, o, lanes, coef, k_ref, k_mag, step, mx, my, mz, moving):
    """Heading from the horizontal field (004's vector rejection), unless the field's norm
    or dip disagrees with the tracked reference or the norm moves with the orientation
    (``moving``: ``hard_iron``); returns whether it did (disturbed).
    (mx, my, mz): the field in the level frame; ``k_ref``, ``k_mag``: the interval's gains
    (read only when step > 0). The lockstep pass has :func:`_heading_steady`."""
    m_norm = math.sqrt(mx * mx + my * my + mz * mz)
    horizontal = math.sqrt(mx * mx + my * my)
    # an all-zero sample (no measurement) has m_norm == 0: skipped
    usable = (m_norm > 0.0) & (horizontal > 1e-6 * m_norm)
    disturbed = False
    i_nref, i_dref = o + R_MAG_NORM_REF * lanes, o + R_MAG_DIP_REF * lanes
    i_cn, i_cd, i_cs = o + R_CAND_NORM * lanes, o + R_CAND_DIP * lanes, o + R_CAND_S * lanes
    i_n, i_since = o + R_HEADING_N * lanes, o + R_SINCE_START * lanes
    if usable:
        dip = atan2(-mz, horizontal)
        if st[i_nref] <= 0.0:
            st[i_nref] = m_norm
            st[i_cn] = m_norm
        if math.isnan(st[i_dref]):
            st[i_dref] = dip
            st[i_cd] = dip
        ref_n, ref_d = st[i_nref], st[i_dref]
        disturbed = (
            (abs(m_norm - ref_n) > coef[C_MAG_NORM_TOL] * ref_n)
            | (abs(dip - ref_d) > coef[C_MAG_DIP_TOL])
            | moving
        )
        if step > 0.0:
            if not disturbed:
                st[i_nref] = ref_n + k_ref * (m_norm - ref_n)
                st[i_dref] = ref_d + k_ref * (dip - ref_d)
                st[i_cn] = m_norm
                st[i_cd] = dip
                st[i_cs] = 0.0
                # a fixed time constant: an adaptive (Kalman) gain that grows after fast
                # turns or rejected disturbances was measured worse on BROAD, re-acquiring
                # still-distorted fields too quickly. Start-up: the mean of the
                # measurements while 1/n is larger
                k = k_mag
                if st[i_since] < coef[C_CONVERGE]:
                    st[i_n] += 1.0
                    k = max(k, 1.0 / st[i_n])
                # angle of the horizontal field from north (+y) towards east (+x)
                field_heading = atan2(mx, my)
                i_head = o + R_HEADING * lanes
                head = st[i_head]
                st[i_head] = _wrap(head + k * _wrap(field_heading - head))
            else:
                # a new, steady field: track a candidate and adopt it once it has stayed
                # consistent for long enough (a new environment)
                cand_n, cand_d = st[i_cn], st[i_cd]
                consistent = (abs(m_norm - cand_n) < coef[C_MAG_NORM_TOL] * cand_n) & (
                    abs(dip - cand_d) < coef[C_MAG_DIP_TOL]
                )
                if consistent:
                    st[i_cs] += step
                    st[i_cn] = cand_n + k_ref * (m_norm - cand_n)
                    st[i_cd] = cand_d + k_ref * (dip - cand_d)
                else:
                    st[i_cs] = 0.0
                    st[i_cn] = m_norm
                    st[i_cd] = dip
                if st[i_cs] > coef[C_MAG_NEW_REF_T]:
                    st[i_nref] = st[i_cn]
                    st[i_dref] = st[i_cd]
                    st[i_cs] = 0.0
    if st[i_since] == 0.0 and st[i_n] == 1.0 and (disturbed or not usable):
        # a start without an undisturbed field: its heading is no measurement, the first
        # one replaces it (the lockstep pass has had an interval since its start)
        st[i_n] = 0.0
    return disturbed


@njit(cache=True, inline="always")
def _heading_steady(st, o, lanes, coef, k_ref, k_mag, step, mx, my, mz, has_mag, moving):
    """:func:`_heading` in the lockstep pass (both references known, step > 0; the field
    used only with ``has_mag``): the same values, each slot stored whatever the branches
    (``jit.select``: the new value or the old), as a store in a branch is a masked store."""
    m_norm = math.sqrt(mx * mx + my * my + mz * mz)
    horizontal = math.sqrt(mx * mx + my * my)
    usable = has_mag & (m_norm > 0.0) & (horizontal > 1e-6 * m_norm)
    i_nref, i_dref = o + R_MAG_NORM_REF * lanes, o + R_MAG_DIP_REF * lanes
    i_cn, i_cd, i_cs = o + R_CAND_NORM * lanes, o + R_CAND_DIP * lanes, o + R_CAND_S * lanes
    i_n, i_head = o + R_HEADING_N * lanes, o + R_HEADING * lanes
    dip = atan2(-mz, horizontal)
    ref_n, ref_d = st[i_nref], st[i_dref]
    disturbed = usable & (
        (abs(m_norm - ref_n) > coef[C_MAG_NORM_TOL] * ref_n)
        | (abs(dip - ref_d) > coef[C_MAG_DIP_TOL])
        | moving
    )
    accepted = usable & (not disturbed)
    # accepted: the heading moves (start-up: the mean of the measurements, _heading)
    converging = accepted & (st[o + R_SINCE_START * lanes] < coef[C_CONVERGE])
    n_heading = st[i_n] + 1.0
    st[i_n] = select(converging, n_heading, st[i_n])
    k = select(converging, max(k_mag, 1.0 / n_heading), k_mag)
    head = st[i_head]
    st[i_head] = select(accepted, _wrap(head + k * _wrap(atan2(mx, my) - head)), head)
    # disturbed: the candidate reference, adopted once steady long enough
    cand_n, cand_d, cand_s = st[i_cn], st[i_cd], st[i_cs]
    consistent = (abs(m_norm - cand_n) < coef[C_MAG_NORM_TOL] * cand_n) & (
        abs(dip - cand_d) < coef[C_MAG_DIP_TOL]
    )
    new_s = select(consistent, cand_s + step, 0.0)
    new_n = select(consistent, cand_n + k_ref * (m_norm - cand_n), m_norm)
    new_d = select(consistent, cand_d + k_ref * (dip - cand_d), dip)
    adopted = disturbed & (new_s > coef[C_MAG_NEW_REF_T])
    st[i_nref] = select(accepted, ref_n + k_ref * (m_norm - ref_n), select(adopted, new_n, ref_n))
    st[i_dref] = select(accepted, ref_d + k_ref * (dip - ref_d), select(adopted, new_d, ref_d))
    st[i_cn] = select(accepted, m_norm, select(disturbed, new_n, cand_n))
    st[i_cd] = select(accepted, dip, select(disturbed, new_d, cand_d))
    st[i_cs] = select(accepted | adopted, 0.0, select(disturbed, new_s, cand_s))
    return disturbed


@njit(cache=True, inline="always")
def step_at(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, qa, qo, xa, xo,
            outs, steady):
    """One screened sample (an all-zero acc or mag: no measurement; dt 0: nothing to
    integrate): output k of the 9-D (6-D without a field) orientation to ``qa[qo + k *
    outs]``, of the extra outputs to ``xa[xo + k * outs]``; returns the REST and
    MAG_DISTURBED bits."""
    # (the lockstep pass has an accelerometer sample: robust._rare_at)
    acc_ok = steady or (a0 != 0.0) | (a1 != 0.0) | (a2 != 0.0)
    i_g = o + R_Q_GYR * lanes
    i_lp, i_stage = o + R_ACC_LP * lanes, o + R_LP_STAGE * lanes
    if not steady and acc_ok and st[i_stage] == LP_EMPTY:
        # the first usable sample since the start: it starts both low-passes (q_gyr is
        # the identity at a start, so I is the body frame then)
        st[i_lp], st[i_lp + lanes], st[i_lp + 2 * lanes] = rotate(
            st[i_g], st[i_g + lanes], st[i_g + 2 * lanes], st[i_g + 3 * lanes], a0, a1, a2
        )
        i_a = o + R_ACC_REST * lanes
        st[i_a], st[i_a + lanes], st[i_a + 2 * lanes] = a0, a1, a2
        st[i_stage] = LP_FIRST
        acc_ok = False  # used: not filtered a second time below
    rest = False
    k_ref = k_mag = 0.0  # (read only when dt > 0)
    if steady or dt > 0.0:
        if steady:
            k_rest, k_ref, k_mag, b0, a1_bw, a2_bw = gains_steady_at(st, o, lanes, coef, dt)
        else:
            k_rest, k_ref, k_mag, b0, a1_bw, a2_bw = gains_values_at(
                st, o, lanes, gains_at(st, o, lanes, coef, dt)
            )
        st[o + R_SINCE_START * lanes] += dt
        # -- strapdown: q_gyr ⊗ exp((ω - b) dt / 2); the bias walks between measurements
        i_b, i_v = o + R_BIAS * lanes, o + R_BIAS_VAR * lanes
        dw, dx, dy, dz = exp_half(g0 - st[i_b], g1 - st[i_b + lanes], g2 - st[i_b + 2 * lanes],
                                  dt)
        gw, gx, gy, gz = mul(st[i_g], st[i_g + lanes], st[i_g + 2 * lanes], st[i_g + 3 * lanes],
                             dw, dx, dy, dz)
        gw, gx, gy, gz = normalized(gw, gx, gy, gz)
        st[i_g], st[i_g + lanes], st[i_g + 2 * lanes], st[i_g + 3 * lanes] = gw, gx, gy, gz
        walk = coef[C_BIAS_WALK] ** 2 * dt
        st[i_v] += walk
        st[i_v + lanes] += walk
        st[i_v + 2 * lanes] += walk
        rest = _rest(st, o, lanes, coef, k_rest, dt, g0, g1, g2, a0, a1, a2, acc_ok)
        if acc_ok:  # (an all-zero sample is no measurement: nothing reaches the low-pass)
            _incline(st, o, lanes, coef, b0, a1_bw, a2_bw, dt, a0, a1, a2, rest, steady)
        bias_max = coef[C_BIAS_MAX]
        i_sd = o + R_BIAS_SD * lanes
        for k in range(3):
            st[i_b + k * lanes] = min(max(st[i_b + k * lanes], -bias_max), bias_max)
            st[i_sd + k * lanes] = math.sqrt(abs(st[i_v + k * lanes]))  # (abs: as above)
    i_c = o + R_Q_ACC * lanes
    q6w, q6x, q6y, q6z = mul(st[i_c], st[i_c + lanes], st[i_c + 2 * lanes], st[i_c + 3 * lanes],
                             st[i_g], st[i_g + lanes], st[i_g + 2 * lanes], st[i_g + 3 * lanes])
    m0, m1, m2, moving = hard_iron.sample_at(st, o, lanes, coef, dt, m0, m1, m2, has_mag,
                                             steady)
    disturbed = False
    if steady:  # (without a field too: a branch on has_mag would mask the stores)
        mx, my, mz = rotate(q6w, q6x, q6y, q6z, m0, m1, m2)
        disturbed = _heading_steady(st, o, lanes, coef, k_ref, k_mag, dt, mx, my, mz, has_mag,
                                    moving)
        sin_half, cos_half = sincos(0.5 * st[o + R_HEADING * lanes])
        ow, ox, oy, oz = mul(cos_half, 0.0, 0.0, sin_half, q6w, q6x, q6y, q6z)
        ow, ox = select(has_mag, ow, q6w), select(has_mag, ox, q6x)
        oy, oz = select(has_mag, oy, q6y), select(has_mag, oz, q6z)
    elif has_mag:
        mx, my, mz = rotate(q6w, q6x, q6y, q6z, m0, m1, m2)  # the field in the level frame
        disturbed = _heading(st, o, lanes, coef, k_ref, k_mag, dt, mx, my, mz, moving)
        sin_half, cos_half = sincos(0.5 * st[o + R_HEADING * lanes])
        ow, ox, oy, oz = mul(cos_half, 0.0, 0.0, sin_half, q6w, q6x, q6y, q6z)
    else:
        ow, ox, oy, oz = q6w, q6x, q6y, q6z
    ned = coef[C_NED] > 0.5
    ow, ox, oy, oz = to_output_frame(ned, ow, ox, oy, oz)
    qa[qo], qa[qo + outs], qa[qo + 2 * outs], qa[qo + 3 * outs] = ow, ox, oy, oz
    outputs_at(st, o, lanes, ned, q6w, q6x, q6y, q6z, xa, xo, outs)
    return (REST if rest else 0) | (MAG_DISTURBED if disturbed else 0)
