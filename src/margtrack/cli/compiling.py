"""A notice while numba compiles kernels: a spinner on a terminal, one line otherwise.

numba compiles a ``@njit(cache=True)`` kernel on its first call when no valid cache entry
exists (first run, new numba, edited source); later runs load it in milliseconds. numba
raises its ``"numba:compile"`` event only around a real compilation, never for a cache
hit, so listening to it is an exact cold-cache test with nothing to guess.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from margtrack.kernels import jit

if TYPE_CHECKING:  # pragma: no cover
    from rich.console import Console
    from rich.status import Status

__all__ = ["MESSAGE", "CompileNotice", "compile_notice"]

MESSAGE = "compiling kernels (first run only)"


class CompileNotice:
    """Listener of numba's ``"numba:compile"`` events that keeps a notice up while they run.

    ``kernels`` lists the compiled functions (``module.function``) in order; nested
    compilations (a kernel calling another) count once through ``depth``.
    """

    def __init__(self, console: Console) -> None:
        self.console = console
        self.kernels: list[str] = []
        self.depth = 0
        self._status: Status | None = None
        self._told = False

    def on_start(self, event: Any) -> None:
        """A compilation began: start (or update) the notice."""
        name = _kernel_name(event)
        self.kernels.append(name)
        self.depth += 1
        text = f"{MESSAGE}: {name}"
        if not self.console.is_terminal:
            if not self._told:  # a log or a pipe gets one plain line, not an animation
                self.console.print(f"{MESSAGE}...", soft_wrap=True)
                self._told = True
            return
        if self._status is None:
            self._status = self.console.status(text, spinner="dots")
            self._status.start()
        else:
            self._status.update(text)

    def on_end(self, event: Any) -> None:
        """A compilation ended: remove the notice when no other one is running."""
        self.depth = max(0, self.depth - 1)
        if self.depth == 0:
            self.stop()

    def stop(self) -> None:
        """Remove the spinner (nothing is left on the screen)."""
        if self._status is not None:
            self._status.stop()
            self._status = None


def _kernel_name(event: Any) -> str:
    data = getattr(event, "data", None) or {}
    func = getattr(data.get("dispatcher"), "py_func", None)
    if func is None:
        return "kernel"
    module = str(getattr(func, "__module__", "")).removeprefix("margtrack.kernels.")
    return f"{module}.{func.__qualname__}"


@contextmanager
def compile_notice(console: Console) -> Iterator[CompileNotice]:
    """Show :data:`MESSAGE` on ``console`` while numba compiles inside the block.

    On a terminal a spinner names the kernel being compiled and disappears when the
    compilation ends; elsewhere (a pipe, a log, a test runner) one line is printed the
    first time. Nothing at all is shown when every kernel comes from numba's cache.
    """
    notice = CompileNotice(console)
    listening = contextlib.ExitStack()

    def listen() -> None:  # numba is imported only when a kernel first runs through it
        from numba.core import event

        class _Listener(event.Listener):  # numba accepts only its own Listener subclasses
            def on_start(self, ev: Any) -> None:
                notice.on_start(ev)

            def on_end(self, ev: Any) -> None:
                notice.on_end(ev)

        listening.enter_context(event.install_listener("numba:compile", _Listener()))

    remove = jit.on_numba_load(listen)
    try:
        yield notice
    finally:
        remove()
        listening.close()
        notice.stop()


def with_compile_notice(func: Callable[..., Any], console: Console) -> Callable[..., Any]:
    """``func`` run inside :func:`compile_notice` (signature kept for Typer)."""
    import functools

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with compile_notice(console):
            return func(*args, **kwargs)

    wrapper.compile_notice = True  # type: ignore[attr-defined]  # marks a wrapped command
    return wrapper


#: shown while an ahead-of-time build compiles (``margtrack.kernels.aot``)
AOT_MESSAGE = "compiling kernels for a quick start next time (first run only)"


@contextmanager
def quick_start_build(console: Console) -> Iterator[None]:
    """After the block, build the kernels it ran through numba ahead of time.

    The next process running the same command then loads them in milliseconds instead of
    importing numba (``margtrack.kernels.aot``). Nothing happens when every kernel came from
    a build already, or with ``MARGTRACK_AOT=0``. A failed build (no C compiler, say) is
    reported once in a line and remembered, and changes nothing else.
    """
    from margtrack.kernels import aot

    if not aot.enabled():
        yield
        return
    with aot.recording() as recorded:
        yield
    if not recorded or not aot.worth_building(recorded):
        return
    # a line, not a spinner: numba's compile notice (a spinner on a terminal) shows the
    # kernels being built, and a console shows one live display at a time
    console.print(AOT_MESSAGE)
    try:
        aot.build(recorded)
    except Exception as exc:  # any build failure only costs start-up time
        aot.remember_failure(exc)
        console.print(
            f"[yellow]note:[/] the quick-start build failed ({type(exc).__name__}: {exc}); "
            "margtrack works as before and only starts slower. MARGTRACK_AOT=0 stops trying.",
            soft_wrap=True,
        )
