"""``jit.select``: ``a if c else b`` as one LLVM ``select``, not a branch."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from margtrack.estimator import jit
from margtrack.estimator.jit import njit

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


@pytest.mark.skipif(numba.config.DISABLE_JIT,
                    reason="numba's JIT is off: nothing is compiled, so no option to set")
def test_forced_vector_width_is_set_only_while_its_kernel_compiles(monkeypatch, capfd):
    """The LLVM option is process-wide: it is set for the forced kernel's compilation and
    reset right after, never for another kernel; LLVM's remarks do not reach the user."""
    from llvmlite import binding

    calls = []
    real = binding.set_option
    monkeypatch.setattr(binding, "set_option", lambda *a: calls.append(a) or real(*a))

    @njit(cache=False)
    def plain(a):
        return a.sum()

    def scaled(a, out):
        for i in range(a.shape[0]):
            out[i] = 2.0 * a[i] if a[i] > 0.0 else a[i]

    forced = jit.force_vector_width(njit(cache=False)(scaled), 8)
    a, out = np.linspace(-1.0, 1.0, 33), np.empty(33)
    assert plain(a) == pytest.approx(0.0, abs=1e-12)
    assert calls == []  # another kernel compiles as numba would
    forced(a, out)
    np.testing.assert_array_equal(out, np.where(a > 0.0, 2.0 * a, a))
    assert calls == [("margtrack", "-force-vector-width=8"), ("margtrack", "-force-vector-width=0")]
    forced(a, out)  # compiled: nothing set again
    assert len(calls) == 2
    assert "remark" not in capfd.readouterr().err
