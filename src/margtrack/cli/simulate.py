"""The ``simulate`` and ``demo`` commands: recordings with a known truth."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from margtrack.cli.app import app, console, friendly_errors


@app.command()
@friendly_errors
def simulate(
    output: Annotated[Path, typer.Option("--output", "-o", help="Output .h5/.hdf5 or .csv file.")],
    motion: Annotated[
        str, typer.Option(help="random, limb, static or tilt (constant rotation about x).")
    ] = "random",
    duration_s: Annotated[float, typer.Option("--duration", help="Length in s.")] = 60.0,
    rate_hz: Annotated[float, typer.Option("--rate", help="Sample rate in Hz.")] = 100.0,
    seed: Annotated[int, typer.Option(help="Random seed (same seed, same data).")] = 0,
    frame: Annotated[str, typer.Option(help="Earth frame of the truth: ENU or NED.")] = "ENU",
    noise: Annotated[bool, typer.Option(help="Apply the MEMS sensor error model.")] = True,
    mag: Annotated[bool, typer.Option(help="Include a magnetometer.")] = True,
) -> None:
    """Write a simulated recording with ground truth."""
    from margtrack import io, sim

    rec = sim.simulate_motion(
        motion,
        duration_s=duration_s,
        rate_hz=rate_hz,
        seed=seed,
        frame=frame,
        noise=noise,
        with_mag=mag,
    )
    io.write(rec, output)
    console.print(
        f"wrote {output}: {rec.n_samples} samples at {rate_hz:g} Hz, {motion} motion, "
        f"{'noisy' if noise else 'noise-free'}, truth in {rec.frame}"
    )




@app.command()
@friendly_errors
def demo(
    duration_s: Annotated[float, typer.Option("--duration", help="Simulated length in s.")] = 60.0,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
) -> None:
    """Simulate a noisy MARG recording and compare every method against its truth."""
    from margtrack import sim

    rec = sim.simulate_motion("random", duration_s=duration_s, rate_hz=100.0, seed=seed)
    console.print(
        f"simulated {rec.duration_s:.0f} s of random motion at 100 Hz with MEMS sensor errors "
        f"(seed {seed})"
    )
    import os
    from concurrent.futures import ProcessPoolExecutor

    from margtrack import methods

    table = Table(title="RMSE against the simulated truth (deg)")
    for col in ("method", "total", "heading", "inclination"):
        table.add_column(col, justify="left" if col == "method" else "right")
    names = methods.available()
    # the methods shared among the CPUs (their first run compiles their kernels): first one
    # method per compiled kernel (the recursive filters, the longest to compile), then those
    # sharing a kernel already compiled by then, then the single-frame estimators
    kernels = [getattr(methods.get(n), "kernel", None) for n in names]
    rank = [0 if k is not None and kernels.index(k) == i else 1 if k is not None else 2
            for i, k in enumerate(kernels)]
    order = [n for _, n in sorted(zip(rank, names, strict=True), key=lambda p: p[0])]
    with ProcessPoolExecutor(max_workers=min(os.cpu_count() or 1, len(names))) as pool:
        futures = {name: pool.submit(_method_errors, name, f"{name} ({n} of {len(names)})", rec)
                   for n, name in enumerate(order, 1)}
        for name in names:
            total, heading, inclination = futures[name].result()
            star = " (default)" if name == methods.DEFAULT_METHOD else ""
            table.add_row(name + star, f"{total:.2f}", f"{heading:.2f}", f"{inclination:.2f}")
    console.print(table)


def _method_errors(name: str, stage: str, rec: object) -> tuple[float, float, float]:
    """One method's total, heading and inclination RMSE (deg) on the demo's recording, in a
    worker process; a line on stderr names ``stage`` if its kernels compile first."""
    from rich.console import Console

    from margtrack import methods
    from margtrack.bench.runner import evaluate
    from margtrack.cli.compiling import compile_notice

    # a plain line, not a spinner: the workers share the terminal
    with compile_notice(Console(stderr=True, force_terminal=False, soft_wrap=True)) as notice:
        notice.stage = stage
        errors = evaluate(methods.create(name), rec)
    return errors.total_rmse_deg, errors.heading_rmse_deg, errors.inclination_rmse_deg
