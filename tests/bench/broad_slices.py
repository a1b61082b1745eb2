"""Short BROAD slices for the tuning and cross-validation tests."""

from __future__ import annotations

import json
from pathlib import Path

from margtrack import io


def write_broad_slices(broad_folder: Path, folder: Path, names: list[str]) -> Path:
    """7 s of each named BROAD trial (samples 20000-22000) into ``folder``, with the
    trials.json entries of those trials; returns ``folder``."""
    index = json.loads((broad_folder / "trials.json").read_text())
    for name in names:
        io.write(io.read_broad(broad_folder / f"{name}.hdf5").slice(20000, 22000),
                 folder / f"{name}.hdf5")
    index["trials"] = {n: index["trials"][n] for n in names}
    (folder / "trials.json").write_text(json.dumps(index))
    return folder
