"""A method's ``series`` (the per-sensor run) compiles without numba's reference counting:
no atomic count per array passed on per sample (``kernels/contract.series``)."""

from __future__ import annotations

import os
import re

import numba
import numpy as np
import pytest

from margtrack import methods
from margtrack.kernels import jit


def _own_body(llvm_ir: str, name: str) -> str:
    """The LLVM IR of the function whose mangled name contains ``name`` (its definition
    only: the module also holds the functions it calls)."""
    for match in re.finditer(r"^define [^\n]*@\"?([\w.$]+)\"?\(", llvm_ir, re.M):
        if name in match.group(1) and not match.group(1).startswith(("cpython", "cfunc")):
            return llvm_ir[match.start():llvm_ir.index("\n}\n", match.start())]
    raise LookupError(name)


@pytest.mark.kernel
@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"),
                    reason="numba's JIT is off: nothing is compiled")
@pytest.mark.parametrize("name", ["gyro", "bias-kf"])  # bias-kf: its start and partial
def test_series_counts_no_references_and_gives_the_cached_results(name):  # updates count
    """Compiled afresh (numba's cache keeps no IR): the series function itself calls no
    ``NRT_incref``/``NRT_decref`` (the functions it calls that make views of a row keep
    theirs, declared ``_nrt=True``), and gives the results of the cached kernel."""
    kernel = methods.get(name).kernel
    options = next(lazy.options for lazy in jit.kernels()
                   if kernel.series in (lazy, lazy.dispatcher))
    assert options.get("_nrt") is False
    fresh = jit._dispatcher(numba, jit.LazyKernel(
        kernel.series.py_func, {k: v for k, v in options.items() if k != "cache"}))
    est = methods.create(name)
    n = 400
    rng = np.random.default_rng(3)
    gyr = rng.normal(0.0, 0.5, (2, n, 3))
    acc = np.array([0.3, -0.2, 9.7]) + rng.normal(0.0, 0.2, (2, n, 3))
    mag = np.array([18.0, 2.0, -42.0]) + rng.normal(0.0, 0.5, (2, n, 3))
    acc[1, 100:120] = 0.0  # the screening's "no measurement": bias-kf's heading alone
    mag[0, 200:230] = 0.0  # no field: the tilt alone
    dts, ks, tflags = np.full(n, 0.01), np.full(n, 1e-4), np.zeros(n, np.int64)
    outs = []
    for f in (fresh, kernel.series):
        out = (np.zeros((2, n, 4)), np.zeros((2, n, est.run_width)), np.zeros((2, n), np.uint16))
        f(est._new_rows(2).rows, est._coefs, dts, ks, tflags, gyr, acc, mag, 3, *out)
        outs.append(out)
    for a, b in zip(*outs, strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.isfinite(outs[0][0]).all()
    body = _own_body(fresh.inspect_llvm(fresh.signatures[0]), "series")
    assert "@NRT_incref(" not in body and "@NRT_decref(" not in body
