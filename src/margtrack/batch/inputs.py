"""Expand a batch's INPUT arguments (files, folders, globs) into the recordings to run.

Every format ``margtrack run`` reads is one recording:

- a ``.h5``/``.hdf5`` file (margtrack HDF5 or a BROAD trial) or a table (``.csv``,
  ``.tsv``, ``.txt``: margtrack CSV, a phone logger's table);
- an x-IMU3 sensor folder (a folder holding ``Inertial.csv``);
- a folder of per-sensor files (``Gyroscope.csv``, ``Accelerometer.csv``...: Sensor
  Logger, phyphox), which ``run`` merges into one recording.

A folder argument that is not itself a recording gives the recordings directly in it: its
``.h5``/``.hdf5``/``.csv``/``.tsv`` files (a BROAD folder: its trials; ``trials.json``,
``.txt`` notes and other files are not recordings) and its recording subfolders (an
x-IMU3 body export: one recording per sensor). A glob (``data/*/trial_*.hdf5``, ``**``
for any depth) gives every match, each expanded the same way. The result is in argument
order, sorted within a folder or glob, without duplicates; anything inside ``exclude``
(the batch's own output folder) is left out.
"""

from __future__ import annotations

import glob
import hashlib
from collections.abc import Iterable, Sequence
from pathlib import Path

__all__ = ["RECORDING_SUFFIXES", "expand_inputs", "output_names"]

#: files a folder's recordings are taken from
RECORDING_SUFFIXES = (".h5", ".hdf5", ".csv", ".tsv")
#: files that are recordings when named (or matched by a glob) one by one
FILE_SUFFIXES = (*RECORDING_SUFFIXES, ".txt")
_GLOB_CHARS = set("*?[")


def _is_recording_folder(p: Path) -> bool:
    """An x-IMU3 sensor folder, or a folder of per-sensor files with a gyroscope."""
    if not p.is_dir():
        return False
    if (p / "Inertial.csv").is_file():
        return True
    from margtrack.io.phone import sensor_files

    try:
        return "gyr" in sensor_files(p)
    except OSError:
        return False


def _in_folder(folder: Path) -> list[Path]:
    if _is_recording_folder(folder):
        return [folder]
    found = []
    for p in sorted(folder.iterdir()):
        if p.name.startswith("."):
            continue
        if p.is_file() and p.suffix.lower() in RECORDING_SUFFIXES:
            found.append(p)
        elif _is_recording_folder(p):
            found.append(p)
    return found


def _one(p: Path, arg: str) -> list[Path]:
    if p.is_dir():
        return _in_folder(p)
    if p.is_file():
        if p.suffix.lower() not in FILE_SUFFIXES:
            raise ValueError(
                f"{arg}: {p} is not a recording ({p.suffix or 'no extension'}); batch reads "
                f"{', '.join(FILE_SUFFIXES)} files, x-IMU3 sensor folders and folders of "
                "per-sensor files"
            )
        return [p]
    raise FileNotFoundError(f"{arg}: no such file or folder: {p}")


def _inside(p: Path, folder: Path) -> bool:
    try:
        p.resolve().relative_to(folder.resolve())
    except ValueError:
        return False
    return True


def expand_inputs(args: Iterable[str | Path], *, exclude: Path | None = None) -> list[Path]:
    """The recordings named by ``args`` (see the module), in order, each once.

    Raises ``FileNotFoundError`` for a path that does not exist, and ``ValueError`` for a
    glob or folder that holds no recording, for a file that is not a recording, and when
    nothing at all is left; each message names the argument.
    """
    out: list[Path] = []
    seen: set[Path] = set()
    for raw in args:
        arg = str(raw)
        if _GLOB_CHARS & set(arg) and not Path(arg).exists():
            matches = sorted(glob.glob(arg, recursive=True))
            if not matches:
                raise ValueError(f"{arg}: the pattern matched no file or folder")
            found = []
            for m in matches:
                mp = Path(m)
                if mp.is_dir():
                    found += _in_folder(mp)
                elif mp.suffix.lower() in FILE_SUFFIXES:
                    found.append(mp)
        else:
            found = _one(Path(arg), arg)
        if exclude is not None:
            found = [f for f in found if not _inside(f, exclude)]
        if not found:
            raise ValueError(
                f"{arg}: no recording there ({', '.join(RECORDING_SUFFIXES)} files, x-IMU3 "
                "sensor folders or folders of per-sensor files"
                + (f", outside the output folder {exclude}" if exclude is not None else "")
                + ")"
            )
        for f in found:
            key = f.resolve()
            if key not in seen:
                seen.add(key)
                out.append(f)
    if not out:
        raise ValueError("no input given: name recording files, folders or globs")
    return out


def output_names(inputs: Sequence[Path], suffix: str = ".h5") -> list[str]:
    """One output file name per input, unique within the batch and the same on every rerun.

    The name is the input's stem (an x-IMU3 sensor folder's name) plus ``suffix``; inputs
    whose stems collide (``a/trial.h5`` and ``b/trial.csv``) get ``-`` and the first 8 hex
    digits of the sha256 of their absolute path appended.
    """
    stems = [p.name if p.is_dir() else p.stem for p in inputs]
    counts: dict[str, int] = {}
    for s in stems:
        counts[s.lower()] = counts.get(s.lower(), 0) + 1
    names = []
    for p, s in zip(inputs, stems, strict=True):
        if counts[s.lower()] > 1:
            tag = hashlib.sha256(str(p.resolve()).encode()).hexdigest()[:8]
            s = f"{s}-{tag}"
        names.append(s + suffix)
    return names
