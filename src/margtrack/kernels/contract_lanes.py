"""Many sensors in lockstep: blocks of ``LANES`` sensors advanced together, sample by sample.

``contract.run_series`` runs each sensor through all its samples in turn. Here a block of
up to LANES sensors goes through the samples together. Their rows are interleaved in one
flat buffer (row slot j of a lane at ``buf[j * LANES + lane]``), and one loop over the lanes
runs a sample's screening and step for all of them. Every access is then a constant offset
from the lane, so the compiler vectorises that loop across sensors. The results are those
of ``contract.run_series`` bit for bit: each sensor gets the same arithmetic in the same
order (a vector lane rounds as a scalar does, and the libm calls stay scalar calls).

A method provides its ``contract`` functions in strided form: the row's slot j at
``st[o + j * lanes]``, output k at ``xa[xo + k * outs]``:

- ``start_at(st, o, lanes, coef, first, qw, qx, qy, qz)``;
- ``step_at(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, qa, qo,
  xa, xo, outs, steady)``, returning its flag bits;
- ``hold_at(st, o, lanes, coef, xa, xo, outs)``;
- ``rare_at(st, o, lanes, coef, dt, has_mag, a0, a1, a2, m0, m1, m2)``: whether this
  sample (as screened) takes a rare branch of the step (a call or a loop the vectoriser
  cannot take: Bachmann's heading set from the field, say). The vector pass calls
  ``step_at`` with the constant ``steady=True`` for the other lanes, so the step leaves
  those branches out of its code.

(Re)starts are rare (the first usable sample, after a gap) and call TRIAD: they, and the
rare steps, run in a scalar pass over the lanes that need them, after the vector pass,
with the sample as screened there, which is the order of ``contract._sample``.

Entry points using these must be compiled with ``error_model="numpy"``. Under numba's
default a float division checks its divisor and may raise: a branch the vectoriser cannot
take. The kernels guard every division they make, so no result depends on it.
"""

from __future__ import annotations

import numpy as np

from margtrack.kernels import contract, screen
from margtrack.kernels.contract import INITIALISING, K_Q, K_READY, K_SCREEN, K_STARTS
from margtrack.kernels.jit import njit

#: sensors per block: 4 AVX-512 vectors; a block's buffer (about 70 slots) stays in L1
LANES = 32
#: lanes per vector the block kernels are compiled for (``jit``'s ``vector_width``): 8
#: float64 in AVX-512; on a machine with narrower vectors LLVM splits them
VECTOR_WIDTH = 8

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
def _lane(step_at, rare_at, st, o, n_row, coef, scoef, dt, k_ref, tflags, has_mag, has_gyr):
    """One lane's sample (the vector pass): screen, then step unless it (re)starts or its
    step takes a rare branch (left to the scalar pass)."""
    lanes = LANES
    i_in = o + (n_row + B_GYR) * lanes
    f, g0, g1, g2, a0, a1, a2, m0, m1, m2 = screen.screen_at(
        scoef, st, o + K_SCREEN * lanes, lanes, dt, k_ref, tflags,
        st[i_in], st[i_in + lanes], st[i_in + 2 * lanes],
        st[i_in + 3 * lanes], st[i_in + 4 * lanes], st[i_in + 5 * lanes],
        st[i_in + 6 * lanes], st[i_in + 7 * lanes], st[i_in + 8 * lanes], has_mag, has_gyr,
    )
    st[i_in], st[i_in + lanes], st[i_in + 2 * lanes] = g0, g1, g2
    st[i_in + 3 * lanes], st[i_in + 4 * lanes], st[i_in + 5 * lanes] = a0, a1, a2
    st[i_in + 6 * lanes], st[i_in + 7 * lanes], st[i_in + 8 * lanes] = m0, m1, m2
    if tflags & screen.GAP:
        st[o + K_READY * lanes] = 0.0
    scalar = RESTART
    if st[o + K_READY * lanes] != 0.0:
        rare = rare_at(st, o, lanes, coef, dt, has_mag, a0, a1, a2, m0, m1, m2)
        scalar = STEP if rare else 0.0
    i_q = o + (n_row + B_Q) * lanes
    if scalar == 0.0:
        f |= step_at(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag,
                     st, i_q, st, o + (n_row + B_X) * lanes, lanes, True)
        # written out: a loop here, inside a branch, stops the vectoriser
        i_last = o + K_Q * lanes
        st[i_last], st[i_last + lanes] = st[i_q], st[i_q + lanes]
        st[i_last + 2 * lanes], st[i_last + 3 * lanes] = st[i_q + 2 * lanes], st[i_q + 3 * lanes]
    st[o + (n_row + B_FLAGS) * lanes] = f
    st[o + (n_row + B_SCALAR) * lanes] = scalar


@njit(cache=True, inline="always")
def _scalar(start_at, step_at, hold_at, st, o, n_row, coef, scoef, dt, has_mag):
    """The rest of a lane's sample when it (re)starts or its step takes a rare branch (the
    scalar pass; ``contract._sample``)."""
    lanes = LANES
    i_in = o + (n_row + B_GYR) * lanes
    g0, g1, g2 = st[i_in], st[i_in + lanes], st[i_in + 2 * lanes]
    a0, a1, a2 = st[i_in + 3 * lanes], st[i_in + 4 * lanes], st[i_in + 5 * lanes]
    m0, m1, m2 = st[i_in + 6 * lanes], st[i_in + 7 * lanes], st[i_in + 8 * lanes]
    i_q, i_x = o + (n_row + B_Q) * lanes, o + (n_row + B_X) * lanes
    i_f = o + (n_row + B_FLAGS) * lanes
    f = int(st[i_f])
    if st[o + (n_row + B_SCALAR) * lanes] == RESTART:
        ok, qw, qx, qy, qz = contract.initial(scoef, a0, a1, a2, m0, m1, m2)
        if not ok:
            for k in range(4):
                st[i_q + k * lanes] = st[o + (K_Q + k) * lanes]
            hold_at(st, o, lanes, coef, st, i_x, lanes)
            st[i_f] = f | INITIALISING
            return
        start_at(st, o, lanes, coef, st[o + K_STARTS * lanes] == 0.0, qw, qx, qy, qz)
        st[o + K_STARTS * lanes] += 1.0
        st[o + K_READY * lanes] = 1.0
        dt = 0.0  # the measured orientation is this sample's: nothing to integrate
    f |= step_at(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag,
                 st, i_q, st, i_x, lanes, False)
    for k in range(4):
        st[o + (K_Q + k) * lanes] = st[i_q + k * lanes]
    st[i_f] = f


@njit(cache=True, inline="always")
def block(start_at, step_at, hold_at, rare_at, n_row, n_x, st, rows, s0, scoef, coef, dts, ks,
          tflags, gyr, acc, mag, has, q_out, x_out, flags_out):
    """Sensors s0 .. s0 + LANES (fewer at the end) through all samples, in lockstep.

    ``st`` ((n_row + N_B + n_x) * LANES,) is the block's buffer, as scratch; ``n_row``,
    ``n_x`` the method's row and extra outputs widths (constants). For a kernel compiled
    with ``_nrt=False`` (numba's reference counting, kept otherwise around every array
    passed to an inlined function, is a call the vectoriser cannot take), by a method's
    entry point per block (:func:`run_blocks`). The coefficients come as tuples
    (``jit.to_fixed_tuple``, with the method's constant ``N_COEF``, in its entry point): read
    from an array, each is a pointer the vectorised loop must check at run time against the
    buffer it writes, and LLVM gives up beyond a few; a tuple is values.
    """
    has_mag, has_gyr = (has & 1) != 0, (has & 2) != 0
    lanes = LANES
    n = min(lanes, rows.shape[0] - s0)
    for lane in range(n):
        for j in range(n_row):
            st[j * lanes + lane] = rows[s0 + lane, j]
    i_in = (n_row + B_GYR) * lanes
    i_q, i_x, i_f = (n_row + B_Q) * lanes, (n_row + B_X) * lanes, (n_row + B_FLAGS) * lanes
    i_scalar = (n_row + B_SCALAR) * lanes
    for i in range(dts.shape[0]):
        dt, k_ref, tf = dts[i], ks[i], tflags[i]
        for lane in range(n):
            s = s0 + lane
            for c in range(3):
                st[i_in + c * lanes + lane] = gyr[s, i, c]
                st[i_in + (3 + c) * lanes + lane] = acc[s, i, c]
                st[i_in + (6 + c) * lanes + lane] = mag[s, i, c]
        for lane in range(n):  # vectorised across the lanes
            _lane(step_at, rare_at, st, lane, n_row, coef, scoef, dt, k_ref, tf, has_mag,
                  has_gyr)
        for lane in range(n):
            if st[i_scalar + lane] != 0.0:
                _scalar(start_at, step_at, hold_at, st, lane, n_row, coef, scoef, dt, has_mag)
        for lane in range(n):
            s = s0 + lane
            flags_out[s, i] = int(st[i_f + lane])
            for k in range(4):
                q_out[s, i, k] = st[i_q + k * lanes + lane]
            for k in range(x_out.shape[2]):  # at most n_x
                x_out[s, i, k] = st[i_x + k * lanes + lane]
    for lane in range(n):
        for j in range(n_row):
            rows[s0 + lane, j] = st[j * lanes + lane]


@njit(cache=True, inline="always")
def run_blocks(block_kernel, width, rows, clock, coefs, t, gyr, acc, mag, has, q_out, x_out,
               flags_out):
    """``contract.run_series`` (same arguments and results) by blocks of LANES sensors in
    lockstep: ``block_kernel(st, rows, s0, coefs, dts, ks, tflags, gyr, acc, mag, has, q_out,
    x_out, flags_out)`` the method's :func:`block`, ``width`` its slots per lane."""
    dts, ks, tflags = contract._clock_series(clock, coefs[screen.C_MAX_GAP], t)
    st = np.empty(width * LANES)
    for b in range((rows.shape[0] + LANES - 1) // LANES):
        block_kernel(st, rows, b * LANES, coefs, dts, ks, tflags, gyr, acc, mag, has, q_out,
                     x_out, flags_out)
