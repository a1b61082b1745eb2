"""Shared fixtures: the location of the real data beside the repository."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BROAD = DATA / "broad"


@pytest.fixture(scope="session")
def broad_folder() -> Path:
    """../shared/data/broad, or skip: the BROAD trials live outside the repository."""
    if not (BROAD / "trials.json").is_file():
        pytest.skip(f"BROAD data not found at {BROAD} (it lives in ../shared beside the repo)")
    return BROAD
