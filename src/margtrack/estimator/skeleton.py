"""The compiled skeleton every method's kernel runs on: clock, screening, (re)starts, holds.

A method provides three ``@njit`` functions over one sensor's flat state row ``row``
(``N_CONTRACT`` contract slots first, the method's own after them), named ``_start``,
``_step``, ``_hold`` in its kernel module:

- ``_start(row, coef, first, qw, qx, qy, qz)``: (re)start at the orientation q (body to
  earth, output frame); ``first`` is True the very first time (then the method also sets
  what it knows of the sensor, like a bias variance); a restart after a gap keeps that;
- ``_step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out)``:
  one screened sample (an all-zero acc or mag: no measurement; dt 0: nothing to
  integrate); writes the orientation to ``q_out`` (4,) and what it keeps per sample to
  ``x_out`` (``N_X``,); returns its own flag bits (REST, MAG_DISTURBED, ACC_IGNORED ...);
- ``_hold(row, coef, x_out)``: ``x_out`` of the current state, for held samples.

:func:`entry_points` generates the method's compiled entry points from them: ``run``
(S sensors' N samples; ``update`` is ``run`` over one sample, so N updates equal one run),
``lanes`` (the same in lockstep blocks, for a method that also writes its functions in
strided form) and ``start``. Every sample goes through :func:`_sample`. ``run`` reads the
shared clock sample by sample; ``lanes`` on its values read before (:func:`clock_series`).

``contract_lanes`` runs the same samples for blocks of sensors in lockstep, vectorised
across them, with the same results, for a method that also provides its functions in
strided form.

Contract slots of a row: ``K_READY`` (1: started), ``K_STARTS`` (how many starts),
``K_Q`` (4: the last output; during a restart's window the last before the gap),
``K_SCREEN`` (the screening state, ``screen.N_SCREEN``), ``K_WINDOW`` (a restart's window,
``restart.N_WINDOW``).

The first start (and any start not after a gap: a row set up by hand) is measured from
the first usable sample (:func:`initial`); a restart after a gap or a clock reset that
follows a start, from a short window of samples carried into one frame by the
gyroscope (``estimator/restart_kernel.py``), the output meanwhile flagged
``INITIALISING``.
Screening coefficients ``scoef`` are ``screen``'s plus ``C_NED`` and ``C_MAG_REQUIRED``.
"""

from __future__ import annotations

import math
import types

import numpy as np

from margtrack.estimator import restart_kernel as restart
from margtrack.estimator import screen_kernel as screen
from margtrack.estimator.jit import force_vector_width, njit, to_fixed_tuple
from margtrack.estimator.triad_kernel import level, reference_triad, triad_unit, unit_pair

K_READY = 0
K_STARTS = 1
K_Q = 2
K_SCREEN = 6
K_WINDOW = K_SCREEN + screen.N_SCREEN
N_CONTRACT = K_WINDOW + restart.N_WINDOW
K_REF = K_SCREEN + screen.S_REF  # the screening's field reference (norm, dip)

# screening coefficients beyond screen.N_COEF
C_NED = screen.N_COEF  # 1: the output frame is NED (else ENU)
C_MAG_REQUIRED = screen.N_COEF + 1  # 1: a start needs a usable field (else acc suffices)
N_SCOEF = screen.N_COEF + 2

INITIALISING = 256  # margtrack.estimator.flags.Flag.INITIALISING


@njit(cache=True)
def initial(scoef, a0, a1, a2, m0, m1, m2):
    """The orientation measured by one screened sample: (ok, w, x, y, z).

    TRIAD with a usable field (heading from its horizontal part), else, when the method
    does not require the field, the shortest arc taking the acceleration to up (heading
    left as it falls); not ok when neither is possible.
    """
    ned = scoef[C_NED] > 0.5
    uz = -1.0 if ned else 1.0
    flag, ax, ay, az, mx, my, mz = unit_pair(a0, a1, a2, m0, m1, m2)
    if flag == 0:
        nx, ny = (1.0, 0.0) if ned else (0.0, 1.0)
        s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z = reference_triad(0.0, 0.0, uz, nx, ny, 0.0)
        w, x, y, z = triad_unit(ax, ay, az, mx, my, mz, s1x, s1y, s1z, s2x, s2y, s2z, s3x, s3y, s3z)
        return True, w, x, y, z
    if flag == 1 or scoef[C_MAG_REQUIRED] > 0.5:
        return False, 1.0, 0.0, 0.0, 0.0
    # no usable field: a zero field (flag 2) or one parallel to the acceleration (flag 3)
    if flag == 3 and not (m0 == 0.0 and m1 == 0.0 and m2 == 0.0):
        return False, 1.0, 0.0, 0.0, 0.0
    w, x, y, z = level(1.0, 0.0, 0.0, 0.0, a0, a1, a2, 0.0, 0.0, uz)
    return True, w, x, y, z


@njit(cache=True, inline="always")
def _sample(start, step, hold, window_field, row, coef, scoef, dt, k_ref, tflags, g0, g1, g2,
            a0, a1, a2, m0, m1, m2, has_mag, has_gyr, q_out, x_out):
    """One sensor, one sample: screen, (re)start when due, step or hold; returns flags.

    ``k_ref`` is ``screen.ref_gain(dt)``, shared by the sensors of a sample."""
    f, g0, g1, g2, a0, a1, a2, m0, m1, m2 = screen.screen_at(
        scoef, row, K_SCREEN, 1, dt, k_ref, tflags, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag,
        has_gyr,
    )
    if tflags & screen.GAP:
        row[K_READY] = 0.0
        restart.clear(row, 0, 1, K_WINDOW, row[K_STARTS] > 0.0)
    if row[K_READY] == 0.0:
        if not restart.pending(row, 0, 1, K_WINDOW):  # a start (not after a gap): this sample's
            ok, qw, qx, qy, qz = initial(scoef, a0, a1, a2, m0, m1, m2)
            if not ok:
                for k in range(4):
                    q_out[k] = row[K_Q + k]
                hold(row, coef, x_out)
                return f | INITIALISING
        else:  # a restart: from a window of samples (restart_kernel)
            o0, o1, o2, own_n, own_d = window_field(row, 0, 1)
            w0, w1, w2 = restart.off(m0, m1, m2, o0, o1, o2)
            done = restart.add(row, 0, 1, K_WINDOW, K_REF, scoef, own_n, own_d, dt, f, g0, g1,
                               g2, a0, a1, a2, w0, w1, w2)
            held, qw, qx, qy, qz = restart.orientation(row, 0, 1, K_WINDOW, K_Q, K_REF, scoef,
                                                       own_n, own_d, C_NED, has_mag, done)
            if not done:
                q_out[0], q_out[1], q_out[2], q_out[3] = qw, qx, qy, qz
                hold(row, coef, x_out)
                return f | INITIALISING
            if held and has_mag:
                f |= restart.HEADING_CARRIED
            a0, a1, a2, m0, m1, m2 = restart.measured(row, 0, 1, K_WINDOW, held)
            m0, m1, m2 = restart.on(m0, m1, m2, o0, o1, o2)
        start(row, coef, row[K_STARTS] == 0.0, qw, qx, qy, qz)
        row[K_STARTS] += 1.0
        row[K_READY] = 1.0
        dt = 0.0  # the measured orientation is this sample's: nothing to integrate
    f |= step(row, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, q_out, x_out)
    for k in range(4):
        row[K_Q + k] = q_out[k]
    return f


@njit(cache=True)
def clock_series(clock, max_gap, t):
    """The shared clock over timestamps ``t`` (N,): intervals (N,) s, clock flags (N,) and
    the screening's reference gains (N,) (``screen.ref_gain``, once per sample).

    A gain is computed (an ``exp``) only for an interval that differs from the last two
    computed (a steady rate's intervals take 2-3 values in turn, differing in the last
    bits): the same values at a fraction of the cost on one long stream."""
    n = t.shape[0]
    dts = np.empty(n)
    ks = np.empty(n)
    tflags = np.empty(n, dtype=np.int64)
    dt_a, k_a, dt_b, k_b = math.nan, 0.0, math.nan, 0.0  # the last two computed
    for i in range(n):
        dt, tflags[i] = screen.time_one(clock, max_gap, t[i])
        dts[i] = dt
        if dt == dt_a:
            ks[i] = k_a
        elif dt == dt_b:
            ks[i] = k_b
        else:
            dt_b, k_b = dt_a, k_a
            dt_a, k_a = dt, screen.ref_gain(dt)
            ks[i] = k_a
    return dts, ks, tflags


@njit(cache=True, inline="always")
def series(start, step, hold, window_field, rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out,
           flags_out):
    """S sensors' N samples with common timestamps ``t`` (N,) s on the shared ``clock``
    (1,) in/out.

    rows (S, R) in/out; coefs: the screening coefficients (N_SCOEF) then the method's;
    gyr, acc, mag (S, N, 3); ``has`` bits: 1 a field is given, 2 a rate is given;
    q_out (S, N, 4), x_out (S, N, K), flags_out (S, N) uint16 filled. Each sensor runs
    through its samples on its own, reading the clock from where the call found it (the
    same intervals for all; the clock ends where one sensor's samples leave it). A
    reference gain is computed (an ``exp``) only for an interval that differs from the last
    two (a steady rate's intervals take 2-3 values in turn). The body of a method's
    ``run``, compiled without numba's reference counting (``_nrt=False``): with it, every
    array a sample passes on (the row, the output rows) is counted in and out, about a
    dozen atomic calls per sample.
    """
    scoef, coef = coefs[:N_SCOEF], coefs[N_SCOEF:]
    has_mag, has_gyr = (has & 1) != 0, (has & 2) != 0
    max_gap = scoef[screen.C_MAX_GAP]
    clock_before = clock[0]
    for s in range(rows.shape[0]):
        clock[0] = clock_before
        row, gyr_s, acc_s, mag_s, q_s, x_s = rows[s], gyr[s], acc[s], mag[s], q_out[s], x_out[s]
        dt_a, k_a, dt_b, k_b = math.nan, 0.0, math.nan, 0.0  # the last two gains computed
        for i in range(t.shape[0]):
            dt, tflags = screen.time_one(clock, max_gap, t[i])
            if dt == dt_a:
                k_ref = k_a
            elif dt == dt_b:
                k_ref = k_b
            else:
                dt_b, k_b = dt_a, k_a
                dt_a, k_a = dt, screen.ref_gain(dt)
                k_ref = k_a
            flags_out[s, i] = _sample(
                start, step, hold, window_field, row, coef, scoef, dt, k_ref, tflags,
                gyr_s[i, 0], gyr_s[i, 1], gyr_s[i, 2], acc_s[i, 0], acc_s[i, 1], acc_s[i, 2],
                mag_s[i, 0], mag_s[i, 1], mag_s[i, 2], has_mag, has_gyr, q_s[i], x_s[i],
            )


@njit(cache=True, inline="always")
def start_rows(start, rows, coefs, quat0):
    """Start every sensor at a given orientation quat0 (S, 4) (``reset(q0)``)."""
    coef = coefs[N_SCOEF:]
    for s in range(rows.shape[0]):
        row = rows[s]
        start(row, coef, row[K_STARTS] == 0.0, quat0[s, 0], quat0[s, 1], quat0[s, 2], quat0[s, 3])
        row[K_STARTS] += 1.0
        row[K_READY] = 1.0
        for k in range(4):
            row[K_Q + k] = quat0[s, k]


# -- the entry points generated for a method (entry_points) ---------------------------------
# Templates: plain functions whose free names (_start, _step, _hold, _start_at, _step_at,
# _hold_at, _rare_at, N_ROW, N_X, N_COEF) are a method's, bound by entry_points.


def _run_template(rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out, flags_out):
    """S sensors' N samples at times t (N,) s: rows (S, N_ROW) and clock (1,) in/out, gyr,
    acc, mag (S, N, 3), q_out (S, N, 4), x_out (S, N, N_X), flags_out (S, N) filled
    (:func:`series`)."""
    series(_start, _step, _hold, _window_field_at, rows, clock, coefs, t, gyr,  # noqa: F821
           acc, mag, has, q_out, x_out, flags_out)


def _lanes_template(st, rows, coefs, dts, ks, tflags, gyr, acc, mag, has, q_out, x_out,
                    flags_out, frame_major, s_in):
    """:func:`_run_template` by blocks of sensors in lockstep (``contract_lanes.block``), on
    the clock already read (:func:`clock_series`), the same results; ``st``
    ((N_ROW + contract_lanes.N_B + N_X) * LANES,) scratch; the
    inputs (S, N, 3), or with ``frame_major`` (N, S', 3), sensor s at ``s_in + s``."""
    # coefficients as tuples of constant length: values, not memory the loop must check
    scoef = to_fixed_tuple(coefs, N_SCOEF)
    coef = to_fixed_tuple(coefs[N_SCOEF:], N_COEF)  # noqa: F821
    for s0 in range(0, rows.shape[0], contract_lanes.LANES):  # noqa: F821
        contract_lanes.block(  # noqa: F821
            _lanes_scalar, _step_at, _rare_at, N_ROW, N_X,  # noqa: F821
            st, rows, s0, scoef, coef, dts, ks, tflags, gyr, acc, mag, has, q_out, x_out,
            flags_out, frame_major, s_in)


def _lanes_scalar_template(st, o, n_row, coef, scoef, dt, has_mag):
    """A lane's sample in the lockstep blocks' scalar pass (``contract_lanes._scalar``):
    called, not inlined, by :func:`_lanes_template` (only a block with a lane that
    (re)starts or takes a rare branch reaches it; inlined, it was compiled into the
    blocks' vector code, and ``lanes`` took twice as long to compile: docs/speed.md)."""
    contract_lanes._scalar(_start_at, _step_at, _hold_at, _window_field_at,  # noqa: F821
                           st, o, n_row, coef, scoef, dt, has_mag)


def _start_template(rows, coefs, quat0):
    """Start S sensors at quat0 (S, 4), an orientation given whole (:func:`start_rows`)."""
    start_rows(_start_given, rows, coefs, quat0)  # noqa: F821


def _generated(template, name, module, options, **names_extra):
    """``template`` compiled as the function ``name`` of ``module``, its free names bound to
    the module's: numba caches it beside the module's own kernels (an edit of the module
    compiles it again) under its own name."""
    from margtrack.estimator import lockstep as contract_lanes

    names = dict(globals(), contract_lanes=contract_lanes)
    names.update({k: v for k, v in vars(module).items() if not k.startswith("__")})
    names.update(names_extra, __name__=module.__name__)
    code = template.__code__.replace(co_filename=module.__file__, co_name=name,
                                     co_qualname=name)
    func = types.FunctionType(code, names, name)
    func.__module__ = module.__name__
    func.__qualname__ = name
    func.__doc__ = template.__doc__
    return njit(cache=True, **options)(func)


def entry_points(module_name):
    """The compiled entry points of the method whose kernel module is ``module_name``:
    ``(run, lanes, start)``, written by the method as
    ``run, lanes, start = contract.entry_points(__name__)`` below its functions.

    The module provides ``_start``, ``_step``, ``_hold`` over one row (this module's
    docstring; ``_start_given`` too if a start at an orientation given whole,
    ``reset(q0)``, differs from one measured; ``_window_field_at`` if it takes a hard-iron
    offset off the field: ``estimator/restart_kernel.py``), ``N_ROW`` and ``N_X`` (values per sample
    ``run`` writes); ``lanes`` (None otherwise) when it also provides them strided
    (``_start_at``, ``_step_at``, ``_hold_at``, ``_rare_at``: ``estimator/lockstep.py``) and
    ``N_COEF``. ``lanes`` runs on a clock already read (:func:`clock_series`); both release
    the GIL (threads share the sensors) and count no references (``_nrt=False``: a dozen
    atomic calls a sample otherwise); ``lanes`` also compiles float division without its zero check
    (``error_model="numpy"``, a branch the vectoriser cannot take: the kernels guard every
    division), with LLVM's vectoriser forced to the module's ``LANES_VECTOR_WIDTH`` lanes
    if it sets one (``jit.force_vector_width``). The blocks' scalar pass (a lane that
    (re)starts or takes a rare branch) is a function of its own, ``lanes_scalar``, called
    by ``lanes`` (inlined, it made ``lanes`` take twice as long to compile).
    """
    import sys

    module = sys.modules[module_name]
    # a method's view of the field for a restart's window (restart_kernel), if it has one
    window_field = getattr(module, "_window_field_at", restart.no_own_field)
    run = _generated(_run_template, "run", module, {"nogil": True, "_nrt": False},
                     _window_field_at=window_field)
    # a start at an orientation given whole (``reset(q0)``) may differ from one measured
    start = _generated(_start_template, "start", module, {},
                       _start_given=getattr(module, "_start_given", module._start))
    lanes = None
    if hasattr(module, "_step_at"):
        options = {"nogil": True, "_nrt": False, "error_model": "numpy"}
        scalar = _generated(_lanes_scalar_template, "lanes_scalar", module, options,
                            _window_field_at=window_field)
        lanes = _generated(_lanes_template, "lanes", module, options, _lanes_scalar=scalar)
        width = getattr(module, "LANES_VECTOR_WIDTH", None)
        if width:
            lanes = force_vector_width(lanes, width)
    return run, lanes, start
