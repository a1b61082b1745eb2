"""The ``margtrack`` Typer application, its consoles and its one error handler."""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

# Typer validates options with pydantic, whose plugin lookup scans every installed package's
# entry points (20 ms per process); margtrack's CLI uses no pydantic plugin. A user's own
# setting wins.
os.environ.setdefault("PYDANTIC_DISABLE_PLUGINS", "__all__")

import typer
from rich.console import Console
from rich.markup import escape

app = typer.Typer(
    name="margtrack",
    help="Orientation tracking with MARG sensors (gyroscope, accelerometer, magnetometer).",
    no_args_is_help=True,
    add_completion=False,
)
console = Console()
err_console = Console(stderr=True)

F = TypeVar("F", bound=Callable[..., Any])


def friendly_errors(func: F) -> F:
    """Turn input errors into a one-line message and exit code 2 instead of a traceback."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (ValueError, FileNotFoundError, KeyError, OSError) as exc:
            err_console.print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)
            raise typer.Exit(code=2) from None

    return wrapper  # type: ignore[return-value]


@contextlib.contextmanager
def progress_bar(label: str) -> Iterator[Callable[[int, int | None], None] | None]:
    """A transient progress bar on standard error when it is a terminal: yields its
    ``update(done, total)``; yields None in pipes and logs (and loads nothing for it)."""
    if not err_console.is_terminal:
        yield None
        return
    from rich.progress import Progress

    with Progress(console=err_console, transient=True) as bar:
        task = bar.add_task(label, total=None)
        yield lambda done, total: bar.update(task, completed=done, total=total)


def warn(text: str) -> None:
    """Print a one-line warning on standard error."""
    err_console.print(f"[yellow]warning:[/] {escape(text)}", soft_wrap=True)
