"""The dual-IMU trials beside the repository (../shared/data/dualimu), or a skip."""

from __future__ import annotations

from pathlib import Path

import pytest

DUALIMU = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "dualimu"


@pytest.fixture(scope="session")
def dualimu_folder() -> Path:
    """../shared/data/dualimu (9 trials of Weygers & Kok 2020), or skip: it lives outside
    the repository."""
    if not (DUALIMU / "data_2D_01.mat").is_file():
        pytest.skip(f"dual-IMU data not found at {DUALIMU} (it lives in ../shared)")
    return DUALIMU
