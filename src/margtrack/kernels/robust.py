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

State layout per sensor (``state`` (S, N_STATE)) is given by the ``I_*`` offsets below.
"""

from __future__ import annotations

import math

from numba import njit

from margtrack.kernels._quat import exp_half, mul, normalized

# -- state layout ------------------------------------------------------------------------
I_QGYR = 0  # 4: q_gyr
I_QACC = 4  # 4: q_acc
I_HEAD = 8  # heading, rad
I_BIAS = 9  # 3: gyro bias, rad/s (body)
I_BIAS_VAR = 12  # 3: variance of the bias estimate per body axis, (rad/s)²
I_ACC_LP = 15  # 3: accelerometer low-passed in frame I, m/s²
I_GYR_REST = 18  # 3: gyro low-passed for rest detection, rad/s
I_ACC_REST = 21  # 3: accelerometer low-passed for rest detection, m/s²
I_REST_T = 24  # time spent still, s
I_MAG_NORM_REF = 25  # reference field norm (0: none yet)
I_MAG_DIP_REF = 26  # reference dip, rad
I_MAG_CAND_NORM = 27  # candidate norm while disturbed
I_MAG_CAND_DIP = 28  # candidate dip while disturbed
I_MAG_CAND_T = 29  # time the candidate has been consistent, s
I_BW = 30  # 6: Butterworth states (s1, s2) of the three accelerometer channels
I_BW_DT = 36  # sample interval the coefficients below were computed for, s
I_BW_COEF = 37  # 3: b0, a1, a2 of the second-order Butterworth low-pass
N_STATE = 40

# -- parameter layout (``coef`` (N_COEF,)) ------------------------------------------------
C_TAU_ACC = 0
C_TAU_MAG = 1
C_BIAS_WALK = 2
C_BIAS_REST_NOISE = 3
C_BIAS_MOTION_NOISE = 4
C_BIAS_MAX = 5
C_REST_GYR = 6
C_REST_ACC = 7
C_REST_MIN_T = 8
C_REST_TAU = 9
C_MAG_NORM_TOL = 10
C_MAG_DIP_TOL = 11
C_MAG_NEW_REF_T = 12
C_MAG_REF_TAU = 13
C_NED = 14
N_COEF = 15


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
def _butterworth(st, step, tau):
    """Second-order Butterworth low-pass coefficients for time constant tau at interval step.

    Cut-off ``f_c = sqrt(2) / (2 pi tau)`` (so its step response is close to a first-order
    filter's with the same tau), discretised by the bilinear transform with pre-warping;
    recomputed only when the sample interval changes.
    """
    if step != st[I_BW_DT]:
        fc = math.sqrt(2.0) / (2.0 * math.pi * tau)
        c = math.tan(math.pi * fc * step)
        d = c * c + math.sqrt(2.0) * c + 1.0
        st[I_BW_COEF] = c * c / d
        st[I_BW_COEF + 1] = 2.0 * (c * c - 1.0) / d
        st[I_BW_COEF + 2] = (1.0 - math.sqrt(2.0) * c + c * c) / d
        st[I_BW_DT] = step


@njit(cache=True, inline="always")
def _butterworth_step(st, k, x):
    """Filter one sample of channel k (transposed direct form II); returns the output."""
    b0, a1, a2 = st[I_BW_COEF], st[I_BW_COEF + 1], st[I_BW_COEF + 2]
    y = b0 * x + st[I_BW + 2 * k]
    st[I_BW + 2 * k] = 2.0 * b0 * x - a1 * y + st[I_BW + 2 * k + 1]
    st[I_BW + 2 * k + 1] = b0 * x - a2 * y
    return y


@njit(cache=True, inline="always")
def _butterworth_hold(st, k, x):
    """Set channel k's states to the steady state of a constant input x."""
    b0, a1, a2 = st[I_BW_COEF], st[I_BW_COEF + 1], st[I_BW_COEF + 2]
    st[I_BW + 2 * k + 1] = (b0 - a2) * x
    st[I_BW + 2 * k] = (2.0 * b0 - a1) * x + st[I_BW + 2 * k + 1]


@njit(cache=True)
def _init(st, acc, q0):
    """Start from q0 (ENU): all of it in q_acc, heading 0, filters at the first sample."""
    st[I_QGYR] = 1.0
    st[I_QGYR + 1] = 0.0
    st[I_QGYR + 2] = 0.0
    st[I_QGYR + 3] = 0.0
    for k in range(4):
        st[I_QACC + k] = q0[k]
    st[I_HEAD] = 0.0
    for k in range(3):
        st[I_ACC_LP + k] = 0.0
        st[I_ACC_REST + k] = acc[k]
        st[I_GYR_REST + k] = 0.0
    # q_gyr starts at identity, so the strapdown frame I is the body frame at sample 0
    st[I_ACC_LP] = acc[0]
    st[I_ACC_LP + 1] = acc[1]
    st[I_ACC_LP + 2] = acc[2]
    st[I_BW_DT] = -1.0  # coefficients not computed yet
    st[I_REST_T] = 0.0
    st[I_MAG_NORM_REF] = 0.0
    st[I_MAG_CAND_T] = 0.0


@njit(cache=True)
def robust_filter(
    state,
    coef,
    gyr,
    acc,
    mag,
    has_mag,
    dt,
    fresh,
    q_init,
    quat_out,
    quat6_out,
    bias_out,
    bias_sd_out,
    rest_out,
    mag_dist_out,
):
    """Run S filters over N samples.

    state (S, N_STATE) in/out; coef (N_COEF,); gyr, acc, mag (S, N, 3) rad/s, m/s², any
    field unit (mag ignored when ``has_mag`` is False); dt (N,) s; fresh (S,) bool: state
    not yet initialised (then sample 0 initialises from ``q_init`` (S, 4), given in ENU);
    outputs (S, N, ...) filled: 9-D (or 6-D without mag) quaternion in the requested frame,
    6-D quaternion, bias rad/s, bias standard deviation rad/s, rest flag, mag disturbed flag.
    """
    n_sensors, n = gyr.shape[0], gyr.shape[1]
    ned = coef[C_NED] > 0.5
    h = math.sqrt(0.5)
    for s in range(n_sensors):
        st = state[s]
        # low-pass gains depend only on the interval: recompute when it changes
        gains_step = -1.0
        k_rest = k_ref = k_mag = 0.0
        for i in range(n):
            g0, g1, g2 = gyr[s, i, 0], gyr[s, i, 1], gyr[s, i, 2]
            a0, a1, a2 = acc[s, i, 0], acc[s, i, 1], acc[s, i, 2]
            step = dt[i]
            if i == 0 and fresh[s]:
                _init(st, acc[s, i], q_init[s])
                step = 0.0
            rest = False
            disturbed = False
            if step > 0.0 and step != gains_step:
                k_rest = _lowpass_gain(step, coef[C_REST_TAU])
                k_ref = _lowpass_gain(step, coef[C_MAG_REF_TAU])
                k_mag = _lowpass_gain(step, coef[C_TAU_MAG])
                gains_step = step
            if step > 0.0:
                # -- 1. strapdown: q_gyr ⊗ exp((ω - b) dt / 2) -------------------------
                w0 = g0 - st[I_BIAS]
                w1 = g1 - st[I_BIAS + 1]
                w2 = g2 - st[I_BIAS + 2]
                dw, dx, dy, dz = exp_half(w0, w1, w2, step)
                qw, qx, qy, qz = mul(
                    st[I_QGYR], st[I_QGYR + 1], st[I_QGYR + 2], st[I_QGYR + 3], dw, dx, dy, dz
                )
                qw, qx, qy, qz = normalized(qw, qx, qy, qz)
                st[I_QGYR], st[I_QGYR + 1], st[I_QGYR + 2], st[I_QGYR + 3] = qw, qx, qy, qz

                # -- 2. bias: random walk between measurements -------------------------
                walk = coef[C_BIAS_WALK] ** 2 * step
                for k in range(3):
                    st[I_BIAS_VAR + k] += walk

                # -- 3. rest detection: small deviation from slow means, small rate ----
                dev_g = 0.0
                dev_a = 0.0
                for k, (gk, ak) in enumerate(((g0, a0), (g1, a1), (g2, a2))):
                    st[I_GYR_REST + k] += k_rest * (gk - st[I_GYR_REST + k])
                    st[I_ACC_REST + k] += k_rest * (ak - st[I_ACC_REST + k])
                    dev_g += (gk - st[I_GYR_REST + k]) ** 2
                    dev_a += (ak - st[I_ACC_REST + k]) ** 2
                still = (
                    dev_g < coef[C_REST_GYR] ** 2
                    and dev_a < coef[C_REST_ACC] ** 2
                    and abs(st[I_GYR_REST]) < coef[C_BIAS_MAX]
                    and abs(st[I_GYR_REST + 1]) < coef[C_BIAS_MAX]
                    and abs(st[I_GYR_REST + 2]) < coef[C_BIAS_MAX]
                )
                st[I_REST_T] = st[I_REST_T] + step if still else 0.0
                rest = st[I_REST_T] >= coef[C_REST_MIN_T]
                if rest:
                    # at rest the gyro reads its bias: a Kalman update per axis
                    r = coef[C_BIAS_REST_NOISE] ** 2
                    for k in range(3):
                        p = st[I_BIAS_VAR + k]
                        gain = p / (p + r)
                        st[I_BIAS + k] += gain * (st[I_GYR_REST + k] - st[I_BIAS + k])
                        st[I_BIAS_VAR + k] = (1.0 - gain) * p

                # -- 4. inclination: low-passed acc in I must point up -----------------
                ex, ey, ez = _rotate(qw, qx, qy, qz, a0, a1, a2)
                if st[I_BW_DT] < 0.0:
                    _butterworth(st, step, coef[C_TAU_ACC])
                    for k in range(3):
                        _butterworth_hold(st, k, st[I_ACC_LP + k])
                _butterworth(st, step, coef[C_TAU_ACC])
                st[I_ACC_LP] = _butterworth_step(st, 0, ex)
                st[I_ACC_LP + 1] = _butterworth_step(st, 1, ey)
                st[I_ACC_LP + 2] = _butterworth_step(st, 2, ez)
                cw, cx, cy, cz = st[I_QACC], st[I_QACC + 1], st[I_QACC + 2], st[I_QACC + 3]
                lx, ly, lz = _rotate(
                    cw, cx, cy, cz, st[I_ACC_LP], st[I_ACC_LP + 1], st[I_ACC_LP + 2]
                )
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
                    st[I_QACC], st[I_QACC + 1], st[I_QACC + 2], st[I_QACC + 3] = cw, cx, cy, cz
                    if not rest:
                        # the applied correction rate (level frame), seen in the body, is
                        # minus the horizontal bias error: a bias measurement in motion
                        q6w, q6x, q6y, q6z = mul(cw, cx, cy, cz, qw, qx, qy, qz)
                        ux, uy, uz = _rotate(
                            q6w, -q6x, -q6y, -q6z, 2.0 * rx / step, 2.0 * ry / step, 0.0
                        )
                        # only the horizontal components are observed: weight by how much
                        # of each body axis lies in the horizontal plane
                        vx, vy, vz = _rotate(q6w, -q6x, -q6y, -q6z, 0.0, 0.0, 1.0)
                        r = coef[C_BIAS_MOTION_NOISE] ** 2
                        for k, (uk, vk) in enumerate(((ux, vx), (uy, vy), (uz, vz))):
                            horizontal = 1.0 - vk * vk
                            if horizontal > 1e-3:
                                p = st[I_BIAS_VAR + k]
                                gain = p * horizontal / (p * horizontal + r)
                                st[I_BIAS + k] -= gain * uk
                                st[I_BIAS_VAR + k] = (1.0 - gain * horizontal) * p
                for k in range(3):
                    b = st[I_BIAS + k]
                    st[I_BIAS + k] = min(max(b, -coef[C_BIAS_MAX]), coef[C_BIAS_MAX])

            # -- 5. heading from the horizontal field --------------------------------
            q6w, q6x, q6y, q6z = mul(
                st[I_QACC],
                st[I_QACC + 1],
                st[I_QACC + 2],
                st[I_QACC + 3],
                st[I_QGYR],
                st[I_QGYR + 1],
                st[I_QGYR + 2],
                st[I_QGYR + 3],
            )
            if has_mag:
                mx, my, mz = _rotate(q6w, q6x, q6y, q6z, mag[s, i, 0], mag[s, i, 1], mag[s, i, 2])
                m_norm = math.sqrt(mx * mx + my * my + mz * mz)
                horizontal = math.sqrt(mx * mx + my * my)
                if m_norm > 0.0 and horizontal > 1e-6 * m_norm:
                    dip = math.atan2(-mz, horizontal)
                    # angle of the horizontal field from north (+y) towards east (+x)
                    field_heading = math.atan2(mx, my)
                    if st[I_MAG_NORM_REF] <= 0.0:
                        st[I_MAG_NORM_REF] = m_norm
                        st[I_MAG_DIP_REF] = dip
                        st[I_MAG_CAND_NORM] = m_norm
                        st[I_MAG_CAND_DIP] = dip
                    ref_n = st[I_MAG_NORM_REF]
                    disturbed = (
                        abs(m_norm - ref_n) > coef[C_MAG_NORM_TOL] * ref_n
                        or abs(dip - st[I_MAG_DIP_REF]) > coef[C_MAG_DIP_TOL]
                    )
                    if step > 0.0:
                        if not disturbed:
                            st[I_MAG_NORM_REF] += k_ref * (m_norm - ref_n)
                            st[I_MAG_DIP_REF] += k_ref * (dip - st[I_MAG_DIP_REF])
                            st[I_MAG_CAND_NORM] = m_norm
                            st[I_MAG_CAND_DIP] = dip
                            st[I_MAG_CAND_T] = 0.0
                            # a fixed time constant: an adaptive (Kalman) gain that grows
                            # after fast turns or rejected disturbances was measured worse
                            # on BROAD, re-acquiring still-distorted fields too quickly
                            error = _wrap(field_heading - st[I_HEAD])
                            st[I_HEAD] = _wrap(st[I_HEAD] + k_mag * error)
                        else:
                            # a new, steady field: track a candidate and adopt it once it
                            # has stayed consistent for long enough (a new environment)
                            cand_n = st[I_MAG_CAND_NORM]
                            steady = (
                                abs(m_norm - cand_n) < coef[C_MAG_NORM_TOL] * cand_n
                                and abs(dip - st[I_MAG_CAND_DIP]) < coef[C_MAG_DIP_TOL]
                            )
                            if steady:
                                st[I_MAG_CAND_T] += step
                                st[I_MAG_CAND_NORM] += k_ref * (m_norm - cand_n)
                                st[I_MAG_CAND_DIP] += k_ref * (dip - st[I_MAG_CAND_DIP])
                            else:
                                st[I_MAG_CAND_T] = 0.0
                                st[I_MAG_CAND_NORM] = m_norm
                                st[I_MAG_CAND_DIP] = dip
                            if st[I_MAG_CAND_T] > coef[C_MAG_NEW_REF_T]:
                                st[I_MAG_NORM_REF] = st[I_MAG_CAND_NORM]
                                st[I_MAG_DIP_REF] = st[I_MAG_CAND_DIP]
                                st[I_MAG_CAND_T] = 0.0

            # -- 6. outputs ---------------------------------------------------------
            half = 0.5 * st[I_HEAD]
            hw, hz = math.cos(half), math.sin(half)
            ow, ox, oy, oz = mul(hw, 0.0, 0.0, hz, q6w, q6x, q6y, q6z)
            if not has_mag:
                ow, ox, oy, oz = q6w, q6x, q6y, q6z
            if ned:
                ow, ox, oy, oz = mul(0.0, h, h, 0.0, ow, ox, oy, oz)
                q6w, q6x, q6y, q6z = mul(0.0, h, h, 0.0, q6w, q6x, q6y, q6z)
            quat_out[s, i, 0], quat_out[s, i, 1] = ow, ox
            quat_out[s, i, 2], quat_out[s, i, 3] = oy, oz
            quat6_out[s, i, 0], quat6_out[s, i, 1] = q6w, q6x
            quat6_out[s, i, 2], quat6_out[s, i, 3] = q6y, q6z
            for k in range(3):
                bias_out[s, i, k] = st[I_BIAS + k]
                bias_sd_out[s, i, k] = math.sqrt(st[I_BIAS_VAR + k])
            rest_out[s, i] = rest
            mag_dist_out[s, i] = disturbed
