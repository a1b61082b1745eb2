"""numba's ``njit`` for margtrack's kernels, and the two small compiled helpers they share.

Kernel modules take ``njit``, ``literally``, ``to_fixed_tuple``, ``select`` and ``keep``
from here, so that running them as plain Python (``NUMBA_DISABLE_JIT=1``, the kernels'
readable twin in the tests) needs no other switch: ``select`` is then a conditional
expression and ``to_fixed_tuple`` a slice.
"""

from __future__ import annotations

import os
import sys
import tempfile
import threading
from typing import Any

import numba
from numba import literally, njit
from numba.core import event as numba_event

__all__ = ["force_vector_width", "keep", "literally", "njit", "select", "to_fixed_tuple"]


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


#: the dispatchers compiled with a forced vector width, and that width
_FORCED: dict[int, int] = {}
_FORCED_LOCK = threading.Lock()


class _ForcedWidth(numba_event.Listener):
    """Sets LLVM's loop-vectoriser width while numba compiles one of :data:`_FORCED`
    (numba's ``"numba:compile"`` event, raised in the compiling thread under numba's
    compile lock) and restores it after; LLVM's remarks on the loops it then cannot
    vectorise (stderr) are dropped meanwhile."""

    def __init__(self) -> None:
        self._saved: list[int] = []

    def on_start(self, event: Any) -> None:
        dispatcher = (event.data or {}).get("dispatcher")
        width = _FORCED.get(id(dispatcher))
        self._saved.append(-1 if width is None else os.dup(2))
        if width is None:
            return
        from llvmlite import binding

        sys.stderr.flush()
        self._caught = tempfile.TemporaryFile()
        os.dup2(self._caught.fileno(), 2)
        binding.set_option("margtrack", f"-force-vector-width={width}")

    def on_end(self, event: Any) -> None:
        saved = self._saved.pop()
        if saved < 0:
            return
        from llvmlite import binding

        binding.set_option("margtrack", "-force-vector-width=0")
        os.dup2(saved, 2)
        os.close(saved)
        self._caught.seek(0)
        kept = [line for line in self._caught.read().decode(errors="replace").splitlines(True)
                if not line.startswith("remark: ")]
        self._caught.close()
        if kept:
            sys.stderr.write("".join(kept))


def force_vector_width(dispatcher: Any, width: int) -> Any:
    """Compile ``dispatcher`` with LLVM's loop vectoriser made to use ``width`` lanes.

    For a loop over sensors written to vectorise (the lockstep blocks) that LLVM's cost
    model leaves scalar, pricing the long if-converted body too high: Bachmann's blocks
    run 1.3 times faster so, with the same results (a vector lane rounds as a scalar does).
    The option is LLVM's, process-wide, so it is set only while numba compiles this
    dispatcher and restored after (a kernel loaded from numba's cache compiles nothing).
    Returns the dispatcher.
    """
    if numba.config.DISABLE_JIT:
        return dispatcher
    with _FORCED_LOCK:
        if not _FORCED:
            numba_event.register("numba:compile", _ForcedWidth())
        _FORCED[id(dispatcher)] = width
    return dispatcher
