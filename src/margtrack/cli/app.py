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
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption


def unwrap(text: str | None) -> str | None:
    """A docstring's paragraphs each on one line (a sentence is never broken in ``--help``);
    list items (``- ``) and indented lines keep their own lines."""
    if not text:
        return text
    import inspect

    paragraphs = []
    for paragraph in inspect.cleandoc(text).split("\n\n"):
        lines: list[str] = []
        for line in paragraph.splitlines():
            if lines and not line.startswith(("- ", "* ", " ", "\b")):
                lines[-1] += " " + line.strip()
            else:
                lines.append(line)
        paragraphs.append("\n".join(lines))
    return "\n\n".join(paragraphs)


class _PlainArgument(TyperArgument):
    """An argument shown as its name in capitals (``PATHS...``), without a type column and
    without braces in the usage line."""

    def display_type_rich(self, ctx: Any) -> str | None:
        return None

    def _usage_display_name(self) -> str:
        name = self.display_name_raw
        return name if self.required else f"[{name}]"


#: typer's type labels (``<list[Path]>``) as people read them
_TYPE_WORDS = {"str": "TEXT", "path": "PATH", "Path": "PATH", "int": "INTEGER",
               "float": "FLOAT", "int range": "INTEGER", "float range": "FLOAT"}


class _PlainOption(TyperOption):
    """An option whose value is named as a word (PATH, TEXT, INTEGER) and a flag without
    one (not ``<bool>``)."""

    def display_type_rich(self, ctx: Any) -> str | None:
        if self.is_flag:
            return ""
        if self.metavar is not None:
            return self.metavar
        label = str(super().display_type_rich(ctx) or "")
        inner = label.strip("<>.").removeprefix("list[").removesuffix("]")
        return _TYPE_WORDS.get(inner, label)


def _plain_params(params: list[Any]) -> None:
    """The options and arguments of a command as :class:`_PlainOption` and
    :class:`_PlainArgument` (same objects, their help display changed)."""
    for param in params:
        if type(param) is TyperOption:
            param.__class__ = _PlainOption
        elif type(param) is TyperArgument:
            if param.metavar is None:
                param.metavar = str(param.name).upper() + ("..." if param.nargs != 1 else "")
            param.__class__ = _PlainArgument


class PlainHelpCommand(TyperCommand):
    """A command whose ``--help`` reads as prose: whole sentences, no Python types."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.help = unwrap(self.help)
        _plain_params(self.params)

    def get_help_option(self, ctx: Any) -> Any:
        option = super().get_help_option(ctx)
        if option is not None:
            _plain_params([option])
        return option


class PlainHelpGroup(TyperGroup):
    """A group whose ``--help`` reads as prose (:class:`PlainHelpCommand`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.help = unwrap(self.help)
        _plain_params(self.params)

    def get_help_option(self, ctx: Any) -> Any:
        option = super().get_help_option(ctx)
        if option is not None:
            _plain_params([option])
        return option


def plain_help(typer_app: typer.Typer) -> None:
    """Make every command and group of ``typer_app`` (recursively) show plain help, unless
    it chose its own class."""
    from typer.models import DefaultPlaceholder

    def unset(cls: object) -> bool:  # typer's own classes are its defaults
        return cls in (None, TyperCommand, TyperGroup) or isinstance(cls, DefaultPlaceholder)

    if unset(typer_app.info.cls):
        typer_app.info.cls = PlainHelpGroup
    for info in typer_app.registered_commands:
        if unset(info.cls):
            info.cls = PlainHelpCommand
    for group in typer_app.registered_groups:
        if group.typer_instance is not None:
            if unset(group.cls):
                group.cls = PlainHelpGroup
            plain_help(group.typer_instance)


app = typer.Typer(
    name="margtrack",
    help="Orientation tracking with MARG sensors (gyroscope, accelerometer, magnetometer).",
    no_args_is_help=True,
    add_completion=False,
)
console = Console()
err_console = Console(stderr=True)

F = TypeVar("F", bound=Callable[..., Any])


def cli_message(exc: BaseException) -> str:
    """The message of ``exc`` as the command line says it: the Python fix of an error that
    carries one (``fix``: :class:`~margtrack.errors.InputError`,
    :class:`~margtrack.units.UnitError`), on ``exc`` or on the errors it was raised from,
    replaced by the command line's (an option, a command)."""
    from margtrack.cli.options import cli_unit_fix
    from margtrack.units import UnitError

    text = str(exc)
    seen: BaseException | None = exc
    for _ in range(8):  # the error and the ones it was raised from (``__context__``)
        if seen is None:
            break
        fix = getattr(seen, "fix", "")
        if isinstance(fix, str) and fix and fix in text:
            if isinstance(seen, UnitError):
                text = text.replace(fix, cli_unit_fix(seen.signal, seen.suspected))
            elif isinstance(getattr(seen, "cli_fix", None), str):
                text = text.replace(fix, seen.cli_fix)  # type: ignore[attr-defined]
        seen = seen.__cause__ or seen.__context__
    return text


def friendly_errors(func: F) -> F:
    """Turn input errors into a one-line message and exit code 2 instead of a traceback;
    the message names the command line's fix (:func:`cli_message`)."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (ValueError, FileNotFoundError, KeyError, OSError) as exc:
            err_console.print(f"[bold red]error:[/] {escape(cli_message(exc))}", soft_wrap=True)
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
