"""The 8 x 8 tile transpose (kernels.transpose) and the lockstep blocks' row moves built on it
equal numpy's transposes, compiled and as Python."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack.kernels.contract_lanes import LANES, _rows_in, _rows_out
from margtrack.kernels.transpose import transpose8_python


def test_transpose8_python_equals_numpy_on_offset_strided_tiles():
    rng = np.random.default_rng(3)
    src, dst = rng.normal(size=(20, 13)), np.full(400, np.nan)
    transpose8_python(src, 2 * 13 + 4, 13, dst, 7, 40)  # rows 2-9, columns 4-11
    want = src[2:10, 4:12].T  # dst[7 + k * 40 + i] = src[2 + i, 4 + k]
    for k in range(8):
        np.testing.assert_array_equal(dst[7 + k * 40: 7 + k * 40 + 8], want[k])
    untouched = np.ones(400, bool)
    for k in range(8):
        untouched[7 + k * 40: 15 + k * 40] = False
    assert np.isnan(dst[untouched]).all()


@pytest.mark.parametrize("n_row", [69, 8, 5, 17, 64])
@pytest.mark.parametrize("n", [LANES, 7])
def test_rows_in_and_out_equal_numpy_transposes(n_row, n):
    """A full block by tiles (8 x 8 shuffles and the scalar tail), a partial one by
    scalar loops: the interleaved buffer is the rows' transpose, and back is the identity,
    to the bit (NaN and signed zeros included)."""
    rng = np.random.default_rng(n_row)
    rows = rng.normal(size=(3 * LANES, n_row))
    rows[5, 0], rows[40, n_row - 1], rows[33, 0] = np.nan, -0.0, np.inf
    s0 = LANES if n == LANES else 2 * LANES + 3
    st = np.full(n_row * LANES + 16, 7.0)
    _rows_in(rows, s0, n, n_row, st)
    got = st[: n_row * LANES].reshape(n_row, LANES)[:, :n]
    want = rows[s0: s0 + n].T
    np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))
    assert (st[n_row * LANES:] == 7.0).all()  # nothing written past the slots
    st[: n_row * LANES] = rng.normal(size=n_row * LANES)
    before = rows.copy()
    _rows_out(rows, s0, n, n_row, st)
    np.testing.assert_array_equal(
        rows[s0: s0 + n].view(np.int64),
        st[: n_row * LANES].reshape(n_row, LANES)[:, :n].T.copy().view(np.int64))
    outside = np.ones(rows.shape[0], bool)
    outside[s0: s0 + n] = False
    np.testing.assert_array_equal(rows[outside].view(np.int64), before[outside].view(np.int64))
