"""A restart after a gap or a clock reset: the orientation measured over a short window.

The very first start of a recording is measured from one sample (``skeleton.initial``).
After a gap the sensor may be moving fast, or beside a disturbed field, so one sample's
acceleration (mostly motion) and field (the disturbance) can give an orientation far off:
upside down, or the heading a half turn wrong. A restart instead waits for a window of
samples and measures the orientation at its last sample:

- the gyroscope carries every sample of the window into the window's first body frame
  (``r``: the current frame relative to the first, ``r ← r ⊗ exp(ω dt / 2)``). Carried so,
  the accelerations are the first frame's view of ``g + a_lin`` with the earth fixed, so
  their mean over T s is gravity plus ``Δv / T``, the velocity change over the window
  over its length: the tilt error is at most ``atan(|Δv| / (g T))``;
- inclination: while at least half of the accelerations are within :data:`ACC_TOL` of g
  (:func:`quiet`: gentle motion) the mean of those over :data:`WINDOW_S` s; otherwise the
  mean of every usable one over :data:`WINDOW_MAX_S` s, long enough for ``Δv / T`` to be
  small in the fastest hand motion;
- heading: TRIAD from the mean of the window's field samples that agree with the field
  reference the screening learned before the gap (norm within the norm tolerance of the
  reference's: :func:`reference`), when they are the majority of the window's field
  samples and the dip of their mean is within the dip tolerance of the reference's: the
  field after the gap is then the earth's field as it was known, so it gives the heading
  whatever the sensor did during the gap (no gyroscope data in a gap: a carried heading is
  a guess off by the gap's turn). Without a reference (none learned yet) every field
  sample agrees. Otherwise the field after the gap is not the one known before it: the
  last orientation before the gap keeps its heading (``level``), and the restart's sample
  is flagged ``HEADING_CARRIED`` (when a magnetometer is given: a 6-D method's heading is
  always carried, not flagged). Whether the field was disturbed before the gap does not
  matter: only the field after it is judged.
- a method that takes a hard-iron offset off its field (``robust``) gives the window its
  view of the field (``_window_field_at(st, o, lanes)`` in its kernel: the offset, and its
  reference norm and dip for the corrected field; a norm < 0 when it rejects the field, a
  magnet turning with the sensor and not yet fitted): the window's field samples have the
  offset taken off and are judged by that reference, so a carried magnet's field neither
  passes for the earth's nor hides it. :func:`measured`'s field is the window's mean as
  the method reads it (offset back on). Without it (:func:`no_own_field`) the screening's.

During the window (flagged ``INITIALISING``) the output is the window's orientation so far
(at its first sample what a one-sample start gives, then better as samples add up); the
method's state is not touched and starts at the window's orientation at its last sample,
that sample stepped with the window's mean measurements (:func:`measured`), then converges
with its restart gain.

The window's slots live in the contract's row (``skeleton.K_WINDOW``). :func:`add`,
:func:`orientation`, :func:`measured` and a method's view of the field are called, not
inlined, by the entry points (only a restarting sample reaches them; inlined into every
method's two entry points they doubled the compile time). Every function here is in
strided form (slot j at ``st[o + (k + j) * lanes]``, ``k`` the window's first
slot), so the per-sensor skeleton (``(row, 0, 1)``) and the lockstep blocks' scalar pass
(``(st, lane, LANES)``) share the same arithmetic: bit for bit the same results. Nothing
here runs on a sample that does not restart: the steady step is untouched.
"""

from __future__ import annotations

import math

from margtrack.estimator import fastmath as _fastmath
from margtrack.estimator import screen_kernel as screen
from margtrack.estimator.jit import njit
from margtrack.estimator.quat_kernel import exp_half, mul, normalized
from margtrack.estimator.triad_kernel import level, reference_triad, rotate, triad_unit, unit_pair

W_T = 0  # s since the gap (the sum of the window's intervals)
W_R = 1  # 4: the current body frame relative to the window's first
W_ACC = 5  # 3: sum of the accepted accelerations in the first frame, m/s²
W_N_ACC = 8  # how many accepted
W_ALL = 9  # 3: sum of every usable acceleration in the first frame, m/s²
W_N_ALL = 12  # how many usable
W_MAG = 13  # 3: sum of the field samples that agree with the reference, in the first frame
W_N_MAG = 16  # how many agree
W_N_OFF = 17  # field samples off the reference's norm (or flagged MAG_DISTURBED)
W_PENDING = 18  # 1: a gap after a start; the next start is a restart, from a window
N_WINDOW = 19

#: an acceleration counts toward inclination in gentle motion while | |a| - g | < ACC_TOL g:
#: the accelerometers' own scale error and a walking body's vertical bounce stay inside it,
#: a push or a swing does not
ACC_TOL = 0.1
#: the window in gentle motion, s: over it a slow hand movement's velocity change (a few
#: tenths of m/s) leaves ``atan(Δv / (g T))`` of a few degrees, and it spans at least one
#: period of every motion above 2.5 Hz (the bulk of hand and body motion's power, tremor,
#: gait's harmonics) so their linear acceleration averages out
WINDOW_S = 0.4
#: the window when most samples are far from g, s: a fast hand movement's velocity change
#: of up to about 1 m/s leaves ``atan(1 / (9.81 * 1.5))`` = 4 degrees; longer would hold the
#: output at the window's estimate longer while the gyroscope's drift is negligible either
#: way (0.01 rad/s for 1.5 s: under a degree)
WINDOW_MAX_S = 1.5

#: the relative norm and the dip (deg) tolerances a restart's field is judged by, at least:
#: the shared screening's defaults (``estimator/params.py``: ``mag_norm_tol``,
#: ``mag_dip_tol_deg``), the field's variation indoors that still gives its heading
NORM_TOL = 0.25
DIP_TOL_DEG = 20.0

HEADING_CARRIED = 512  # margtrack.estimator.flags.Flag.HEADING_CARRIED


@njit(cache=True, _nrt=False)
def no_own_field(st, o, lanes):
    """A method's view of the field for a restart's window, for a method without one: no
    offset to take off, the screening's reference (``window_field_at`` below)."""
    return 0.0, 0.0, 0.0, 0.0, math.nan


@njit(cache=True, inline="always")
def off(m0, m1, m2, o0, o1, o2):
    """A field sample with a method's offset taken off (a zero vector, no sample, stays)."""
    if m0 == 0.0 and m1 == 0.0 and m2 == 0.0:
        return m0, m1, m2
    return m0 - o0, m1 - o1, m2 - o2


@njit(cache=True, inline="always")
def on(m0, m1, m2, o0, o1, o2):
    """:func:`measured`'s mean field with the offset back on, as the method reads a field
    (a zero vector, none, stays)."""
    if m0 == 0.0 and m1 == 0.0 and m2 == 0.0:
        return m0, m1, m2
    return m0 + o0, m1 + o1, m2 + o2


@njit(cache=True, inline="always")
def clear(st, o, lanes, k, started):
    """An empty window (at a gap). The next start is a restart from the window if the
    sensor had ``started`` (else it is the first, from a sample)."""
    for j in range(W_PENDING):
        st[o + (k + j) * lanes] = 0.0
    st[o + (k + W_R) * lanes] = 1.0
    st[o + (k + W_PENDING) * lanes] = 1.0 if started else 0.0


@njit(cache=True, inline="always")
def pending(st, o, lanes, k):
    """Whether the next start is a restart from a window (a gap after a start)."""
    return st[o + (k + W_PENDING) * lanes] != 0.0


@njit(cache=True, _nrt=False)
def add(st, o, lanes, k, k_ref, scoef, own_n, own_d, dt, f, g0, g1, g2, a0, a1, a2, m0, m1,
        m2):
    """One screened sample (rad/s, m/s², field; zero vectors: none) into the window;
    returns whether the window is complete. ``k_ref``: the screening's field reference,
    ``own_n``, ``own_d``: the method's (:func:`reference`; a field sample whose norm is off
    the reference's by more than its tolerance does not agree with it)."""
    i = o + k * lanes
    rw, rx = st[i + W_R * lanes], st[i + (W_R + 1) * lanes]
    ry, rz = st[i + (W_R + 2) * lanes], st[i + (W_R + 3) * lanes]
    if dt > 0.0:
        dw, dx, dy, dz = exp_half(g0, g1, g2, dt)
        rw, rx, ry, rz = mul(rw, rx, ry, rz, dw, dx, dy, dz)
        rw, rx, ry, rz = normalized(rw, rx, ry, rz)
        st[i + W_R * lanes], st[i + (W_R + 1) * lanes] = rw, rx
        st[i + (W_R + 2) * lanes], st[i + (W_R + 3) * lanes] = ry, rz
    t = st[i + W_T * lanes] + dt
    st[i + W_T * lanes] = t
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    if na > 0.0:
        bx, by, bz = rotate(rw, rx, ry, rz, a0, a1, a2)
        st[i + W_ALL * lanes] += bx
        st[i + (W_ALL + 1) * lanes] += by
        st[i + (W_ALL + 2) * lanes] += bz
        st[i + W_N_ALL * lanes] += 1.0
        if abs(na - screen.GRAVITY) < ACC_TOL * screen.GRAVITY:
            st[i + W_ACC * lanes] += bx
            st[i + (W_ACC + 1) * lanes] += by
            st[i + (W_ACC + 2) * lanes] += bz
            st[i + W_N_ACC * lanes] += 1.0
    nm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if nm > 0.0:
        ref_n, _, tol_n, _ = reference(st, o, lanes, k_ref, scoef, own_n, own_d)
        if own_n < 0.0 or (ref_n > 0.0 and abs(nm - ref_n) > tol_n * ref_n):
            st[i + W_N_OFF * lanes] += 1.0
        else:
            bx, by, bz = rotate(rw, rx, ry, rz, m0, m1, m2)
            st[i + W_MAG * lanes] += bx
            st[i + (W_MAG + 1) * lanes] += by
            st[i + (W_MAG + 2) * lanes] += bz
            st[i + W_N_MAG * lanes] += 1.0
    elif (f & screen.MAG_DISTURBED) != 0:
        st[i + W_N_OFF * lanes] += 1.0
    return st[i + W_N_ALL * lanes] > 0.0 and (
        (t >= WINDOW_S and quiet(st, o, lanes, k)) or t >= WINDOW_MAX_S)


@njit(cache=True, inline="always")
def reference(st, o, lanes, k_ref, scoef, own_n, own_d):
    """The field reference learned before the gap and how far a field may be from it and
    still agree: (norm, dip rad (nan: unknown), relative norm tolerance, dip tolerance rad).

    The screening's reference (``k_ref``), unless the method gives its own (``own_n`` > 0,
    ``own_d``: a method that takes a hard-iron offset off its field keeps its reference
    for the corrected field; ``own_n`` < 0: the method rejects the field, none agrees).

    The tolerances are the method's own (``mag_norm_tol``, ``mag_dip_tol_deg``) but never
    tighter than the shared screening's defaults (:data:`NORM_TOL`, :data:`DIP_TOL_DEG`):
    a method that rejects its field more tightly while tracking loses nothing for a
    while (the gyroscope holds the heading), but a restart that rejects it carries a
    heading the sensor may have turned away from by anything during the gap."""
    ref_n = st[o + (k_ref + screen.R_NORM) * lanes]
    ref_d = st[o + (k_ref + screen.R_DIP) * lanes]
    if own_n > 0.0:
        ref_n, ref_d = own_n, own_d
    tol_n = max(scoef[screen.C_NORM_TOL], NORM_TOL)
    tol_d = max(scoef[screen.C_DIP_TOL], DIP_TOL_DEG * (math.pi / 180.0))
    return ref_n, ref_d, tol_n, tol_d


@njit(cache=True, inline="always")
def quiet(st, o, lanes, k):
    """Whether most of the window's accelerations so far are near g (then only those
    count; else every one, the linear acceleration averaging out over a longer window)."""
    n_acc = st[o + (k + W_N_ACC) * lanes]
    return n_acc > 0.0 and 2.0 * n_acc >= st[o + (k + W_N_ALL) * lanes]


@njit(cache=True, _nrt=False)
def orientation(st, o, lanes, k, k_q, k_ref, scoef, own_n, own_d, c_ned, has_mag, done):
    """The window's orientation at its last sample: (heading carried, w, x, y, z).

    ``k_q``: the slots of the last orientation before the gap; ``k_ref``: the screening's
    field reference (norm, dip), ``own_n``, ``own_d`` the method's (:func:`reference`);
    ``scoef[c_ned]`` 1 for NED; ``done``: the window is
    complete (before, the mean acceleration may still be tens of degrees off in fast
    motion, so the mean field's dip is not judged by it)."""
    i = o + k * lanes
    s = W_ACC if quiet(st, o, lanes, k) else W_ALL
    a0, a1, a2 = st[i + s * lanes], st[i + (s + 1) * lanes], st[i + (s + 2) * lanes]
    uz = -1.0 if scoef[c_ned] > 0.5 else 1.0
    n_mag = st[i + W_N_MAG * lanes]
    # the field after the gap agrees with the reference: most of its samples within the
    # norm's tolerance (the mean of those taken), and that mean's dip within the dip's
    clean = has_mag and n_mag > st[i + W_N_OFF * lanes]
    flag, ax, ay, az, mx, my, mz = unit_pair(a0, a1, a2, st[i + W_MAG * lanes],
                                             st[i + (W_MAG + 1) * lanes],
                                             st[i + (W_MAG + 2) * lanes])
    if clean and flag == 0:
        _, ref_d, _, tol_d = reference(st, o, lanes, k_ref, scoef, own_n, own_d)
        dip = _fastmath.asin(min(1.0, max(-1.0, -(ax * mx + ay * my + az * mz))))
        if done and not math.isnan(ref_d) and abs(dip - ref_d) > tol_d:
            clean = False
    else:
        clean = False
    if clean:
        nx, ny = (1.0, 0.0) if uz < 0.0 else (0.0, 1.0)
        s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z = reference_triad(0.0, 0.0, uz, nx, ny, 0.0)
        w, x, y, z = triad_unit(ax, ay, az, mx, my, mz, s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y,
                                s3z)
    else:
        j = o + k_q * lanes
        w, x, y, z = level(st[j], st[j + lanes], st[j + 2 * lanes], st[j + 3 * lanes],
                           a0, a1, a2, 0.0, 0.0, uz)
    w, x, y, z = mul(w, x, y, z, st[i + W_R * lanes], st[i + (W_R + 1) * lanes],
                     st[i + (W_R + 2) * lanes], st[i + (W_R + 3) * lanes])
    w, x, y, z = normalized(w, x, y, z)
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    return not clean, w, x, y, z


@njit(cache=True, _nrt=False)
def measured(st, o, lanes, k, held):
    """The restart is made: the window's mean acceleration (m/s²) and mean field (zero
    when ``held``: the heading was carried) in the current body frame, the measurements
    the restart's sample is stepped with, those its orientation was made from (a method
    that low-passes the accelerometer from its first sample, robust, then starts from the
    mean, not from one sample of motion). Returns (a0, a1, a2, m0, m1, m2)."""
    i = o + k * lanes
    st[i + W_PENDING * lanes] = 0.0  # the restart is made
    rw, rx = st[i + W_R * lanes], -st[i + (W_R + 1) * lanes]
    ry, rz = -st[i + (W_R + 2) * lanes], -st[i + (W_R + 3) * lanes]
    s = W_ACC if quiet(st, o, lanes, k) else W_ALL
    n = st[i + (W_N_ACC if s == W_ACC else W_N_ALL) * lanes]
    a0, a1, a2 = rotate(rw, rx, ry, rz, st[i + s * lanes] / n, st[i + (s + 1) * lanes] / n,
                        st[i + (s + 2) * lanes] / n)
    m0 = m1 = m2 = 0.0
    n_mag = st[i + W_N_MAG * lanes]
    if not held and n_mag > 0.0:
        m0, m1, m2 = rotate(rw, rx, ry, rz, st[i + W_MAG * lanes] / n_mag,
                            st[i + (W_MAG + 1) * lanes] / n_mag,
                            st[i + (W_MAG + 2) * lanes] / n_mag)
    return a0, a1, a2, m0, m1, m2
