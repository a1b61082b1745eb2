"""Names of a package that load their module on first use (PEP 562).

A package lists ``name -> submodule`` and gets a module ``__getattr__`` and ``__dir__``:
``margtrack.methods.Robust`` imports ``margtrack.methods.robust`` only, so a command that
runs one method, reads one format or opens no viewer loads nothing else.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Mapping
from typing import Any

__all__ = ["lazy_names"]


def lazy_names(
    package: str, where: Mapping[str, str], eager: Iterable[str] = ()
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package``: ``where`` maps a name to its submodule.

    ``eager``: the names the package imports itself, listed by ``__dir__`` too.
    """
    listed = sorted(set(where) | set(eager))

    def get_attribute(name: str) -> Any:
        if name in where:
            return getattr(importlib.import_module(f"{package}.{where[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def list_names() -> list[str]:
        return listed

    return get_attribute, list_names
