"""The declared tuning grid of each method (its registry record's): the parameters whose
defaults were chosen on BROAD.

A method's figures on BROAD are in-sample when its defaults were picked on the same 16
trials; :mod:`margtrack.bench.cv` measures how much of that is fitting by choosing a point
of this grid without each trial and scoring the trial with it. Each grid names the
parameters that were tuned on BROAD (their docstrings and commits say so) with 3-5
candidates around the default, the default among them, each with a one-line reason.

``margtrack tune FOLDER -m METHOD --cv`` without ``-g`` and ``margtrack bench broad`` read
these grids; the registry declares them.
"""

from __future__ import annotations

from collections.abc import Mapping

from margtrack.registry import RECORDS, GridParam

__all__ = ["GRIDS", "GridParam", "declared_grid", "has_grid"]


#: method -> {parameter: GridParam}: the grids of the registry's records
GRIDS: Mapping[str, Mapping[str, GridParam]] = {r.name: r.grid for r in RECORDS if r.grid}


def has_grid(method: str) -> bool:
    """True if ``method`` has a declared grid."""
    return method in GRIDS


def declared_grid(method: str) -> dict[str, list[float | int | str]]:
    """The declared grid of ``method`` as ``{parameter: [values]}`` (for :func:`tune`).

    Raises ``ValueError`` naming the methods that have one when ``method`` has none.
    """
    if method not in GRIDS:
        raise ValueError(
            f"method {method!r} has no declared tuning grid; give one with -g name=v1,v2,... "
            f"(declared: {', '.join(sorted(GRIDS))})"
        )
    return {name: list(p.values) for name, p in GRIDS[method].items()}
