"""What a batch remembers between runs: one record per output, keyed by a job hash.

A finished output has a record ``OUTDIR/.margtrack-batch/<output name>.json`` holding the
job's key and its summary row. A rerun skips an input whose key is unchanged and whose
record says ``done``; anything else runs again.

The key is the sha256 of: the input's fingerprint, the method, its full parameter set
(after defaults, so ``-p gain=0.1`` and ``-p gain=0.10`` agree), the output frame, the
calibration file's fingerprint, the declared units and the margtrack version.

The fingerprint of a file is its size, its modification time (ns) and the sha256 of its
first and last MiB, not of every byte. Why: a rerun over a study of thousands of
recordings must decide quickly (reading every byte again costs as long as reading them
to process them, 1 TB at ~1 GB/s is a quarter of an hour of I/O before anything is
skipped), and any ordinary change of a file changes its mtime (rewrite, append, re-export,
copy without preserved times); the head and tail hash catches a file replaced by
another of the same size with a restored time (the HDF5 superblock and the CSV header
and last rows live there). A change that keeps size and time and touches only the
middle needs ``--force``. ``full=True`` hashes every byte instead.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

__all__ = ["HEAD_TAIL_BYTES", "fingerprint", "job_key", "read_record", "record_path",
           "write_record"]

#: bytes hashed at each end of a file by the quick fingerprint
HEAD_TAIL_BYTES = 1 << 20
RECORD_FOLDER = ".margtrack-batch"


def _file_fingerprint(path: Path, full: bool) -> dict[str, Any]:
    st = path.stat()
    digest = hashlib.sha256()
    with path.open("rb") as f:
        if full or st.st_size <= 2 * HEAD_TAIL_BYTES:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
        else:
            digest.update(f.read(HEAD_TAIL_BYTES))
            f.seek(st.st_size - HEAD_TAIL_BYTES)
            digest.update(f.read(HEAD_TAIL_BYTES))
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": digest.hexdigest(),
            "full": full or st.st_size <= 2 * HEAD_TAIL_BYTES}


def fingerprint(path: str | Path, *, full: bool = False) -> dict[str, Any]:
    """The fingerprint of a file, or of every file in a folder (an x-IMU3 sensor), by name.

    See the module for what it holds and why; ``full`` hashes every byte.
    """
    p = Path(path)
    if p.is_dir():
        files = sorted(q for q in p.rglob("*") if q.is_file())
        return {str(q.relative_to(p)): _file_fingerprint(q, full) for q in files}
    return _file_fingerprint(p, full)


def job_key(
    input_fingerprint: dict[str, Any],
    *,
    method: str,
    params: dict[str, Any],
    frame: str | None,
    calibration: dict[str, Any] | None,
    read_kwargs: dict[str, Any],
    version: str,
) -> str:
    """The sha256 (hex) of everything an output depends on (canonical JSON)."""
    blob = json.dumps(
        {"input": input_fingerprint, "method": method, "params": params, "frame": frame,
         "calibration": calibration, "read": read_kwargs, "margtrack": version},
        sort_keys=True, default=repr,
    )
    return hashlib.sha256(blob.encode()).hexdigest()


def record_path(outdir: Path, output: Path) -> Path:
    """Where the record of ``output`` (a file in ``outdir``) lives."""
    return outdir / RECORD_FOLDER / f"{output.name}.json"


def read_record(path: Path) -> dict[str, Any] | None:
    """The record at ``path``: None if there is none; ``{}`` if it is unreadable (a crash).

    An unreadable record still says the output is the batch's own, so it is redone
    without ``--force``.
    """
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def write_record(path: Path, record: dict[str, Any]) -> None:
    """Write ``record`` as JSON to ``path`` atomically (temporary file, then rename)."""
    from margtrack.io.safe_output import atomic_output

    path.parent.mkdir(exist_ok=True)
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(record, indent=1, default=repr) + "\n")
