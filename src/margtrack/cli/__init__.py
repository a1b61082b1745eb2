"""The ``margtrack`` command line, thin over the API: one module per group of commands."""

from __future__ import annotations

import importlib

from margtrack.cli.app import app
from margtrack.cli.options import cli_unit_fix


def _mount_calibration() -> None:
    from margtrack.calibration.cli import calibrate_app

    app.add_typer(calibrate_app, name="calibrate", help="Calibrate a MARG sensor (000, 003).")


def _mount_live() -> None:
    from margtrack.live.cli import live_command

    app.command(
        name="live",
        help="Track sensors live in a browser page (simulator, replay, UDP, serial).",
    )(live_command)


# each module registers its commands on import, in the order `margtrack --help` lists them
COMMAND_MODULES = ("inspect", "simulate", "run", "evaluate", "experiment", "bench")
for _module in COMMAND_MODULES:
    importlib.import_module(f"margtrack.cli.{_module}")
_mount_live()
_mount_calibration()

__all__ = ["app", "cli_unit_fix"]
