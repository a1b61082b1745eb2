"""Kernel of margtrack's robust filter (``filters/robust.py``): one loop over sensors and samples.

Internally everything is computed in ENU; the output is rotated to NED at the end when
asked. Orientation is factored as ``q9 = q_z(heading) ⊗ q_acc ⊗ q_gyr`` (the factoring of
FQA, 002, where heading is kept apart from inclination):

- ``q_gyr``: strapdown integration of the bias-corrected gyro, body to a quasi-inertial
  frame I that drifts only as slowly as the bias error;
- ``q_acc``: I to a level frame, corrected so that the accelerometer, low-pass filtered in
  I (where linear acceleration of a moving person averages out but gravity does not),
  points up;
- ``heading``: rotation about the vertical from the level frame to the earth frame, from
  the horizontal magnetometer direction only (004's vector rejection), skipped while the
  field's norm or dip disagrees with its tracked reference.

Start-up (after the first sample and after every restart): the heading gain is ``1/n``
for its n-th measurement since the start (the initial orientation counting as the first)
while that exceeds the nominal gain and for at most ``converge_s``, as VQF does at
start-up: the heading is the mean of the measurements so far, so a start sample taken
during motion stops dominating it after a second or two instead of after several
``tau_mag`` (20 s). The accelerometer low-pass starts at its first sample, steady (a mean
of the first seconds was tried: it lets a periodic motion's linear acceleration through,
49 deg of tilt on a 1 Hz limb swing, against 2 deg from the start sample).

The state is passed as named arrays (see :class:`margtrack.filters.robust.RobustState`);
the kernel loads each sensor's state into locals, runs its samples and stores it back.
"""

from __future__ import annotations

import math

from numba import njit

from margtrack.kernels._quat import exp_half, mul, normalized

# -- stages of the accelerometer low-pass (``acc_lp_stage``) --------------------------------
LP_EMPTY = 0  # no usable accelerometer sample since the start
LP_FIRST = 1  # holds the first sample (rotated into I); filter states set at the next step
LP_FILTER = 2  # the second-order Butterworth low-pass, running

# -- parameter layout (``coef`` (N_COEF,)) ------------------------------------------------
C_TAU_ACC = 0  # s
C_TAU_MAG = 1  # s
C_BIAS_WALK = 2  # rad/s/√s
C_BIAS_REST_NOISE = 3  # rad/s
C_BIAS_MOTION_NOISE = 4  # rad/s
C_BIAS_MAX = 5  # rad/s
C_REST_GYR = 6  # rad/s
C_REST_ACC = 7  # m/s²
C_REST_MIN_T = 8  # s
C_REST_TAU = 9  # s
C_MAG_NORM_TOL = 10  # relative
C_MAG_DIP_TOL = 11  # rad
C_MAG_NEW_REF_T = 12  # s
C_MAG_REF_TAU = 13  # s
C_NED = 14  # 1: output in NED
C_CONVERGE = 15  # s, longest start-up phase of the heading (0: none)
N_COEF = 16


@njit(cache=True, inline="always")
def _rotate(w, x, y, z, vx, vy, vz):
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
    return math.atan2(math.sin(angle), math.cos(angle))


@njit(cache=True, inline="always")
def _lowpass_gain(dt, tau):
    """First-order low-pass gain for a time constant tau (s); 1 when tau <= 0."""
    if tau <= 0.0:
        return 1.0
    return 1.0 - math.exp(-dt / tau)


@njit(cache=True)
def butterworth_coefficients(step, tau):
    """(b0, a1, a2) of the second-order Butterworth low-pass for time constant tau at step.

    Cut-off ``f_c = sqrt(2) / (2 pi tau)`` (so its step response is close to a first-order
    filter's with the same tau), discretised by the bilinear transform with pre-warping;
    ``b1 = 2 b0`` and ``b2 = b0``.
    """
    fc = math.sqrt(2.0) / (2.0 * math.pi * tau)
    c = math.tan(math.pi * fc * step)
    d = c * c + math.sqrt(2.0) * c + 1.0
    return c * c / d, 2.0 * (c * c - 1.0) / d, (1.0 - math.sqrt(2.0) * c + c * c) / d


@njit(cache=True, inline="always")
def _bw_step(b0, a1, a2, s1, s2, x):
    """One sample through the low-pass (transposed direct form II): (y, s1, s2)."""
    y = b0 * x + s1
    return y, 2.0 * b0 * x - a1 * y + s2, b0 * x - a2 * y


@njit(cache=True, inline="always")
def _bw_hold(b0, a1, a2, x):
    """States (s1, s2) of the low-pass in the steady state of a constant input x."""
    s2 = (b0 - a2) * x
    return (2.0 * b0 - a1) * x + s2, s2


@njit(cache=True)
def robust_filter(
    coef,
    gyr,
    acc,
    mag,
    has_mag,
    dt,
    q_gyr,
    q_acc,
    heading,
    bias,
    bias_var,
    acc_lp,
    acc_lp_bw,
    acc_lp_stage,
    heading_n,
    since_start,
    gyr_rest,
    acc_rest,
    still_t,
    mag_norm_ref,
    mag_dip_ref,
    mag_cand_norm,
    mag_cand_dip,
    mag_cand_t,
    quat_out,
    quat6_out,
    bias_out,
    bias_sd_out,
    rest_out,
    mag_dist_out,
):
    """Run S filters over N samples.

    coef (N_COEF,); gyr, acc, mag (S, N, 3) rad/s, m/s², any field unit (mag ignored when
    ``has_mag`` is False; an all-zero acc or mag sample is no measurement); dt (N,) s
    (0: nothing to integrate). State, in/out, per sensor (meaning and units in
    ``RobustState``): q_gyr, q_acc (S, 4), heading (S,), bias, bias_var (S, 3), acc_lp
    (S, 3), acc_lp_bw (S, 3, 2), acc_lp_stage (S,) int8, heading_n (S,) int64,
    since_start (S,), gyr_rest, acc_rest (S, 3), still_t (S,), and the field tracker (S,):
    mag_norm_ref, mag_dip_ref rad (0 / nan: taken from the next sample), mag_cand_norm,
    mag_cand_dip rad, mag_cand_t s. Outputs (S, N, ...): 9-D (6-D without mag) quaternion in
    the requested frame, 6-D quaternion, bias rad/s, its standard deviation rad/s, rest
    flag, mag disturbed flag.
    """
    n_sensors, n = gyr.shape[0], gyr.shape[1]
    ned = coef[C_NED] > 0.5
    h = math.sqrt(0.5)
    tau_acc, tau_mag = coef[C_TAU_ACC], coef[C_TAU_MAG]
    converge = coef[C_CONVERGE]
    bias_max = coef[C_BIAS_MAX]
    for s in range(n_sensors):
        # -- load the state into locals ------------------------------------------------
        gw, gx, gy, gz = q_gyr[s, 0], q_gyr[s, 1], q_gyr[s, 2], q_gyr[s, 3]
        cw, cx, cy, cz = q_acc[s, 0], q_acc[s, 1], q_acc[s, 2], q_acc[s, 3]
        head = heading[s]
        b0_, b1_, b2_ = bias[s, 0], bias[s, 1], bias[s, 2]
        p0, p1, p2 = bias_var[s, 0], bias_var[s, 1], bias_var[s, 2]
        l0, l1, l2 = acc_lp[s, 0], acc_lp[s, 1], acc_lp[s, 2]
        s10, s20 = acc_lp_bw[s, 0, 0], acc_lp_bw[s, 0, 1]
        s11, s21 = acc_lp_bw[s, 1, 0], acc_lp_bw[s, 1, 1]
        s12, s22 = acc_lp_bw[s, 2, 0], acc_lp_bw[s, 2, 1]
        stage = acc_lp_stage[s]
        hd_n = heading_n[s]
        t_start = since_start[s]
        gr0, gr1, gr2 = gyr_rest[s, 0], gyr_rest[s, 1], gyr_rest[s, 2]
        ar0, ar1, ar2 = acc_rest[s, 0], acc_rest[s, 1], acc_rest[s, 2]
        t_still = still_t[s]
        ref_n, ref_d = mag_norm_ref[s], mag_dip_ref[s]
        cand_n, cand_d, cand_t = mag_cand_norm[s], mag_cand_dip[s], mag_cand_t[s]
        # gains and low-pass coefficients depend only on the interval: recomputed when it
        # changes (derived, not state)
        gains_step = -1.0
        k_rest = k_ref = k_mag = 0.0
        bw_step = -1.0
        bb0 = ba1 = ba2 = 0.0
        for i in range(n):
            g0, g1, g2 = gyr[s, i, 0], gyr[s, i, 1], gyr[s, i, 2]
            a0, a1, a2 = acc[s, i, 0], acc[s, i, 1], acc[s, i, 2]
            acc_ok = a0 != 0.0 or a1 != 0.0 or a2 != 0.0
            step = dt[i]
            rest = False
            disturbed = False
            if acc_ok and stage == LP_EMPTY:
                # the first usable sample since the start: it starts both low-passes (q_gyr
                # is the identity at a start, so I is the body frame then)
                l0, l1, l2 = _rotate(gw, gx, gy, gz, a0, a1, a2)
                ar0, ar1, ar2 = a0, a1, a2
                stage = LP_FIRST
                acc_ok = False  # used: not filtered a second time below
            if step > 0.0 and step != gains_step:
                k_rest = _lowpass_gain(step, coef[C_REST_TAU])
                k_ref = _lowpass_gain(step, coef[C_MAG_REF_TAU])
                k_mag = _lowpass_gain(step, tau_mag)
                gains_step = step
            if step > 0.0:
                t_start += step
                # -- 1. strapdown: q_gyr ⊗ exp((ω - b) dt / 2) -------------------------
                dw, dx, dy, dz = exp_half(g0 - b0_, g1 - b1_, g2 - b2_, step)
                gw, gx, gy, gz = mul(gw, gx, gy, gz, dw, dx, dy, dz)
                gw, gx, gy, gz = normalized(gw, gx, gy, gz)

                # -- 2. bias: random walk between measurements -------------------------
                walk = coef[C_BIAS_WALK] ** 2 * step
                p0 += walk
                p1 += walk
                p2 += walk

                # -- 3. rest detection: small deviation from slow means, small rate ----
                gr0 += k_rest * (g0 - gr0)
                gr1 += k_rest * (g1 - gr1)
                gr2 += k_rest * (g2 - gr2)
                dev_g = (g0 - gr0) ** 2 + (g1 - gr1) ** 2 + (g2 - gr2) ** 2
                still = (
                    dev_g < coef[C_REST_GYR] ** 2
                    and abs(gr0) < bias_max
                    and abs(gr1) < bias_max
                    and abs(gr2) < bias_max
                )
                if acc_ok:
                    ar0 += k_rest * (a0 - ar0)
                    ar1 += k_rest * (a1 - ar1)
                    ar2 += k_rest * (a2 - ar2)
                    dev_a = (a0 - ar0) ** 2 + (a1 - ar1) ** 2 + (a2 - ar2) ** 2
                    still = still and dev_a < coef[C_REST_ACC] ** 2
                    t_still = t_still + step if still else 0.0
                elif not still:
                    t_still = 0.0  # without an accelerometer the gyro alone can end rest
                rest = still and t_still >= coef[C_REST_MIN_T]
                if rest:
                    # at rest the gyro reads its bias: a Kalman update per axis
                    r = coef[C_BIAS_REST_NOISE] ** 2
                    gain = p0 / (p0 + r)
                    b0_ += gain * (gr0 - b0_)
                    p0 = (1.0 - gain) * p0
                    gain = p1 / (p1 + r)
                    b1_ += gain * (gr1 - b1_)
                    p1 = (1.0 - gain) * p1
                    gain = p2 / (p2 + r)
                    b2_ += gain * (gr2 - b2_)
                    p2 = (1.0 - gain) * p2

                # -- 4. inclination: low-passed acc in I must point up -----------------
                # (an all-zero sample is no measurement: nothing is fed to the low-pass)
                if acc_ok:
                    ex, ey, ez = _rotate(gw, gx, gy, gz, a0, a1, a2)
                    if step != bw_step:
                        bb0, ba1, ba2 = butterworth_coefficients(step, tau_acc)
                        bw_step = step
                    if stage == LP_FIRST:
                        # start the low-pass steady at the first sample
                        s10, s20 = _bw_hold(bb0, ba1, ba2, l0)
                        s11, s21 = _bw_hold(bb0, ba1, ba2, l1)
                        s12, s22 = _bw_hold(bb0, ba1, ba2, l2)
                        stage = LP_FILTER
                    l0, s10, s20 = _bw_step(bb0, ba1, ba2, s10, s20, ex)
                    l1, s11, s21 = _bw_step(bb0, ba1, ba2, s11, s21, ey)
                    l2, s12, s22 = _bw_step(bb0, ba1, ba2, s12, s22, ez)
                    lx, ly, lz = _rotate(cw, cx, cy, cz, l0, l1, l2)
                    norm = math.sqrt(lx * lx + ly * ly + lz * lz)
                    if norm > 0.0:
                        lx, ly, lz = lx / norm, ly / norm, lz / norm
                        # shortest arc taking (lx, ly, lz) to up = [0, 0, 1] (004)
                        if lz > -0.999999:
                            sq = math.sqrt(2.0 * (1.0 + lz))
                            rw, rx, ry = 0.5 * sq, ly / sq, -lx / sq
                        else:
                            rw, rx, ry = 0.0, 1.0, 0.0
                        cw, cx, cy, cz = mul(rw, rx, ry, 0.0, cw, cx, cy, cz)
                        cw, cx, cy, cz = normalized(cw, cx, cy, cz)
                        if not rest:
                            # the applied correction rate (level frame), seen in the body,
                            # is minus the horizontal bias error: a bias measurement in
                            # motion
                            q6w, q6x, q6y, q6z = mul(cw, cx, cy, cz, gw, gx, gy, gz)
                            ux, uy, uz = _rotate(
                                q6w, -q6x, -q6y, -q6z, 2.0 * rx / step, 2.0 * ry / step, 0.0
                            )
                            # only the horizontal components are observed: weight by how
                            # much of each body axis lies in the horizontal plane
                            vx, vy, vz = _rotate(q6w, -q6x, -q6y, -q6z, 0.0, 0.0, 1.0)
                            r = coef[C_BIAS_MOTION_NOISE] ** 2
                            horizontal = 1.0 - vx * vx
                            if horizontal > 1e-3:
                                gain = p0 * horizontal / (p0 * horizontal + r)
                                b0_ -= gain * ux
                                p0 = (1.0 - gain * horizontal) * p0
                            horizontal = 1.0 - vy * vy
                            if horizontal > 1e-3:
                                gain = p1 * horizontal / (p1 * horizontal + r)
                                b1_ -= gain * uy
                                p1 = (1.0 - gain * horizontal) * p1
                            horizontal = 1.0 - vz * vz
                            if horizontal > 1e-3:
                                gain = p2 * horizontal / (p2 * horizontal + r)
                                b2_ -= gain * uz
                                p2 = (1.0 - gain * horizontal) * p2
                b0_ = min(max(b0_, -bias_max), bias_max)
                b1_ = min(max(b1_, -bias_max), bias_max)
                b2_ = min(max(b2_, -bias_max), bias_max)

            # -- 5. heading from the horizontal field --------------------------------
            q6w, q6x, q6y, q6z = mul(cw, cx, cy, cz, gw, gx, gy, gz)
            if has_mag:
                mx, my, mz = _rotate(q6w, q6x, q6y, q6z, mag[s, i, 0], mag[s, i, 1], mag[s, i, 2])
                m_norm = math.sqrt(mx * mx + my * my + mz * mz)
                horizontal = math.sqrt(mx * mx + my * my)
                # an all-zero sample (no measurement) has m_norm == 0: skipped
                usable = m_norm > 0.0 and horizontal > 1e-6 * m_norm
                if usable:
                    dip = math.atan2(-mz, horizontal)
                    # angle of the horizontal field from north (+y) towards east (+x)
                    field_heading = math.atan2(mx, my)
                    if ref_n <= 0.0:
                        ref_n = m_norm
                        cand_n = m_norm
                    if math.isnan(ref_d):
                        ref_d = dip
                        cand_d = dip
                    disturbed = (
                        abs(m_norm - ref_n) > coef[C_MAG_NORM_TOL] * ref_n
                        or abs(dip - ref_d) > coef[C_MAG_DIP_TOL]
                    )
                    if step > 0.0:
                        if not disturbed:
                            ref_n += k_ref * (m_norm - ref_n)
                            ref_d += k_ref * (dip - ref_d)
                            cand_n = m_norm
                            cand_d = dip
                            cand_t = 0.0
                            # a fixed time constant: an adaptive (Kalman) gain that grows
                            # after fast turns or rejected disturbances was measured worse
                            # on BROAD, re-acquiring still-distorted fields too quickly.
                            # Start-up: the mean of the measurements while 1/n is larger
                            k = k_mag
                            if t_start < converge:
                                hd_n += 1
                                k = max(k_mag, 1.0 / hd_n)
                            error = _wrap(field_heading - head)
                            head = _wrap(head + k * error)
                        else:
                            # a new, steady field: track a candidate and adopt it once it
                            # has stayed consistent for long enough (a new environment)
                            steady = (
                                abs(m_norm - cand_n) < coef[C_MAG_NORM_TOL] * cand_n
                                and abs(dip - cand_d) < coef[C_MAG_DIP_TOL]
                            )
                            if steady:
                                cand_t += step
                                cand_n += k_ref * (m_norm - cand_n)
                                cand_d += k_ref * (dip - cand_d)
                            else:
                                cand_t = 0.0
                                cand_n = m_norm
                                cand_d = dip
                            if cand_t > coef[C_MAG_NEW_REF_T]:
                                ref_n = cand_n
                                ref_d = cand_d
                                cand_t = 0.0
                if t_start == 0.0 and hd_n == 1 and (disturbed or not usable):
                    # a start without an undisturbed field: its heading is no measurement,
                    # the first one replaces it
                    hd_n = 0

            # -- 6. outputs ---------------------------------------------------------
            if has_mag:
                half = 0.5 * head
                ow, ox, oy, oz = mul(math.cos(half), 0.0, 0.0, math.sin(half), q6w, q6x, q6y, q6z)
            else:
                ow, ox, oy, oz = q6w, q6x, q6y, q6z
            if ned:
                ow, ox, oy, oz = mul(0.0, h, h, 0.0, ow, ox, oy, oz)
                q6w, q6x, q6y, q6z = mul(0.0, h, h, 0.0, q6w, q6x, q6y, q6z)
            quat_out[s, i, 0], quat_out[s, i, 1] = ow, ox
            quat_out[s, i, 2], quat_out[s, i, 3] = oy, oz
            quat6_out[s, i, 0], quat6_out[s, i, 1] = q6w, q6x
            quat6_out[s, i, 2], quat6_out[s, i, 3] = q6y, q6z
            bias_out[s, i, 0], bias_out[s, i, 1], bias_out[s, i, 2] = b0_, b1_, b2_
            bias_sd_out[s, i, 0] = math.sqrt(p0)
            bias_sd_out[s, i, 1] = math.sqrt(p1)
            bias_sd_out[s, i, 2] = math.sqrt(p2)
            rest_out[s, i] = rest
            mag_dist_out[s, i] = disturbed

        # -- store the state -------------------------------------------------------------
        q_gyr[s, 0], q_gyr[s, 1], q_gyr[s, 2], q_gyr[s, 3] = gw, gx, gy, gz
        q_acc[s, 0], q_acc[s, 1], q_acc[s, 2], q_acc[s, 3] = cw, cx, cy, cz
        heading[s] = head
        bias[s, 0], bias[s, 1], bias[s, 2] = b0_, b1_, b2_
        bias_var[s, 0], bias_var[s, 1], bias_var[s, 2] = p0, p1, p2
        acc_lp[s, 0], acc_lp[s, 1], acc_lp[s, 2] = l0, l1, l2
        acc_lp_bw[s, 0, 0], acc_lp_bw[s, 0, 1] = s10, s20
        acc_lp_bw[s, 1, 0], acc_lp_bw[s, 1, 1] = s11, s21
        acc_lp_bw[s, 2, 0], acc_lp_bw[s, 2, 1] = s12, s22
        acc_lp_stage[s] = stage
        heading_n[s] = hd_n
        since_start[s] = t_start
        gyr_rest[s, 0], gyr_rest[s, 1], gyr_rest[s, 2] = gr0, gr1, gr2
        acc_rest[s, 0], acc_rest[s, 1], acc_rest[s, 2] = ar0, ar1, ar2
        still_t[s] = t_still
        mag_norm_ref[s], mag_dip_ref[s] = ref_n, ref_d
        mag_cand_norm[s], mag_cand_dip[s], mag_cand_t[s] = cand_n, cand_d, cand_t
