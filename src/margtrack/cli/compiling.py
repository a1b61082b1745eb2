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

if TYPE_CHECKING:  # pragma: no cover
    from rich.console import Console
    from rich.status import Status

__all__ = ["MESSAGE", "CompileNotice", "compile_notice"]

MESSAGE = "compiling kernels (first run only)"


class CompileNotice:
    """Listener of numba's ``"numba:compile"`` events that keeps a notice up while they run.

    ``kernels`` lists the compiled functions (``module.function``) in order; nested
    compilations (a kernel calling another) count once through ``depth``. ``stage`` names
    what a long command is doing (``"gradient (3 of 14)"``): a log gets one line per stage
    that compiles, a terminal's spinner shows it beside the kernel.
    """

    def __init__(self, console: Console) -> None:
        self.console = console
        self.kernels: list[str] = []
        self.depth = 0
        self.stage: str | None = None
        self._status: Status | None = None
        self._told: list[str | None] = []  # the stages a line was printed for

    def on_start(self, event: Any) -> None:
        """A compilation began: start (or update) the notice."""
        name = _kernel_name(event)
        self.kernels.append(name)
        self.depth += 1
        where = f"{self.stage}: " if self.stage else ""
        text = f"{MESSAGE}: {where}{name}"
        if not self.console.is_terminal:
            if self.stage not in self._told:  # a log or a pipe: a line, not an animation
                self.console.print(f"{MESSAGE}{': ' + self.stage if self.stage else ''}...",
                                   soft_wrap=True)
                self._told.append(self.stage)
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
    module = str(getattr(func, "__module__", "")).removeprefix("margtrack.")
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

    def listen() -> None:
        from numba.core import event

        class _Listener(event.Listener):  # numba accepts only its own Listener subclasses
            def on_start(self, ev: Any) -> None:
                notice.on_start(ev)

            def on_end(self, ev: Any) -> None:
                notice.on_end(ev)

        listening.enter_context(event.install_listener("numba:compile", _Listener()))

    listen()
    try:
        yield notice
    finally:
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
