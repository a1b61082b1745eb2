"""The ``compile`` command: every method's kernels into numba's cache, ahead of use."""

from __future__ import annotations

import time
from typing import Annotated

import typer
from rich.table import Table

from margtrack.cli.app import app, console, friendly_errors, progress_bar


@app.command(name="compile")
@friendly_errors
def compile_kernels(
    names: Annotated[
        list[str] | None, typer.Argument(help="Methods to compile (default: all).")
    ] = None,
    jobs: Annotated[
        int | None, typer.Option(help="Processes sharing the methods (default: the CPUs).")
    ] = None,
) -> None:
    """Compile the methods' kernels once, before several processes need them.

    A new install, a new numba or an edited kernel compiles on first use, in every process
    that starts before the first has finished (Dask workers, a test suite on every core).
    This does it once, the methods shared among processes; later runs load the cache.
    """
    from margtrack import methods
    from margtrack.precompile import precompile

    chosen = names or methods.available()
    with progress_bar("compiling kernels") as update:
        done: list[str] = []

        def progress(name: str, seconds: float) -> None:
            done.append(name)
            if update is not None:
                update(len(done), len(chosen))
            else:
                console.print(f"{name}: {seconds:.1f} s", soft_wrap=True)

        start = time.perf_counter()
        seconds = precompile(chosen, jobs=jobs, progress=progress)
        elapsed_s = time.perf_counter() - start
    if not seconds:
        console.print("NUMBA_DISABLE_JIT is set: the kernels run as Python, nothing to compile")
        return
    table = Table("method", "seconds")
    for name, s in sorted(seconds.items(), key=lambda kv: -kv[1]):
        table.add_row(name, f"{s:.1f}")
    console.print(table)
    plural = "" if len(seconds) == 1 else "s"
    console.print(f"{len(seconds)} method{plural} ready in numba's cache in {elapsed_s:.0f} s "
                  "(seconds per method: compiling on a cold cache, loading from it on a warm one)")
