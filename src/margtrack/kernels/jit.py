"""numba's ``njit``, ``literally``, ``to_fixed_tuple``, and ``select``; numba imported when a
kernel first runs.

Kernel modules take ``njit``, ``literally``, ``to_fixed_tuple`` and ``select`` from here
instead of from numba. Importing numba and loading its registries costs about half a second
in every new process, whatever the kernel, so a kernel defined here is a :class:`LazyKernel`
until it is first called from Python. That call

1. runs an ahead-of-time build of the kernel when one matches its argument types
   (:mod:`margtrack.kernels.aot`; numba is then never imported), or else
2. imports numba once and turns *every* kernel defined so far into a real numba dispatcher
   (same options, same ``cache=True`` files), rebinding the module globals that name a
   kernel, ``literally``, ``to_fixed_tuple`` or ``select``, so kernels calling kernels compile
   exactly as before. Kernels defined after that are numba dispatchers from the start.

The registry of kernels is process-wide by nature (numba's own dispatchers are too).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from typing import Any

__all__ = [
    "LazyKernel", "compiled_ir", "dispatcher", "kernels", "literally", "njit", "numba_loaded",
    "on_numba_load", "resolve_all", "select", "to_fixed_tuple", "transpose8",
]


class _LiterallyPlaceholder:
    """Stands for ``numba.literally`` in kernel modules until numba is imported."""

    def __call__(self, value: Any) -> Any:  # pure Python use, as numba.literally does
        return value

    def __repr__(self) -> str:
        return "literally (numba not imported yet)"


class _ToFixedTuplePlaceholder:
    """Stands for ``numba.np.unsafe.ndarray.to_fixed_tuple`` until numba is imported."""

    def __call__(self, array: Any, length: int) -> tuple[Any, ...]:  # pure Python use
        return tuple(array[:length])

    def __repr__(self) -> str:
        return "to_fixed_tuple (numba not imported yet)"


class _SelectPlaceholder:
    """Stands for :func:`_select_intrinsic`'s ``select`` until numba is imported."""

    def __call__(self, cond: bool, if_true: float, if_false: float) -> float:  # pure Python
        return if_true if cond else if_false

    def __repr__(self) -> str:
        return "select (numba not imported yet)"


class _Transpose8Placeholder:
    """Stands for ``transpose8`` (:mod:`margtrack.kernels.transpose`) until numba is imported."""

    def __call__(self, *args: Any) -> None:  # pure Python use (numba's JIT off)
        from margtrack.kernels.transpose import transpose8_python

        transpose8_python(*args)

    def __repr__(self) -> str:
        return "transpose8 (numba not imported yet)"


#: ``literally(n)`` in a kernel compiles it once per constant value of n at its call sites
#: (numba's literal dispatch): a size fixed at compile time without inlining the kernel
literally: Any = _LiterallyPlaceholder()
#: ``to_fixed_tuple(array, n)``, n a constant: the first n values as a tuple, which the
#: compiler keeps in registers (a vectorised loop need not check it against the arrays
#: it writes, as it must an array's memory)
to_fixed_tuple: Any = _ToFixedTuplePlaceholder()
#: ``select(cond, if_true, if_false)``: ``if_true if cond else if_false`` for float64 values,
#: compiled to one LLVM ``select``, not a branch. ``st[i] = select(ok, x, st[i])`` is then a
#: store whatever ``ok``; written as a branch, LLVM drops the store of the value just
#: loaded, and the store left in a branch is a masked store when vectorised (slow on AMD)
select: Any = _SelectPlaceholder()
#: ``transpose8(src, src_off, src_stride, dst, dst_off, dst_stride)``: an 8 x 8 tile of
#: float64 transposed by vector shuffles (:mod:`margtrack.kernels.transpose`)
transpose8: Any = _Transpose8Placeholder()

_KERNELS: list[LazyKernel] = []  # every kernel defined, numba's or not yet
_ON_LOAD: list[Callable[[], None]] = []
_NUMBA: Any = None
_LOCK = threading.Lock()


class LazyKernel:
    """A kernel not compiled yet: a Python function and its ``njit`` options.

    Calling it runs the ahead-of-time build or the numba dispatcher (see the module's
    docstring); any other attribute (``signatures``, ``inspect_llvm`` ...) is the numba
    dispatcher's. ``py_func`` is the Python function, as on a dispatcher.
    """

    def __init__(self, py_func: Callable[..., Any], options: dict[str, Any]) -> None:
        self.py_func = py_func
        self.options = options
        self.dispatcher: Any = None
        self.__doc__ = py_func.__doc__
        self.__name__ = py_func.__name__
        self.__qualname__ = py_func.__qualname__
        self.__module__ = py_func.__module__
        self.__wrapped__ = py_func

    @property
    def key(self) -> str:
        """``module:qualname``, the kernel's name in ahead-of-time builds."""
        return f"{self.py_func.__module__}:{self.py_func.__qualname__}"

    def __call__(self, *args: Any) -> Any:
        if self.dispatcher is not None:
            return self.dispatcher(*args)
        if not self.options.get("parallel"):
            from margtrack.kernels import aot

            compiled = aot.find(self, args)
            if compiled is not None:
                return compiled(*args)
        dispatcher = self.resolve()
        return dispatcher(*(a.resolve() if isinstance(a, LazyKernel) else a for a in args))

    def resolve(self) -> Any:
        """The numba dispatcher (numba is imported on the first call in a process)."""
        if self.dispatcher is None:
            resolve_all()
        return self.dispatcher

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.resolve(), name)

    def __repr__(self) -> str:
        state = "compiled" if self.dispatcher is not None else "not compiled yet"
        return f"<kernel {self.key} ({state})>"


def njit(*args: Any, **options: Any) -> Any:
    """``numba.njit`` for kernel modules: ``@njit(cache=True, ...)`` or ``@njit``.

    One option is margtrack's own: ``vector_width=n`` compiles the kernel with LLVM's loop
    vectoriser made to use n lanes (:func:`_force_vector_width`).
    """
    if args and callable(args[0]) and not options:
        return njit()(args[0])

    def decorate(func: Callable[..., Any]) -> Any:
        kernel = LazyKernel(func, options)
        _KERNELS.append(kernel)
        if _NUMBA is not None:
            kernel.dispatcher = _dispatcher(_NUMBA, kernel)
            return kernel.dispatcher
        return kernel

    return decorate


def _dispatcher(numba: Any, kernel: LazyKernel) -> Any:
    """The numba dispatcher of a kernel; its option ``vector_width`` is margtrack's own:
    :func:`_force_vector_width`."""
    options = dict(kernel.options)
    width = options.pop("vector_width", None)
    dispatcher = numba.njit(**options)(kernel.py_func)
    if width and hasattr(dispatcher, "compile"):  # not under NUMBA_DISABLE_JIT
        _force_vector_width(dispatcher, int(width))
    return dispatcher


_FORCED: list[int] = []  # the vector widths of the forced compilations in progress


def _force_vector_width(dispatcher: Any, width: int) -> None:
    """Compile ``dispatcher`` with LLVM's loop vectoriser made to use ``width`` lanes.

    For a kernel whose loop over sensors is written to vectorise (``contract_lanes``) but
    that LLVM's cost model leaves scalar (it prices the scalar libm calls and the masked
    stores of a long if-converted body too high): vectorised at 8 lanes it ran 2x faster,
    with the same results, since a vector lane rounds as a scalar does. The option is
    process-wide in LLVM, so it is set for this compilation only (numba compiles under one
    lock) and restored after; a kernel loaded from numba's cache compiles nothing.
    """
    from llvmlite import binding

    compile_ = dispatcher.compile

    def compile_forced(sig: Any) -> Any:
        _FORCED.append(width)
        binding.set_option("margtrack", f"-force-vector-width={width}")
        try:
            with _remarks_dropped():
                return compile_(sig)
        finally:
            _FORCED.pop()
            restore = _FORCED[-1] if _FORCED else 0
            binding.set_option("margtrack", f"-force-vector-width={restore}")

    dispatcher.compile = compile_forced


@contextlib.contextmanager
def _remarks_dropped() -> Iterator[None]:
    """With a forced width LLVM prints a remark on stderr for every loop it could not
    vectorise (the kernel's copy loops, say): noise to a user. stderr (the file descriptor,
    where LLVM writes) goes to a file meanwhile; what is not such a remark is written back."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            caught.seek(0)
            kept = [line for line in caught.read().decode(errors="replace").splitlines(True)
                    if not line.startswith("remark: ")]
            if kept:
                sys.stderr.write("".join(kept))


def numba_loaded() -> bool:
    """Whether this process has made its kernels numba dispatchers."""
    return _NUMBA is not None


def on_numba_load(callback: Callable[[], None]) -> Callable[[], None]:
    """Call ``callback`` right after numba is imported, before anything compiles.

    Called at once when numba is imported already (by the kernels or by anything else).
    Returns a function that removes it.
    """
    if _NUMBA is not None or "numba" in sys.modules:
        callback()
        return lambda: None
    _ON_LOAD.append(callback)

    def remove() -> None:
        if callback in _ON_LOAD:
            _ON_LOAD.remove(callback)

    return remove


def dispatcher(kernel: Any) -> Any:
    """The numba dispatcher of ``kernel`` (a :class:`LazyKernel` or already a dispatcher),
    numba imported if it is not yet: for calls that must not go to an ahead-of-time build
    (which holds the GIL)."""
    return kernel.resolve() if isinstance(kernel, LazyKernel) else kernel


def compiled_ir(kernel: Any) -> str:
    """The optimised LLVM IR of every compiled signature of ``kernel`` (a dispatcher or a
    lazy kernel), also when numba loaded it from its cache.

    numba's ``inspect_llvm`` refuses a kernel loaded from the cache; the cache entry keeps
    the optimised module beside the machine code (to link it into kernels that call it),
    and that module is returned here. For tests and diagnostics: which loops vectorised,
    which stores are masked, without compiling a kernel a second time.
    """
    found = dispatcher(kernel)
    # numba's CodeLibrary: the final module, marked for linking (numba 0.59-0.68)
    return "\n".join(str(found.overloads[sig].library._get_module_for_linking())
                     for sig in found.signatures)


def resolve_all() -> None:
    """Import numba and make every kernel defined so far a numba dispatcher."""
    global _NUMBA
    with _LOCK:
        if _NUMBA is not None:
            return
        import numba

        from margtrack.kernels.transpose import transpose8_compiled

        for callback in list(_ON_LOAD):
            callback()
        real = {id(k): _dispatcher(numba, k) for k in _KERNELS}
        # every global names its dispatcher before any kernel can run (and compile) through
        # numba, also when another thread calls a kernel meanwhile
        from numba.np.unsafe.ndarray import to_fixed_tuple as real_to_fixed_tuple

        placeholders = {
            _LiterallyPlaceholder: numba.literally,
            _ToFixedTuplePlaceholder: real_to_fixed_tuple,
            _SelectPlaceholder: _select_intrinsic(),
            _Transpose8Placeholder: transpose8_compiled(),
        }
        if numba.config.DISABLE_JIT:  # the kernels run as Python: numba's intrinsics cannot
            del placeholders[_ToFixedTuplePlaceholder]
            del placeholders[_SelectPlaceholder]
            del placeholders[_Transpose8Placeholder]
        _rebind(real, placeholders)
        for kernel in _KERNELS:
            kernel.dispatcher = real[id(kernel)]
        _NUMBA = numba


def _select_intrinsic() -> Any:
    """``select`` compiled: LLVM's ``select`` of two float64 values (an intrinsic, in a
    function numba inlines, so Python can call it too)."""
    import numba
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

    @numba.njit(inline="always")
    def select(cond: bool, if_true: float, if_false: float) -> float:
        return select_ir(cond, if_true, if_false)

    return select


def kernels() -> list[LazyKernel]:
    """Every kernel defined in this process (``dispatcher`` set once numba is loaded)."""
    return list(_KERNELS)


def _rebind(real: dict[int, Any], placeholders: dict[type, Any]) -> None:
    """Point every module global naming a kernel (or a placeholder: ``literally``,
    ``to_fixed_tuple``, ``select``, ``transpose8``) at the real object."""
    for module in list(sys.modules.values()):
        names = getattr(module, "__dict__", None)
        if not isinstance(names, dict):
            continue
        for name, value in list(names.items()):
            if isinstance(value, LazyKernel) and id(value) in real:
                names[name] = real[id(value)]
            elif type(value) in placeholders:
                names[name] = placeholders[type(value)]


@njit(cache=True, inline="always")
def keep(st, i, live, value, lanes):
    """``st[i] = value`` if ``live``, in a row strided by ``lanes`` (a constant). In lockstep
    (``lanes > 1``) a store of the new or the old value whatever ``live`` (:data:`select`):
    a store in a branch is a masked store across lanes, slow on AMD's cores. One sensor
    alone keeps the branch, which its serial chain runs faster (selects there cost 3-6 % of
    a method's time on one stream)."""
    if lanes > 1:
        st[i] = select(live, value, st[i])
    elif live:
        st[i] = value


if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
    # numba's JIT switched off: kernels are their Python functions; nothing to defer
    resolve_all()
