"""Kernel of the input screening every method runs before its own kernel.

Per sample and sensor it decides what can be used and replaces what cannot, so the
method's kernel never sees a non-finite or absurd value (``estimator/screening.py`` has
the policy in words). The sentinels the method kernels honour:

- ``dt = 0``: nothing to integrate (first sample, gap, skipped timestamp);
- an all-zero accelerometer or magnetometer vector: no measurement, skip that correction.

Flag bits are those of ``estimator/flags.py`` (kept as plain ints here: numba).
"""

from __future__ import annotations

import math

from numba import njit

# flag bits (margtrack.estimator.flags.Flag)
INVALID = 1
CLOCK = 2
GAP = 4
GYR_CLIPPED = 8
ACC_IGNORED = 16
MAG_IGNORED = 32
MAG_DISTURBED = 64

# -- coefficient layout -------------------------------------------------------------------
C_GYR_RANGE = 0  # rad/s
C_ACC_RANGE = 1  # m/s²
C_MAX_GAP = 2  # s
C_MAG_STUCK = 3  # s
C_NORM_TOL = 4  # relative
C_DIP_TOL = 5  # rad
C_CHECK_DISTURBANCE = 6  # 1: gate the field by norm and dip
C_REF_NORM = 7  # given reference norm (0: learn)
C_REF_DIP = 8  # given reference dip, rad (nan: learn)
N_COEF = 9

# -- per-sensor field reference layout (``mag_ref`` (S, N_REF)) -----------------------------
R_NORM = 0  # reference norm (0: none yet)
R_DIP = 1  # reference dip, rad (nan: none yet)
R_CAND_NORM = 2  # candidate new reference while disturbed
R_CAND_DIP = 3
R_CAND_S = 4  # how long the candidate has been steady, s
N_REF = 5

#: a value is "held" only while the rate perpendicular to its axis exceeds this, rad/s
TURN_RAD_S = 0.3
#: time constant of the slow reference tracking, s
REF_TAU_S = 60.0
#: a new steady field becomes the reference after this long, s
NEW_REF_S = 20.0
#: the dip is only compared when |acc| is within this of g (linear acceleration tilts it)
DIP_ACC_TOL_M_S2 = 1.5
GRAVITY = 9.81


@njit(cache=True)
def screen_time(t, t_last, max_gap, dt_out, flags_out):
    """Intervals and clock flags for timestamps ``t`` (N,) after ``t_last`` (nan: none yet).

    dt_out (N,) gets the interval to integrate (0 for the first sample, a gap, a clock
    reset or a skipped timestamp); flags_out (N,) gets CLOCK or GAP. Returns the new last
    accepted time. A jump back by more than ``max_gap`` is a clock reset (treated as a
    gap); a smaller one, a repeated or a non-finite time is skipped.
    """
    for i in range(t.shape[0]):
        ti = t[i]
        dt_out[i] = 0.0
        flags_out[i] = 0
        if not math.isfinite(ti):
            flags_out[i] = CLOCK
            continue
        if not math.isfinite(t_last):
            t_last = ti
            continue
        d = ti - t_last
        if d > max_gap or -d > max_gap:
            flags_out[i] = GAP if d > 0.0 else GAP | CLOCK
            t_last = ti
        elif d > 0.0:
            dt_out[i] = d
            t_last = ti
        else:
            flags_out[i] = CLOCK
    return t_last


@njit(cache=True, inline="always")
def _finite3(x, y, z):
    return math.isfinite(x) and math.isfinite(y) and math.isfinite(z)


@njit(cache=True)
def screen_samples(
    coef,
    dt,
    time_flags,
    gyr,
    acc,
    mag,
    has_mag,
    has_gyr,
    last_gyr,
    acc_prev,
    mag_prev,
    mag_hold_s,
    mag_peak,
    mag_clip,
    mag_ref,
    gyr_out,
    acc_out,
    mag_out,
    flags_out,
):
    """Screen S sensors' samples; write usable (or sentinel) values and flags.

    coef (N_COEF,); dt, time_flags (N,) from :func:`screen_time`; gyr, acc, mag (S, N, 3)
    rad/s, m/s², any field unit (mag read only when ``has_mag``, gyr when ``has_gyr``;
    without a gyroscope, turning is seen in the accelerometer's direction); state (S, ...)
    in/out: last_gyr the last good rate, acc_prev the last usable acceleration, mag_prev
    the previous field sample, mag_hold_s how long each axis has held its value while
    turning, mag_peak the largest |value| of each axis so far, mag_clip learned clip levels
    (0: none),
    mag_ref (S, N_REF). Outputs (S, N, 3) and flags_out (S, N) uint16.
    """
    n_sensors, n = gyr.shape[0], gyr.shape[1]
    g_range = coef[C_GYR_RANGE] * (1.0 - 1e-9)
    a_range = coef[C_ACC_RANGE] * (1.0 - 1e-9)
    stuck_s = coef[C_MAG_STUCK]
    check_dist = coef[C_CHECK_DISTURBANCE] > 0.5
    for s in range(n_sensors):
        for i in range(n):
            f = time_flags[i]
            step = dt[i]
            skip = (f & CLOCK) != 0 and (f & GAP) == 0
            # -- gyroscope: a bad rate is replaced by the last good one ------------------
            g0, g1, g2 = gyr[s, i, 0], gyr[s, i, 1], gyr[s, i, 2]
            if not _finite3(g0, g1, g2):
                f |= INVALID | GYR_CLIPPED
            elif abs(g0) >= g_range or abs(g1) >= g_range or abs(g2) >= g_range:
                f |= GYR_CLIPPED
            else:
                last_gyr[s, 0], last_gyr[s, 1], last_gyr[s, 2] = g0, g1, g2
            g0, g1, g2 = last_gyr[s, 0], last_gyr[s, 1], last_gyr[s, 2]
            gyr_out[s, i, 0], gyr_out[s, i, 1], gyr_out[s, i, 2] = g0, g1, g2
            # -- accelerometer: a bad sample becomes the zero sentinel ----------------
            a0, a1, a2 = acc[s, i, 0], acc[s, i, 1], acc[s, i, 2]
            acc_ok = True
            if not _finite3(a0, a1, a2):
                f |= INVALID | ACC_IGNORED
                acc_ok = False
            elif abs(a0) >= a_range or abs(a1) >= a_range or abs(a2) >= a_range:
                f |= ACC_IGNORED
                acc_ok = False
            elif a0 == 0.0 and a1 == 0.0 and a2 == 0.0:
                f |= ACC_IGNORED
                acc_ok = False
            if not acc_ok or skip:
                a0 = a1 = a2 = 0.0
                acc_ok = False
            acc_out[s, i, 0], acc_out[s, i, 1], acc_out[s, i, 2] = a0, a1, a2
            # -- magnetometer ---------------------------------------------------------
            m0 = m1 = m2 = 0.0
            if has_mag:
                m0, m1, m2 = mag[s, i, 0], mag[s, i, 1], mag[s, i, 2]
                mag_ok = True
                if not _finite3(m0, m1, m2):
                    f |= INVALID | MAG_IGNORED
                    mag_ok = False
                else:
                    w0, w1, w2 = g0, g1, g2
                    if not has_gyr:
                        w0, w1, w2 = _acc_turn_rate(acc_prev[s], acc_ok, a0, a1, a2, step)
                    rate2 = w0 * w0 + w1 * w1 + w2 * w2
                    n_changed = 0
                    for k in range(3):
                        if mag[s, i, k] != mag_prev[s, k]:
                            n_changed += 1
                    for k in range(3):
                        mk = mag[s, i, k]
                        wk = w0 if k == 0 else (w1 if k == 1 else w2)
                        changed = mk != mag_prev[s, k]
                        if not changed:
                            # held: count only while the sensor turns about another axis
                            if rate2 - wk * wk > TURN_RAD_S * TURN_RAD_S:
                                mag_hold_s[s, k] += step
                        else:
                            mag_hold_s[s, k] = 0.0
                        mag_prev[s, k] = mk
                        level = abs(mk)
                        if mag_hold_s[s, k] >= stuck_s:
                            mag_ok = False
                            # pinned at its extreme while another axis moves: a clip level
                            if n_changed > 0 and level > 0.0 and level >= mag_peak[s, k]:
                                if mag_clip[s, k] == 0.0 or level < mag_clip[s, k]:
                                    mag_clip[s, k] = level
                        elif mag_clip[s, k] > 0.0 and level >= mag_clip[s, k] * (1.0 - 1e-12):
                            mag_ok = False
                        mag_peak[s, k] = max(mag_peak[s, k], level)
                    if m0 == 0.0 and m1 == 0.0 and m2 == 0.0:
                        mag_ok = False
                    if not mag_ok:
                        f |= MAG_IGNORED
                if mag_ok and check_dist and not skip:
                    if _disturbed(coef, mag_ref[s], step, acc_ok, a0, a1, a2, m0, m1, m2):
                        f |= MAG_DISTURBED
                        mag_ok = False
                if not mag_ok or skip:
                    m0 = m1 = m2 = 0.0
            mag_out[s, i, 0], mag_out[s, i, 1], mag_out[s, i, 2] = m0, m1, m2
            flags_out[s, i] = f
            if acc_ok:
                acc_prev[s, 0], acc_prev[s, 1], acc_prev[s, 2] = a0, a1, a2


@njit(cache=True, inline="always")
def _acc_turn_rate(prev, acc_ok, a0, a1, a2, step):
    """Rate (rad/s, body) that turned the accelerometer's direction since ``prev``.

    Only the rotation about horizontal axes is seen; zero when either sample is unusable.
    """
    p0, p1, p2 = prev[0], prev[1], prev[2]
    np_ = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    if not acc_ok or step <= 0.0 or np_ == 0.0 or na == 0.0:
        return 0.0, 0.0, 0.0
    scale = 1.0 / (np_ * na * step)
    return (
        (p1 * a2 - p2 * a1) * scale,
        (p2 * a0 - p0 * a2) * scale,
        (p0 * a1 - p1 * a0) * scale,
    )


@njit(cache=True)
def _disturbed(coef, ref, step, acc_ok, a0, a1, a2, m0, m1, m2):
    """Whether the field's norm or dip is far from the tracked reference; tracks it.

    The reference starts at the given values or the first sample, follows slowly while
    the field agrees with it, and is replaced by a new field that stays steady for
    NEW_REF_S (a new environment).
    """
    norm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    dip = math.nan
    a_norm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    if acc_ok and abs(a_norm - GRAVITY) < DIP_ACC_TOL_M_S2:
        sine = -(a0 * m0 + a1 * m1 + a2 * m2) / (a_norm * norm)
        dip = math.asin(min(1.0, max(-1.0, sine)))
    if ref[R_NORM] <= 0.0:
        ref[R_NORM] = coef[C_REF_NORM] if coef[C_REF_NORM] > 0.0 else norm
        ref[R_DIP] = coef[C_REF_DIP]
        ref[R_CAND_NORM] = norm
        ref[R_CAND_DIP] = dip
        ref[R_CAND_S] = 0.0
    if math.isnan(ref[R_DIP]) and not math.isnan(dip):
        ref[R_DIP] = dip
    tol_n, tol_d = coef[C_NORM_TOL], coef[C_DIP_TOL]
    known = not math.isnan(dip) and not math.isnan(ref[R_DIP])
    off_dip = known and abs(dip - ref[R_DIP]) > tol_d
    disturbed = abs(norm - ref[R_NORM]) > tol_n * ref[R_NORM] or off_dip
    k = 1.0 - math.exp(-step / REF_TAU_S) if step > 0.0 else 0.0
    if not disturbed:
        ref[R_NORM] += k * (norm - ref[R_NORM])
        if not math.isnan(dip):
            ref[R_DIP] += k * (dip - ref[R_DIP])
        ref[R_CAND_NORM] = norm
        ref[R_CAND_DIP] = dip
        ref[R_CAND_S] = 0.0
        return False
    cand_n = ref[R_CAND_NORM]
    cand_known = not math.isnan(dip) and not math.isnan(ref[R_CAND_DIP])
    cand_off_dip = cand_known and abs(dip - ref[R_CAND_DIP]) > tol_d
    if abs(norm - cand_n) < tol_n * cand_n and not cand_off_dip:
        ref[R_CAND_S] += step
        ref[R_CAND_NORM] += k * (norm - cand_n)
        if not math.isnan(dip):
            if math.isnan(ref[R_CAND_DIP]):
                ref[R_CAND_DIP] = dip
            ref[R_CAND_DIP] += k * (dip - ref[R_CAND_DIP])
    else:
        ref[R_CAND_S] = 0.0
        ref[R_CAND_NORM] = norm
        ref[R_CAND_DIP] = dip
    if ref[R_CAND_S] > NEW_REF_S:
        ref[R_NORM] = ref[R_CAND_NORM]
        ref[R_DIP] = ref[R_CAND_DIP]
        ref[R_CAND_S] = 0.0
    return disturbed
