"""An 8 x 8 tile of float64 transposed with vector shuffles (``jit.transpose8``).

``transpose8(src, src_off, src_stride, dst, dst_off, dst_stride)`` sets, for i, k < 8::

    dst.flat[dst_off + k * dst_stride + i] = src.flat[src_off + i * src_stride + k]

``src`` and ``dst`` C-contiguous float64 arrays of any dimension, offsets and strides in
elements of their flat data. The lockstep blocks (``contract_lanes``) move each sensor's
state row into their interleaved buffer and back once a batch; in the live engine's small
batches that was a fifth of the kernel's time, the compiler's scalar loads and stores
about 1.5 times a plain copy. Compiled, it is eight vector loads, the transpose in three
rounds of shuffles (pairs of elements, pairs of pairs, halves) and eight vector stores,
which LLVM maps to the machine's widest vectors. The values are moved, never computed:
the result is the same bits as an element loop (:func:`transpose8_python`, what kernels
run when numba's JIT is off).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["transpose8_compiled", "transpose8_python"]


def transpose8_python(src: np.ndarray, src_off: int, src_stride: int, dst: np.ndarray,
                      dst_off: int, dst_stride: int) -> None:
    """:func:`transpose8` as an element loop (module docstring)."""
    source, target = src.reshape(-1), dst.reshape(-1)
    for i in range(8):
        for k in range(8):
            target[dst_off + k * dst_stride + i] = source[src_off + i * src_stride + k]


def transpose8_compiled() -> Any:
    """The compiled ``transpose8``: an intrinsic in a function numba inlines (numba is
    imported here, when :mod:`margtrack.kernels.jit` loads it)."""
    import numba
    from llvmlite import ir
    from numba.core import types
    from numba.extending import intrinsic

    vector = ir.VectorType(ir.DoubleType(), 8)

    def mask(indices: list[int]) -> ir.Constant:
        return ir.Constant(ir.VectorType(ir.IntType(32), 8), indices)

    def c_float64(ty: Any) -> bool:
        return isinstance(ty, types.Array) and ty.dtype == types.float64 and ty.layout == "C"

    @intrinsic
    def transpose8_ir(typingctx: Any, src: Any, src_off: Any, src_stride: Any, dst: Any,
                      dst_off: Any, dst_stride: Any) -> Any:
        if not (c_float64(src) and c_float64(dst) and all(
                isinstance(t, types.Integer) for t in (src_off, src_stride, dst_off, dst_stride))):
            return None
        sig = types.void(src, src_off, src_stride, dst, dst_off, dst_stride)

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            def index(k: int) -> Any:
                return context.cast(builder, args[k], signature.args[k], types.intp)

            def pointers(k_array: int, k_off: int, k_stride: int) -> list[Any]:
                array = context.make_array(signature.args[k_array])(context, builder,
                                                                    args[k_array])
                off, stride = index(k_off), index(k_stride)
                out = []
                for r in range(8):
                    at = builder.add(off, builder.mul(stride, ir.Constant(off.type, r)))
                    out.append(builder.bitcast(builder.gep(array.data, [at]),
                                               vector.as_pointer()))
                return out

            rows = [builder.load(p, align=8) for p in pointers(0, 1, 2)]
            pairs = []  # (r0, r1) even and odd elements, then (r2, r3), ...
            for a in range(0, 8, 2):
                pairs.append(builder.shuffle_vector(rows[a], rows[a + 1],
                                                    mask([0, 8, 2, 10, 4, 12, 6, 14])))
                pairs.append(builder.shuffle_vector(rows[a], rows[a + 1],
                                                    mask([1, 9, 3, 11, 5, 13, 7, 15])))
            quads = [None] * 8
            for g in (0, 4):
                for p in (0, 1):
                    low, high = pairs[g + p], pairs[g + 2 + p]
                    quads[g + p] = builder.shuffle_vector(low, high,
                                                          mask([0, 1, 8, 9, 4, 5, 12, 13]))
                    quads[g + 2 + p] = builder.shuffle_vector(low, high,
                                                              mask([2, 3, 10, 11, 6, 7, 14, 15]))
            columns = [None] * 8
            for k in range(4):
                columns[k] = builder.shuffle_vector(quads[k], quads[k + 4],
                                                    mask([0, 1, 2, 3, 8, 9, 10, 11]))
                columns[k + 4] = builder.shuffle_vector(quads[k], quads[k + 4],
                                                        mask([4, 5, 6, 7, 12, 13, 14, 15]))
            for column, p in zip(columns, pointers(3, 4, 5), strict=True):
                builder.store(column, p, align=8)
            return context.get_dummy_value()

        return sig, codegen

    @numba.njit(inline="always")
    def transpose8(src: Any, src_off: int, src_stride: int, dst: Any, dst_off: int,
                   dst_stride: int) -> None:
        transpose8_ir(src, src_off, src_stride, dst, dst_off, dst_stride)

    return transpose8
