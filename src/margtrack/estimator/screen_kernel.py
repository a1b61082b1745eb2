"""Kernel of the input screening every method runs before its own kernel.

Per sample and sensor it decides what can be used and replaces what cannot, so the
method's kernel never sees a non-finite or absurd value (``estimator/screening.py`` has
the policy in words). The sentinels the method kernels honour:

- ``dt = 0``: nothing to integrate (first sample, gap, skipped timestamp);
- an all-zero accelerometer or magnetometer vector: no measurement, skip that correction.

Flag bits are those of ``estimator/flags.py`` (kept as plain ints here: numba).

:func:`screen_at` is compiled once and called by every method's ``run`` (inlined into each
method it would be compiled again for each, the larger part of their compile time); the
lockstep blocks inline it (:data:`screen_at_inline`) to vectorise it across sensors. Its
helpers are inlined into it.
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator import fastmath as _fastmath
from margtrack.estimator.jit import keep, njit

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

# -- per-sensor state layout (``sc`` (N_SCREEN,)) -------------------------------------------
S_LAST_GYR = 0  # 3: last good rate, rad/s
S_ACC_PREV = 3  # 3: last usable acceleration, m/s²
S_MAG_PREV = 6  # 3: previous field sample
S_MAG_HOLD = 9  # 3: how long each field axis has held its value while turning, s
S_MAG_PEAK = 12  # 3: largest |value| of each field axis so far
S_MAG_CLIP = 15  # 3: learned clip level of each field axis (0: none)
S_REF = 18  # 5: the field reference, offsets R_* below
N_SCREEN = 23

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
#: a field this many times off its reference norm is a glitch in any environment
ABSURD = 10.0


@njit(cache=True)
def fresh(sc):
    """Screening states that have seen nothing: sc (S, N_SCREEN), in place."""
    for s in range(sc.shape[0]):
        for k in range(N_SCREEN):
            sc[s, k] = 0.0
        for k in range(3):
            sc[s, S_MAG_PREV + k] = math.nan
        sc[s, S_REF + R_DIP] = math.nan
        sc[s, S_REF + R_CAND_DIP] = math.nan


@njit(cache=True, inline="always")
def time_one(clock, max_gap, ti):
    """Interval and clock flag of one timestamp after ``clock[0]`` (nan: none yet); updates it.

    Returns (dt, flags): dt is what to integrate (0 for the first sample, a gap, a clock
    reset or a skipped timestamp). A jump back by more than ``max_gap`` is a clock reset
    (treated as a gap); a smaller one, a repeated or a non-finite time is skipped (CLOCK).
    """
    if not math.isfinite(ti):
        return 0.0, CLOCK
    t_last = clock[0]
    if not math.isfinite(t_last):
        clock[0] = ti
        return 0.0, 0
    d = ti - t_last
    if d > max_gap or -d > max_gap:
        clock[0] = ti
        return 0.0, (GAP if d > 0.0 else GAP | CLOCK)
    if d > 0.0:
        clock[0] = ti
        return d, 0
    return 0.0, CLOCK


@njit(cache=True)
def screen_time(t, t_last, max_gap, dt_out, flags_out):
    """:func:`time_one` over timestamps ``t`` (N,); returns the new last accepted time."""
    clock = np.array([t_last])
    for i in range(t.shape[0]):
        dt_out[i], flags_out[i] = time_one(clock, max_gap, t[i])
    return clock[0]


@njit(cache=True, inline="always")
def _finite3(x, y, z):
    return math.isfinite(x) and math.isfinite(y) and math.isfinite(z)


@njit(cache=True, inline="always")
def ref_gain(step):
    """Gain of the field reference's slow tracking over an interval ``step`` s (0: none).

    The same for every sensor sharing the clock: a series computes it once per sample.
    """
    return 1.0 - math.exp(-step / REF_TAU_S) if step > 0.0 else 0.0


@njit(cache=True)
def screen_one(coef, sc, step, time_flags, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, has_gyr):
    """:func:`screen_one_k` with the reference gain of ``step`` (:func:`ref_gain`)."""
    return screen_one_k(coef, sc, step, ref_gain(step), time_flags, g0, g1, g2, a0, a1, a2,
                        m0, m1, m2, has_mag, has_gyr)


@njit(cache=True)
def screen_one_k(coef, sc, step, k_ref, time_flags, g0, g1, g2, a0, a1, a2, m0, m1, m2,
                 has_mag, has_gyr):
    """Screen one sensor's sample; returns (flags, g0, g1, g2, a0, a1, a2, m0, m1, m2).

    coef (N_COEF,); sc (N_SCREEN,) the sensor's screening state, in/out; step, time_flags
    from :func:`time_one`; rad/s, m/s², any field unit (the field read only when
    ``has_mag``, the rate when ``has_gyr``; without a gyroscope, turning is seen in the
    accelerometer's direction). Bad rates come back as the last good one, an unusable
    acceleration or field as the zero sentinel. ``k_ref``: ``ref_gain(step)``.
    """
    return screen_at(coef, sc, 0, 1, step, k_ref, time_flags, g0, g1, g2, a0, a1, a2, m0, m1,
                     m2, has_mag, has_gyr)


@njit(cache=True)
def screen_at(coef, st, o, lanes, step, k_ref, time_flags, g0, g1, g2, a0, a1, a2, m0, m1, m2,
              has_mag, has_gyr):
    """:func:`screen_one_k` with the screening state's slot j at ``st[o + j * lanes]``.

    ``(sc, 0, 1)`` is one sensor's state array; ``(st, lane, LANES)`` a lane of a block of
    sensors whose states are interleaved (``contract_lanes``): there the compiler can
    vectorise the screening across sensors, since every access is a constant offset from
    the lane.
    """
    f = time_flags
    skip = (f & CLOCK) != 0 and (f & GAP) == 0
    i_gyr, i_acc = o + S_LAST_GYR * lanes, o + S_ACC_PREV * lanes
    # -- gyroscope: a bad rate is replaced by the last good one ------------------------
    # (the state's stores here and below go through jit.keep: in lockstep a store in a
    # branch, even one on a value the same for all lanes, is a masked store)
    g_range = coef[C_GYR_RANGE] * (1.0 - 1e-9)
    g_finite = _finite3(g0, g1, g2)
    g_in = abs(g0) < g_range and abs(g1) < g_range and abs(g2) < g_range
    if has_gyr and not g_finite:
        f |= INVALID | GYR_CLIPPED
    elif has_gyr and not g_in:
        f |= GYR_CLIPPED
    g_ok = has_gyr and g_finite and g_in
    keep(st, i_gyr, g_ok, g0, lanes)
    keep(st, i_gyr + lanes, g_ok, g1, lanes)
    keep(st, i_gyr + 2 * lanes, g_ok, g2, lanes)
    if has_gyr:
        g0, g1, g2 = st[i_gyr], st[i_gyr + lanes], st[i_gyr + 2 * lanes]
    else:
        g0 = g1 = g2 = 0.0  # a method that reads no gyroscope: nothing to screen
    # -- accelerometer: a bad sample becomes the zero sentinel --------------------------
    a_range = coef[C_ACC_RANGE] * (1.0 - 1e-9)
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
    # -- magnetometer ------------------------------------------------------------------
    # (in lockstep the field is screened whatever has_mag, its state kept unless has_mag: a
    # branch on it would make the state's stores masked stores)
    if has_mag or lanes > 1:
        m_finite = _finite3(m0, m1, m2)
        w0, w1, w2 = g0, g1, g2
        if not has_gyr:
            w0, w1, w2 = _acc_turn_rate(st, o, lanes, acc_ok, a0, a1, a2, step)
        # (the axes' state moves only for a finite sample)
        usable = _field_usable(coef, st, o, lanes, step, w0, w1, w2, m0, m1, m2,
                               has_mag and m_finite)
        mag_ok = m_finite and usable
        if has_mag and not m_finite:
            f |= INVALID | MAG_IGNORED
        elif has_mag and not usable:
            f |= MAG_IGNORED
        # the reference is tracked for every method; the norm/dip gate applies to methods
        # without their own rejection, the absurd-norm check to all (the reference moves
        # only for a usable sample not skipped)
        far = _disturbed(coef, st, o, lanes, step, k_ref, acc_ok, a0, a1, a2, m0, m1, m2,
                         has_mag and mag_ok and not skip)
        if has_mag and mag_ok and not skip:
            if far == 2:
                f |= MAG_IGNORED
                mag_ok = False
            elif far == 1 and coef[C_CHECK_DISTURBANCE] > 0.5:
                f |= MAG_DISTURBED
                mag_ok = False
        if not (has_mag and mag_ok) or skip:
            m0 = m1 = m2 = 0.0
    else:
        m0 = m1 = m2 = 0.0
    keep(st, i_acc, acc_ok, a0, lanes)
    keep(st, i_acc + lanes, acc_ok, a1, lanes)
    keep(st, i_acc + 2 * lanes, acc_ok, a2, lanes)
    return f, g0, g1, g2, a0, a1, a2, m0, m1, m2


#: :func:`screen_at` inlined where it is called: the lockstep blocks (``contract_lanes``)
#: vectorise its loop across sensors only with its body in the loop. Elsewhere it is
#: called, compiled once for every method.
screen_at_inline = njit(cache=True, inline="always")(getattr(screen_at, "py_func", screen_at))


@njit(cache=True, inline="always")
def _axis_usable(st, o, lanes, step, k, mk, wk, rate2, stuck_s, n_changed, live):
    """:func:`_field_usable` for field axis k (value mk, rate wk about it): updates the
    axis's previous value, hold time, peak and clip level if ``live``; returns whether it
    is usable."""
    i_prev, i_hold = o + (S_MAG_PREV + k) * lanes, o + (S_MAG_HOLD + k) * lanes
    i_peak, i_clip = o + (S_MAG_PEAK + k) * lanes, o + (S_MAG_CLIP + k) * lanes
    hold, peak, clip = st[i_hold], st[i_peak], st[i_clip]
    ok = True
    if mk == st[i_prev]:
        # held: count only while the sensor turns about another axis
        if rate2 - wk * wk > TURN_RAD_S * TURN_RAD_S:
            hold += step
    else:
        hold = 0.0
    level = abs(mk)
    if hold >= stuck_s:
        ok = False
        # pinned at its extreme while another axis moves: a clip level
        if n_changed > 0 and level > 0.0 and level >= peak and (clip == 0.0 or level < clip):
            clip = level
    elif clip > 0.0 and level >= clip * (1.0 - 1e-12):
        ok = False
    keep(st, i_prev, live, mk, lanes)
    keep(st, i_hold, live, hold, lanes)
    keep(st, i_peak, live, max(peak, level), lanes)
    keep(st, i_clip, live, clip, lanes)
    return ok


@njit(cache=True, inline="always")
def _field_usable(coef, st, o, lanes, step, w0, w1, w2, m0, m1, m2, live):
    """Whether a finite field sample is usable: no axis stuck or at a learned clip level.
    The axes' state moves only if ``live`` (the sample is finite).

    An axis that holds its value while the sensor turns about another axis for
    ``mag_stuck_s`` is stuck; if it is pinned at its largest value so far while another
    axis moves, that value is remembered as its clip level and ignored at once afterwards.
    """
    stuck_s = coef[C_MAG_STUCK]
    rate2 = w0 * w0 + w1 * w1 + w2 * w2
    i_prev = o + S_MAG_PREV * lanes
    n_changed = (m0 != st[i_prev]) + (m1 != st[i_prev + lanes]) + (m2 != st[i_prev + 2 * lanes])
    ok = not (m0 == 0.0 and m1 == 0.0 and m2 == 0.0)
    ok = _axis_usable(st, o, lanes, step, 0, m0, w0, rate2, stuck_s, n_changed,
                      live) and ok
    ok = _axis_usable(st, o, lanes, step, 1, m1, w1, rate2, stuck_s, n_changed,
                      live) and ok
    ok = _axis_usable(st, o, lanes, step, 2, m2, w2, rate2, stuck_s, n_changed,
                      live) and ok
    return ok


@njit(cache=True)
def screen_samples(coef, dt, time_flags, gyr, acc, mag, has_mag, has_gyr, sc,
                   gyr_out, acc_out, mag_out, flags_out):
    """:func:`screen_one` over S sensors' N samples; sc (S, N_SCREEN) in/out.

    gyr, acc, mag (S, N, 3) (mag read only when ``has_mag``, gyr when ``has_gyr``);
    outputs (S, N, 3) and flags_out (S, N) uint16. The sensors share the clock, so the
    reference gain of each interval (an ``exp``) is computed once for all of them (the same
    value: :func:`screen_one_k`).
    """
    k_ref = np.empty(dt.shape[0])
    for i in range(dt.shape[0]):
        k_ref[i] = ref_gain(dt[i])
    for s in range(acc.shape[0]):
        sc_s = sc[s]
        for i in range(acc.shape[1]):
            f, g0, g1, g2, a0, a1, a2, m0, m1, m2 = screen_one_k(
                coef, sc_s, dt[i], k_ref[i], time_flags[i],
                gyr[s, i, 0], gyr[s, i, 1], gyr[s, i, 2],
                acc[s, i, 0], acc[s, i, 1], acc[s, i, 2],
                mag[s, i, 0], mag[s, i, 1], mag[s, i, 2],
                has_mag, has_gyr,
            )
            gyr_out[s, i, 0], gyr_out[s, i, 1], gyr_out[s, i, 2] = g0, g1, g2
            acc_out[s, i, 0], acc_out[s, i, 1], acc_out[s, i, 2] = a0, a1, a2
            mag_out[s, i, 0], mag_out[s, i, 1], mag_out[s, i, 2] = m0, m1, m2
            flags_out[s, i] = f


@njit(cache=True, inline="always")
def _acc_turn_rate(st, o, lanes, acc_ok, a0, a1, a2, step):
    """Rate (rad/s, body) that turned the accelerometer's direction since the last usable one.

    Only the rotation about horizontal axes is seen; zero when either sample is unusable.
    """
    i_acc = o + S_ACC_PREV * lanes
    p0, p1, p2 = st[i_acc], st[i_acc + lanes], st[i_acc + 2 * lanes]
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


@njit(cache=True, inline="always")
def _disturbed(coef, st, o, lanes, step, k, acc_ok, a0, a1, a2, m0, m1, m2, live):
    """How far the field is from the tracked reference: 0 close, 1 disturbed, 2 absurd.
    The reference's state moves only if ``live`` (the sample is usable and not skipped).

    Disturbed: norm or dip beyond ``mag_norm_tol`` / ``mag_dip_tol_deg``; absurd: a norm
    more than ABSURD times off, which no environment explains (a glitch), and which does
    not move the reference. The reference starts at the given values or the first sample,
    follows slowly while the field agrees with it, and is replaced by a new field that
    stays steady for NEW_REF_S (a new environment). ``k``: ``ref_gain(step)``.
    """
    norm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    j = o + S_REF * lanes  # the reference's slot r is st[j + r * lanes]
    ref_n, ref_d = st[j + R_NORM * lanes], st[j + R_DIP * lanes]
    cand_n, cand_d = st[j + R_CAND_NORM * lanes], st[j + R_CAND_DIP * lanes]
    cand_s = st[j + R_CAND_S * lanes]
    absurd = ref_n > 0.0 and (norm > ABSURD * ref_n or norm * ABSURD < ref_n)
    # the dip, computed whatever the acceleration (then kept or not), with no library call
    # (_fastmath): the compiler then vectorises this across sensors
    a_norm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    den = a_norm * norm
    sine = -(a0 * m0 + a1 * m1 + a2 * m2) / (den if den > 0.0 else 1.0)
    dip = _fastmath.asin(min(1.0, max(-1.0, sine)))
    if not (acc_ok and abs(a_norm - GRAVITY) < DIP_ACC_TOL_M_S2):
        dip = math.nan
    if ref_n <= 0.0:
        ref_n = coef[C_REF_NORM] if coef[C_REF_NORM] > 0.0 else norm
        ref_d = coef[C_REF_DIP]
        cand_n, cand_d, cand_s = norm, dip, 0.0
    if math.isnan(ref_d) and not math.isnan(dip):
        ref_d = dip
    tol_n, tol_d = coef[C_NORM_TOL], coef[C_DIP_TOL]
    known = not math.isnan(dip) and not math.isnan(ref_d)
    off_dip = known and abs(dip - ref_d) > tol_d
    far = 1
    if not (abs(norm - ref_n) > tol_n * ref_n or off_dip):
        far = 0
        ref_n += k * (norm - ref_n)
        if not math.isnan(dip):
            ref_d += k * (dip - ref_d)
        cand_n, cand_d, cand_s = norm, dip, 0.0
    else:
        cand_known = not math.isnan(dip) and not math.isnan(cand_d)
        cand_off_dip = cand_known and abs(dip - cand_d) > tol_d
        if abs(norm - cand_n) < tol_n * cand_n and not cand_off_dip:
            cand_s += step
            cand_n += k * (norm - cand_n)
            if not math.isnan(dip):
                if math.isnan(cand_d):
                    cand_d = dip
                cand_d += k * (dip - cand_d)
        else:
            cand_n, cand_d, cand_s = norm, dip, 0.0
        if cand_s > NEW_REF_S:
            ref_n, ref_d, cand_s = cand_n, cand_d, 0.0
    live = live and not absurd  # an absurd sample does not move the reference
    keep(st, j + R_NORM * lanes, live, ref_n, lanes)
    keep(st, j + R_DIP * lanes, live, ref_d, lanes)
    keep(st, j + R_CAND_NORM * lanes, live, cand_n, lanes)
    keep(st, j + R_CAND_DIP * lanes, live, cand_d, lanes)
    keep(st, j + R_CAND_S * lanes, live, cand_s, lanes)
    return 2 if absurd else far
