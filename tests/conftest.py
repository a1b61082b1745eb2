"""Shared fixtures (the location of the real data beside the repository), and the kernels
compiled once before pytest-xdist's workers start."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BROAD = DATA / "broad"
XIO = DATA / "xio_lower_body"


@pytest.fixture(scope="session")
def broad_folder() -> Path:
    """../shared/data/broad, or skip: the BROAD trials live outside the repository."""
    if not (BROAD / "trials.json").is_file():
        pytest.skip(f"BROAD data not found at {BROAD} (it lives in ../shared beside the repo)")
    return BROAD


@pytest.fixture(scope="session")
def xio_folder() -> Path:
    """../shared/data/xio_lower_body (7 x-IMU3 sensors), or skip: it lives outside the repo."""
    if not all((XIO / "pelvis" / name).is_file() for name in ("Inertial.csv", "Quaternion.csv")):
        pytest.skip(f"x-IMU3 lower-body data not found at {XIO} (it lives in ../shared)")
    return XIO


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session: pytest.Session) -> None:
    """With pytest-xdist workers (``-n``), compile every method's kernels into numba's cache
    once (``margtrack.precompile``, the methods shared among the CPUs) before the workers
    start: each worker would otherwise compile the kernels its tests use, most of them in
    every worker at the same time. Loading a warm cache takes seconds. Off with
    ``MARGTRACK_TEST_PRECOMPILE=0``."""
    config = session.config
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    if os.environ.get("MARGTRACK_TEST_PRECOMPILE", "1") == "0":
        return
    from margtrack.precompile import precompile

    reporter = config.pluginmanager.get_plugin("terminalreporter")
    start = time.perf_counter()
    seconds = precompile()
    if reporter is not None and seconds:
        reporter.write_line(
            f"margtrack kernels ready in numba's cache in {time.perf_counter() - start:.0f} s "
            "(each method's process: "
            + ", ".join(f"{name} {s:.0f} s" for name, s in
                        sorted(seconds.items(), key=lambda item: -item[1]))
            + ")"
        )
