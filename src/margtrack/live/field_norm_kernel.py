"""Kernel of the live sensors' reference field norms (:mod:`margtrack.live.field_norm`)."""

from __future__ import annotations

import math

from margtrack.estimator.jit import njit

__all__ = ["feed_norms"]


@njit(cache=True, inline="always")
def _median_in_place(values):
    """The median of an odd number of values, sorting them in place (insertion sort: for
    15 values per sensor, numba's ``ndarray.sort`` took 48 ms for 118,125 sensors against
    18, ``np.median`` 35)."""
    for i in range(1, values.shape[0]):
        v = values[i]
        j = i - 1
        while j >= 0 and values[j] > v:
            values[j + 1] = values[j]
            j -= 1
        values[j + 1] = v
    return values[values.shape[0] // 2]


@njit(cache=True, nogil=True)
def feed_norms(t_s, mag, spacing_s, norms, count, due_s, ref):
    """One batch into the sensors' norm samples; returns how many sensors still lack a
    reference.

    t_s (N,) data time, s; mag (S, N, 3) the field, any unit (any strides: frame-major
    batches as sources deliver them); norms (S, K) each sensor's samples so far (K odd),
    count (S,) how many, due_s (S,) the time of its next one, ref (S,) its reference norm
    (NaN until K samples are in: then their median): all in/out. A sample is a finite,
    non-zero norm at or after the sensor's due time; the next is due ``spacing_s`` later.
    """
    k_ref = norms.shape[1]
    left = 0
    for s in range(mag.shape[0]):
        c = count[s]
        if c >= k_ref:
            continue
        for j in range(t_s.shape[0]):
            if not t_s[j] >= due_s[s]:
                continue
            m0, m1, m2 = mag[s, j, 0], mag[s, j, 1], mag[s, j, 2]
            norm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
            if not (norm > 0.0 and norm < math.inf):
                continue
            norms[s, c] = norm
            c += 1
            due_s[s] = t_s[j] + spacing_s
            if c == k_ref:
                ref[s] = _median_in_place(norms[s])
                break
        count[s] = c
        left += c < k_ref
    return left
