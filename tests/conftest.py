"""Shared fixtures: the location of the real data beside the repository."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# No quick-start builds from the commands under test (each would compile for half a minute);
# tests/kernels/test_aot.py switches them on in a temporary cache folder.
os.environ["MARGTRACK_AOT"] = "0"

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
