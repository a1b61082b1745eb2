"""Many sensors in lockstep: blocks of ``LANES`` sensors advanced together, sample by sample.

``contract.run_series`` runs each sensor through all its samples in turn. Here a block of
up to LANES sensors goes through the samples together. Their rows are interleaved in one
flat buffer (row slot j of a lane at ``buf[j * LANES + lane]``), and a loop over the lanes
runs a sample's screening for all of them, another their steps. Every access is then a
constant offset from the lane, so the compiler vectorises these loops across sensors. The
results are those of ``contract.run_series`` bit for bit: each sensor gets the same
arithmetic in the same order (a vector lane rounds as a scalar does, and no libm call is
made in the vector loops: ``_fastmath``).

A method provides its ``contract`` functions in strided form: the row's slot j at
``st[o + j * lanes]``, output k at ``xa[xo + k * outs]``:

- ``start_at(st, o, lanes, coef, first, qw, qx, qy, qz)``;
- ``step_at(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, qa, qo,
  xa, xo, outs, steady)``, returning its flag bits;
- ``hold_at(st, o, lanes, coef, xa, xo, outs)``;
- ``rare_at(st, o, lanes, coef, dt, has_mag, a0, a1, a2, m0, m1, m2)``: whether this
  sample (as screened) takes a rare branch of the step (a call or a loop the vectoriser
  cannot take: Bachmann's heading set from the field, say). The vector pass calls
  ``step_at`` with the constant ``steady=True``, so the step leaves those branches out of
  its code.

(Re)starts are rare (the first usable sample, after a gap) and call TRIAD. When a lane of
the block (re)starts or its step takes a rare branch, that sample's steps of the whole
block run in scalar code (``steady=False``, the same results for the other lanes), with
the sample as screened, which is the order of ``contract._sample``. Otherwise every lane
steps in the vector loop, none left out: a lane left out makes each store of the step a
masked store, slow on AMD's cores, and
the screening's stores are unconditional too (``jit.select``), also for a value the same
for all lanes (``has_mag``).

Entry points using these must be compiled with ``error_model="numpy"``. Under numba's
default a float division checks its divisor and may raise: a branch the vectoriser cannot
take. The kernels guard every division they make, so no result depends on it.
"""

from __future__ import annotations

import numpy as np

from margtrack.estimator import restart_kernel as restart
from margtrack.estimator import screen_kernel as screen
from margtrack.estimator import skeleton as contract
from margtrack.estimator.jit import njit, select
from margtrack.estimator.skeleton import (
    C_NED,
    INITIALISING,
    K_Q,
    K_READY,
    K_REF,
    K_SCREEN,
    K_STARTS,
    K_WINDOW,
)

#: sensors per block: 4 AVX-512 vectors; a block's buffer (about 70 slots) stays in L1
LANES = 32

# a lane's slots after its row (offsets from the row's width n_row)
B_GYR = 0  # 3: this sample's rate, rad/s; screened in place
B_ACC = 3  # 3: acceleration, m/s²; screened in place
B_MAG = 6  # 3: field; screened in place
B_Q = 9  # 4: the output orientation
B_FLAGS = 13  # 1: the flags (as a float: 16 bits are exact)
B_SCALAR = 14  # 1: what the scalar pass does for the lane: 0 nothing, RESTART or STEP
B_X = 15  # K: the method's extra outputs
N_B = B_X

RESTART = 1.0  # the lane (re)starts at this sample
STEP = 2.0  # the lane's step takes a rare branch


@njit(cache=True, inline="always")
def _screen_lane(rare_at, st, o, n_row, coef, scoef, dt, k_ref, tflags, has_mag, has_gyr):
    """A lane's sample, first part (the vector pass): screen it in place, and note whether
    its step needs the scalar pass (it (re)starts, or takes a rare branch)."""
    lanes = LANES
    i_in = o + (n_row + B_GYR) * lanes
    f, g0, g1, g2, a0, a1, a2, m0, m1, m2 = screen.screen_at_inline(
        scoef, st, o + K_SCREEN * lanes, lanes, dt, k_ref, tflags,
        st[i_in], st[i_in + lanes], st[i_in + 2 * lanes],
        st[i_in + 3 * lanes], st[i_in + 4 * lanes], st[i_in + 5 * lanes],
        st[i_in + 6 * lanes], st[i_in + 7 * lanes], st[i_in + 8 * lanes], has_mag, has_gyr,
    )
    st[i_in], st[i_in + lanes], st[i_in + 2 * lanes] = g0, g1, g2
    st[i_in + 3 * lanes], st[i_in + 4 * lanes], st[i_in + 5 * lanes] = a0, a1, a2
    st[i_in + 6 * lanes], st[i_in + 7 * lanes], st[i_in + 8 * lanes] = m0, m1, m2
    rare = rare_at(st, o, lanes, coef, dt, has_mag, a0, a1, a2, m0, m1, m2)
    ready = st[o + K_READY * lanes] != 0.0
    st[o + (n_row + B_FLAGS) * lanes] = f
    st[o + (n_row + B_SCALAR) * lanes] = select(ready, select(rare, STEP, 0.0), RESTART)


@njit(cache=True, inline="always")
def _step_lane(step_at, st, o, n_row, coef, dt, has_mag):
    """A lane's sample, second part (the vector pass, when no lane of the block needs the
    scalar pass): the step, on the sample as screened."""
    lanes = LANES
    i_in = o + (n_row + B_GYR) * lanes
    i_q, i_f = o + (n_row + B_Q) * lanes, o + (n_row + B_FLAGS) * lanes
    f = step_at(st, o, lanes, coef, dt, st[i_in], st[i_in + lanes], st[i_in + 2 * lanes],
                st[i_in + 3 * lanes], st[i_in + 4 * lanes], st[i_in + 5 * lanes],
                st[i_in + 6 * lanes], st[i_in + 7 * lanes], st[i_in + 8 * lanes], has_mag,
                st, i_q, st, o + (n_row + B_X) * lanes, lanes, True)
    st[i_f] = int(st[i_f]) | f
    i_last = o + K_Q * lanes
    st[i_last], st[i_last + lanes] = st[i_q], st[i_q + lanes]
    st[i_last + 2 * lanes], st[i_last + 3 * lanes] = st[i_q + 2 * lanes], st[i_q + 3 * lanes]


@njit(cache=True, inline="always")
def _scalar(start_at, step_at, hold_at, window_field_at, st, o, n_row, coef, scoef, dt,
            has_mag):
    """The rest of a lane's sample in the scalar pass (``contract._sample``): its (re)start
    if it has one, and its step (the same results as :func:`_step_lane`'s, rare branches
    included)."""
    lanes = LANES
    i_in = o + (n_row + B_GYR) * lanes
    g0, g1, g2 = st[i_in], st[i_in + lanes], st[i_in + 2 * lanes]
    a0, a1, a2 = st[i_in + 3 * lanes], st[i_in + 4 * lanes], st[i_in + 5 * lanes]
    m0, m1, m2 = st[i_in + 6 * lanes], st[i_in + 7 * lanes], st[i_in + 8 * lanes]
    i_q, i_x = o + (n_row + B_Q) * lanes, o + (n_row + B_X) * lanes
    i_f = o + (n_row + B_FLAGS) * lanes
    f = int(st[i_f])
    if st[o + (n_row + B_SCALAR) * lanes] == RESTART:
        if not restart.pending(st, o, lanes, K_WINDOW):  # a start (not after a gap): this sample's
            ok, qw, qx, qy, qz = contract.initial(scoef, a0, a1, a2, m0, m1, m2)
            if not ok:
                for k in range(4):
                    st[i_q + k * lanes] = st[o + (K_Q + k) * lanes]
                hold_at(st, o, lanes, coef, st, i_x, lanes)
                st[i_f] = f | INITIALISING
                return
        else:  # a restart: from a window of samples (restart_kernel)
            o0, o1, o2, own_n, own_d = window_field_at(st, o, lanes)
            w0, w1, w2 = restart.off(m0, m1, m2, o0, o1, o2)
            done = restart.add(st, o, lanes, K_WINDOW, K_REF, scoef, own_n, own_d, dt, f, g0,
                               g1, g2, a0, a1, a2, w0, w1, w2)
            held, qw, qx, qy, qz = restart.orientation(st, o, lanes, K_WINDOW, K_Q, K_REF,
                                                       scoef, own_n, own_d, C_NED, has_mag,
                                                       done)
            if not done:
                st[i_q], st[i_q + lanes], st[i_q + 2 * lanes], st[i_q + 3 * lanes] = (
                    qw, qx, qy, qz)
                hold_at(st, o, lanes, coef, st, i_x, lanes)
                st[i_f] = f | INITIALISING
                return
            if held and has_mag:
                f |= restart.HEADING_CARRIED
            a0, a1, a2, m0, m1, m2 = restart.measured(st, o, lanes, K_WINDOW, held)
            m0, m1, m2 = restart.on(m0, m1, m2, o0, o1, o2)
        start_at(st, o, lanes, coef, st[o + K_STARTS * lanes] == 0.0, qw, qx, qy, qz)
        st[o + K_STARTS * lanes] += 1.0
        st[o + K_READY * lanes] = 1.0
        dt = 0.0  # the measured orientation is this sample's: nothing to integrate
    f |= step_at(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag,
                 st, i_q, st, i_x, lanes, False)
    for k in range(4):
        st[o + (K_Q + k) * lanes] = st[i_q + k * lanes]
    st[i_f] = f


@njit(cache=True)
def _move_rows(rows, s0, n, n_row, st, into_block):
    """Rows s0 .. s0 + n into the block's interleaved buffer (slot j of lane l at
    ``st[j * LANES + l]``), or back (``into_block`` False)."""
    lanes = LANES
    if into_block:
        for lane in range(n):
            for j in range(n_row):
                st[j * lanes + lane] = rows[s0 + lane, j]
    else:
        for lane in range(n):
            for j in range(n_row):
                rows[s0 + lane, j] = st[j * lanes + lane]


@njit(cache=True, inline="always")
def _rows_in(rows, s0, n, n_row, st):
    """Rows s0 .. s0 + n into the block's buffer (:func:`_move_rows`)."""
    _move_rows(rows, s0, n, n_row, st, True)


@njit(cache=True, inline="always")
def _rows_out(rows, s0, n, n_row, st):
    """The block's buffer into rows s0 .. s0 + n (:func:`_move_rows`)."""
    _move_rows(rows, s0, n, n_row, st, False)


@njit(cache=True, inline="always")
def block(scalar_pass, step_at, rare_at, n_row, n_x, st, rows, s0, scoef, coef, dts, ks, tflags,
          gyr, acc, mag, has, q_out, x_out, flags_out, frame_major, s_in):
    """Sensors s0 .. s0 + LANES (fewer at the end) through all samples, in lockstep.

    The inputs gyr, acc, mag are (S, N, 3) (``s_in`` 0), or with ``frame_major`` (N, S', 3)
    as the live engine's sources deliver them (a frame's sensors together), sensor s at
    ``s_in + s``: read where they are, no copy into the per-sensor layout first (the block
    gathers each sample's lanes either way; frame-major, they are next to each other).

    ``scalar_pass(st, lane, n_row, coef, scoef, dt, has_mag)``: :func:`_scalar` with the
    method's functions, compiled on its own (``skeleton.entry_points``' ``lanes_scalar``).
    ``st`` ((n_row + N_B + n_x) * LANES,) is the block's buffer, as scratch; ``n_row``,
    ``n_x`` the method's row and extra outputs widths (constants). For a kernel compiled
    with ``_nrt=False`` (numba's reference counting, kept otherwise around every array
    passed to an inlined function, is a call the vectoriser cannot take), by a method's
    entry point (``skeleton.entry_points``' ``lanes``). The coefficients come as tuples
    (``jit.to_fixed_tuple``, with the method's constant ``N_COEF``, in its entry point): read
    from an array, each is a pointer the vectorised loop must check at run time against the
    buffer it writes, and LLVM gives up beyond a few; a tuple is values.
    """
    has_mag, has_gyr = (has & 1) != 0, (has & 2) != 0
    lanes = LANES
    n = min(lanes, rows.shape[0] - s0)
    _rows_in(rows, s0, n, n_row, st)
    i_in = (n_row + B_GYR) * lanes
    i_q, i_x, i_f = (n_row + B_Q) * lanes, (n_row + B_X) * lanes, (n_row + B_FLAGS) * lanes
    i_scalar = (n_row + B_SCALAR) * lanes
    n_x_out = x_out.shape[2]  # at most n_x
    for i in range(dts.shape[0]):
        dt, k_ref, tf = dts[i], ks[i], tflags[i]
        # unsigned indices: numba adds no wraparound for a negative index to them
        iu = np.uint64(i)
        for lane in range(n):
            su, lu = np.uint64(s_in + s0 + lane), np.uint64(lane)
            j0, j1 = (iu, su) if frame_major else (su, iu)  # (frame, sensor) or (sensor, frame)
            for c in range(3):
                cu = np.uint64(c)
                st[np.uint64(i_in + c * lanes) + lu] = gyr[j0, j1, cu]
                st[np.uint64(i_in + (3 + c) * lanes) + lu] = acc[j0, j1, cu]
                st[np.uint64(i_in + (6 + c) * lanes) + lu] = mag[j0, j1, cu]
        if tf & screen.GAP:
            for lane in range(n):
                st[K_READY * lanes + lane] = 0.0
                restart.clear(st, lane, lanes, K_WINDOW, st[K_STARTS * lanes + lane] > 0.0)
        for lane in range(n):  # vectorised across the lanes
            _screen_lane(rare_at, st, lane, n_row, coef, scoef, dt, k_ref, tf, has_mag,
                         has_gyr)
        scalar = 0.0
        for lane in range(n):
            scalar += st[i_scalar + lane]
        if scalar == 0.0:
            for lane in range(n):  # vectorised, no lane left out (no masked stores)
                _step_lane(step_at, st, lane, n_row, coef, dt, has_mag)
        else:  # a lane (re)starts or takes a rare branch: the block's sample in scalar code
            for lane in range(n):
                scalar_pass(st, lane, n_row, coef, scoef, dt, has_mag)
        for lane in range(n):
            su, lu = np.uint64(s0 + lane), np.uint64(lane)
            flags_out[su, iu] = int(st[np.uint64(i_f) + lu])
            for k in range(4):
                q_out[su, iu, np.uint64(k)] = st[np.uint64(i_q + k * lanes) + lu]
            for k in range(n_x_out):
                x_out[su, iu, np.uint64(k)] = st[np.uint64(i_x + k * lanes) + lu]
    _rows_out(rows, s0, n, n_row, st)
