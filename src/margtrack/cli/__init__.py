"""The ``margtrack`` command line, thin over the API: one module per group of commands.

Start-up stays short: the command modules import only typer and rich at module level
(each command imports what it uses when it runs), and the two commands with heavy
imports, ``calibrate`` (scipy.optimize) and ``live`` (viser, the body model), are mounted
lazily: ``margtrack --help`` lists them from a name and a line of help, and their modules
are imported only when one of them is the command being run.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

import click
import typer

from margtrack.cli.app import PlainHelpGroup, app, err_console, plain_help
from margtrack.cli.options import cli_unit_fix

__all__ = ["COMMAND_MODULES", "LAZY_COMMANDS", "app", "cli_unit_fix"]


def _calibrate_command() -> click.Command:
    from margtrack.cli.calibrate import calibrate_app

    plain_help(calibrate_app)
    return typer.main.get_command(calibrate_app)


def _live_command() -> click.Command:
    from margtrack.cli.compiling import with_compile_notice
    from margtrack.cli.live import live_command

    single = typer.Typer(add_completion=False)
    single.command(name="live", help=LAZY_COMMANDS["live"][0])(
        with_compile_notice(live_command, err_console)
    )
    plain_help(single)
    return typer.main.get_command(single)


#: commands imported only when run: name -> (one line of help, loader of the click command)
LAZY_COMMANDS: dict[str, tuple[str, Callable[[], click.Command]]] = {
    "live": (
        "Track sensors live in a browser page (simulator, replay, UDP, serial).",
        _live_command,
    ),
    "calibrate": ("Calibrate a MARG sensor (000, 003).", _calibrate_command),
}


class LazyGroup(PlainHelpGroup):
    """The top-level group: :data:`LAZY_COMMANDS` stay placeholders until one is run."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        for name, (text, _) in LAZY_COMMANDS.items():
            self.commands.setdefault(name, _Placeholder(name=name, help=text))

    def resolve_command(
        self, ctx: click.Context, args: list[str]
    ) -> tuple[str | None, click.Command | None, list[str]]:
        name = args[0] if args else None
        if name in LAZY_COMMANDS and isinstance(self.commands.get(name), _Placeholder):
            self.commands[name] = LAZY_COMMANDS[name][1]()
        return super().resolve_command(ctx, args)


class _Placeholder(click.Command):
    """A lazy command's entry in ``--help``: its name and help, nothing imported."""


# each module registers its commands on import, in the order `margtrack --help` lists them
COMMAND_MODULES = ("inspect", "simulate", "run", "evaluate", "experiment", "bench", "batch", "body",
                   "joint", "plot", "precompile")
for _module in COMMAND_MODULES:
    importlib.import_module(f"margtrack.cli.{_module}")

#: commands that run numba kernels: a notice shows while a kernel compiles (first run);
#: ``demo`` shows its own, naming each method as it compiles
COMPILING_COMMANDS = ("run", "evaluate", "tune", "experiment", "body", "bench", "plot",
                      "batch", "joint")


def _notice_compilation(typer_app: typer.Typer, names: tuple[str, ...] | None) -> None:
    """Wrap the named commands (all when None) of ``typer_app`` and its named groups."""
    from margtrack.cli.compiling import with_compile_notice

    for info in typer_app.registered_commands:
        callback = info.callback
        if callback is None:
            continue
        if names is None or (info.name or callback.__name__.replace("_", "-")) in names:
            info.callback = with_compile_notice(callback, err_console)
    for group in typer_app.registered_groups:
        if names is not None and group.name in names and group.typer_instance is not None:
            _notice_compilation(group.typer_instance, None)


_notice_compilation(app, COMPILING_COMMANDS)
plain_help(app)
app.info.cls = LazyGroup
app.info.epilog = (
    "The source papers 000-004 cited in help and outputs (\"000 eq. 5\") are listed in "
    "docs/papers.md; common mistakes (units, axes, frames, quaternion order) and their "
    "fixes in docs/faq.md."
)
