"""``jit.select``: ``a if c else b`` as one LLVM ``select``, not a branch."""

from __future__ import annotations

import math

import numpy as np
import pytest

from margtrack.kernels import jit
from margtrack.kernels.jit import njit

VALUES = [0.0, -0.0, 1.5, -2.25, math.inf, -math.inf, math.nan, 5e-324]


@njit(cache=False)
def _selected(conds, a, b, out):
    for i in range(out.shape[0]):
        out[i] = jit.select(conds[i], a[i], b[i])


@pytest.mark.kernel
def test_select_is_the_ternary_bit_for_bit():
    """Every pair of special values, either way: the bits of ``a if c else b`` (signed
    zeros, infinities, nan, subnormals), compiled and as Python."""
    a = np.repeat(VALUES, len(VALUES) * 2)
    b = np.tile(np.repeat(VALUES, 2), len(VALUES))
    conds = np.tile([True, False], len(VALUES) ** 2)
    out = np.empty(a.size)
    _selected(conds, a, b, out)
    expected = np.where(conds, a, b)
    np.testing.assert_array_equal(out.view(np.int64), expected.view(np.int64))
    assert [jit.select(c, x, y) for c, x, y in [(True, 1.0, 2.0), (False, 1.0, 2.0)]] == [1.0, 2.0]
