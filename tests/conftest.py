"""Shared fixtures: the location of the real data beside the repository."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

# No quick-start builds from the commands under test (each would compile for half a minute);
# tests/kernels/test_aot.py switches them on in a temporary cache folder.
os.environ["MARGTRACK_AOT"] = "0"


def pytest_sessionstart(session: pytest.Session) -> None:
    """Under pytest-xdist (``-n``), compile every method's kernels once before the workers
    start, the methods shared among the CPUs (``margtrack.precompile``): otherwise each
    worker compiles each kernel it meets, the same kernels at the same time. Nothing to do
    on a warm cache (a second per method) or with ``NUMBA_DISABLE_JIT=1``."""
    config = session.config
    if hasattr(config, "workerinput") or not config.pluginmanager.has_plugin("dsession"):
        return
    from margtrack.precompile import precompile

    start = time.perf_counter()
    seconds = precompile()
    if seconds:
        reporter = config.pluginmanager.get_plugin("terminalreporter")
        slowest = max(seconds, key=seconds.__getitem__)
        reporter.write_line(
            f"kernels of {len(seconds)} methods compiled or loaded in "
            f"{time.perf_counter() - start:.0f} s (slowest: {slowest}, {seconds[slowest]:.0f} s)"
        )


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
