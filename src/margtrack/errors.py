"""Input errors whose fix reads differently in Python and on the command line.

A library error names the Python fix (``read_xio_body(path)``); the ``margtrack`` command
names a command or an option instead (``margtrack body FOLDER -o OUT/``). Such an error
carries both: :class:`InputError` (a ``ValueError``) keeps the Python wording in its
message, the sentence of the message that gives the fix as ``fix`` and the command line's
sentence as ``cli_fix``. Wrappers that put a path or a sensor in front of the message keep
the sentence, so the command's error handler (:func:`margtrack.cli.app.cli_message`) swaps
it, on the error it catches or on the one that error was raised from (``__context__``).
:class:`~margtrack.units.UnitError` works the same way, its command-line fix being the unit
option (``--time-unit ms``).
"""

from __future__ import annotations

from typing import TypeVar

__all__ = ["InputError", "NoRecordingError", "with_cli_fix"]

X = TypeVar("X", bound=BaseException)


class InputError(ValueError):
    """A ``ValueError`` for input the caller must fix, the fix in both spellings.

    Parameters
    ----------
    message : the whole message, Python's wording; it contains ``fix``.
    fix : the part of ``message`` that says how to fix it in Python ("" if none).
    cli_fix : what the command line says instead of ``fix`` ("" drops it).
    """

    def __init__(self, message: str, *, fix: str = "", cli_fix: str = "") -> None:
        super().__init__(message)
        self.fix = fix
        self.cli_fix = cli_fix


class NoRecordingError(InputError):
    """A path that holds no recording margtrack reads (an empty folder, a folder of several
    recordings): a command that takes folders of its own kind says what they must hold."""


def with_cli_fix(exc: X, fix: str, cli_fix: str) -> X:
    """``exc`` (of any type: a ``FileExistsError`` stays one) carrying the two spellings of
    its fix as :class:`InputError` does."""
    exc.fix = fix  # type: ignore[attr-defined]
    exc.cli_fix = cli_fix  # type: ignore[attr-defined]
    return exc
