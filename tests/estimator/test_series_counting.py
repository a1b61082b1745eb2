"""A method's ``series`` (the per-sensor run) compiles without numba's reference counting:
no atomic count per array passed on per sample (``kernels/contract.series``)."""

from __future__ import annotations

import os
import re

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
@pytest.mark.parametrize("name", ["gyro", "bias-kf"])
def test_series_counts_no_references(name):  # bias-kf: its start and partial updates count
    """The series function itself calls no ``NRT_incref``/``NRT_decref`` (the functions it
    calls that make views of a row keep theirs, declared ``_nrt=True``): the optimised IR of
    the kernel as the cache holds it (``jit.compiled_ir``; nothing is compiled again), after
    a call with the argument types ``run`` gives it, on samples that take every branch."""
    kernel = methods.get(name).kernel
    options = next(lazy.options for lazy in jit.kernels()
                   if kernel.series in (lazy, lazy.dispatcher))
    assert options.get("_nrt") is False
    est = methods.create(name)
    n = 400
    rng = np.random.default_rng(3)
    gyr = rng.normal(0.0, 0.5, (2, n, 3))
    acc = np.array([0.3, -0.2, 9.7]) + rng.normal(0.0, 0.2, (2, n, 3))
    mag = np.array([18.0, 2.0, -42.0]) + rng.normal(0.0, 0.5, (2, n, 3))
    acc[1, 100:120] = 0.0  # the screening's "no measurement": bias-kf's heading alone
    mag[0, 200:230] = 0.0  # no field: the tilt alone
    for a in (gyr, acc, mag):
        a.flags.writeable = False  # as run passes them: the signature it compiled
    dts, ks, tflags = np.full(n, 0.01), np.full(n, 1e-4), np.zeros(n, np.int64)
    q = np.zeros((2, n, 4))
    kernel.series(est._new_rows(2).rows, est._coefs, dts, ks, tflags, gyr, acc, mag, 3, q,
                  np.zeros((2, n, est.run_width)), np.zeros((2, n), np.uint16))
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    body = _own_body(jit.compiled_ir(kernel.series), "series")
    assert "@NRT_incref(" not in body and "@NRT_decref(" not in body
