"""numba's ``njit`` for margtrack's kernels, and the two small compiled helpers they share.

Kernel modules take ``njit``, ``literally``, ``to_fixed_tuple``, ``select`` and ``keep``
from here, so that running them as plain Python (``NUMBA_DISABLE_JIT=1``, the kernels'
readable twin in the tests) needs no other switch: ``select`` is then a conditional
expression and ``to_fixed_tuple`` a slice.
"""

from __future__ import annotations

from typing import Any

import numba
from numba import literally, njit

__all__ = ["keep", "literally", "njit", "select", "to_fixed_tuple"]


def _select_compiled() -> Any:
    """``select`` compiled: LLVM's ``select`` of two float64 values (a numba intrinsic, in
    a function numba inlines, so Python can call it too)."""
    from numba.core import types
    from numba.extending import intrinsic

    @intrinsic
    def select_ir(typingctx: Any, cond: Any, if_true: Any, if_false: Any) -> Any:
        if not (isinstance(cond, types.Boolean) and isinstance(if_true, types.Number)
                and isinstance(if_false, types.Number)):
            return None

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            c = context.cast(builder, args[0], cond, types.boolean)
            a = context.cast(builder, args[1], if_true, types.float64)
            b = context.cast(builder, args[2], if_false, types.float64)
            return builder.select(c, a, b)

        return types.float64(cond, if_true, if_false), codegen

    @njit(inline="always")
    def select(cond: bool, if_true: float, if_false: float) -> float:
        return select_ir(cond, if_true, if_false)

    return select


def _select_python(cond: bool, if_true: float, if_false: float) -> float:
    return if_true if cond else if_false


def _to_fixed_tuple_python(array: Any, length: int) -> tuple[Any, ...]:
    return tuple(array[:length])


if numba.config.DISABLE_JIT:
    #: ``select(cond, if_true, if_false)``: ``if_true if cond else if_false``
    select: Any = _select_python
    #: ``to_fixed_tuple(array, n)``, n a constant: the first n values as a tuple
    to_fixed_tuple: Any = _to_fixed_tuple_python
else:
    #: ``select(cond, if_true, if_false)``: ``if_true if cond else if_false`` for float64
    #: values, compiled to one LLVM ``select``, not a branch, so that
    #: ``st[i] = select(ok, x, st[i])`` is a plain store in a loop vectorised across
    #: sensors (a store in a branch is a masked store there)
    select = _select_compiled()
    #: ``to_fixed_tuple(array, n)``, n a constant: the first n values as a tuple, which the
    #: compiler keeps in registers
    from numba.np.unsafe.ndarray import to_fixed_tuple


@njit(cache=True, inline="always")
def keep(st, i, live, value, lanes):
    """``st[i] = value`` if ``live``, in a row strided by ``lanes``. In lockstep
    (``lanes > 1``) a store of the new or the old value whatever ``live`` (:data:`select`);
    one sensor alone keeps the branch."""
    if lanes > 1:
        st[i] = select(live, value, st[i])
    elif live:
        st[i] = value
