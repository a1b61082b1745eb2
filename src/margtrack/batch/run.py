"""The batch: one estimate file per recording and a summary, resumable, on any Dask cluster.

:func:`run_batch` checks the method, its parameters and the output folder first, expands
the inputs (:mod:`margtrack.batch.inputs`), decides per input whether its output is
current (:mod:`margtrack.batch.state`), runs the rest where the :class:`Pool` says
(:mod:`margtrack.batch.cluster`) and writes ``summary.csv`` / ``summary.parquet``
(:mod:`margtrack.batch.summary`).

Per input the work is :func:`margtrack.run.chunked.run_file` (the one runner, in
chunks of bounded memory): an HDF5 output with the estimate and its health flags, and
the figures of the summary row. One failing input is one ``failed`` row; it never stops
the others. An existing output the batch did not write (no record of it) is kept unless
``force``; one it wrote is redone when its key changed.
"""

from __future__ import annotations

import contextlib
import dataclasses
import glob
import os
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from margtrack.batch.cluster import Pool
from margtrack.batch.inputs import expand_inputs, output_names
from margtrack.batch.state import fingerprint, job_key, read_record, record_path, write_record
from margtrack.batch.summary import FIGURES, write_summary

#: inputs that take a column map / import profile (as ``io.read``'s tables)
TABLE_SUFFIXES = (".csv", ".tsv", ".txt")

__all__ = ["BatchConfig", "BatchResult", "Plan", "Task", "execute", "plan_batch", "process_one",
           "run_batch"]

#: told each finished row, how many are finished and how many there are
Progress = Callable[[dict[str, Any], int, int], None]


@dataclass(frozen=True)
class BatchConfig:
    """What every input of a batch is run with (sent to the workers once).

    params : ``name=value`` strings as on the command line (``-p``).
    calibration : a calibration JSON (``margtrack calibrate``) applied before the method.
    read_kwargs : keywords of ``io.read``: declared units; ``columns`` and ``profile``
        (a column map, an import profile) for the inputs that are tables (.csv, .tsv,
        .txt), left out for the others.
    """

    method: str = "default"
    params: tuple[str, ...] = ()
    frame: str | None = None
    calibration: str | None = None
    read_kwargs: dict[str, Any] = field(default_factory=dict)
    chunk_samples: int = 1_000_000


@dataclass(frozen=True)
class Task:
    """One input to run: its path, its output file and the key of the job."""

    file: str
    output: str
    key: str


@dataclass(frozen=True)
class BatchResult:
    """Every input's summary row (input order), where the summary went, where it ran.

    seconds : wall time of running the inputs and writing the summary, s.
    """

    rows: tuple[dict[str, Any], ...]
    summary_csv: Path
    summary_parquet: Path | None
    note: str
    where: str
    seconds: float

    def counts(self) -> dict[str, int]:
        """How many inputs ended ``done``, ``skipped`` and ``failed``."""
        c = Counter(r["status"] for r in self.rows)
        return {s: c.get(s, 0) for s in ("done", "skipped", "failed")}

    @property
    def failed(self) -> list[dict[str, Any]]:
        """The rows of the inputs that failed."""
        return [r for r in self.rows if r["status"] == "failed"]


def _failed_row(file: str, output: str | None, method: str, error: str, seconds: float = 0.0):
    row: dict[str, Any] = dict.fromkeys(FIGURES)
    row.update(file=file, status="failed", output=output, method=method, seconds=seconds,
               error=error)
    return row


def process_one(config: BatchConfig, task: Task) -> dict[str, Any]:
    """Run one input (on a worker): its summary row, ``done`` or ``failed`` with the error.

    The output is replaced (``force``): :func:`run_batch` decided it may be.
    """
    from margtrack.run.chunked import run_file

    start = time.perf_counter()
    read_kwargs = _reading(task.file, config.read_kwargs)
    try:
        summary = run_file(
            task.file,
            task.output,
            config.method,
            config.params,
            calibration=config.calibration,
            frame=config.frame,
            read_kwargs=read_kwargs,
            chunk_samples=config.chunk_samples,
            force=True,
        )
    except Exception as exc:  # one failed input is one row
        return _failed_row(task.file, None, config.method, f"{type(exc).__name__}: {exc}",
                           time.perf_counter() - start)
    row: dict[str, Any] = {k: getattr(summary, k) for k in FIGURES}
    row.update(file=task.file, status="done", output=task.output, error=None)
    return row


def _reading(path: str | Path, read_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The reader keywords that apply to ``path``: a column map or import profile
    describes the batch's tables, not its HDF5 files or sensor folders."""
    out = dict(read_kwargs)
    if Path(path).suffix.lower() not in TABLE_SUFFIXES or Path(path).is_dir():
        out.pop("columns", None)
        out.pop("profile", None)
    return out


def _remove_stale_temps(output: Path) -> None:
    """Remove temporary files of ``output`` left by a writer that was killed."""
    from margtrack.io.safe_output import temp_name_prefix

    for tmp in output.parent.glob(glob.escape(temp_name_prefix(output)) + "*"):
        with contextlib.suppress(OSError):
            tmp.unlink()


def _checked_outdir(outdir: Path) -> Path:
    """``outdir`` if it is, or can become, the output folder (created by :func:`_created`)."""
    if outdir.exists() and not outdir.is_dir():
        raise ValueError(f"output folder {outdir} is a file; give a folder (-o OUTDIR)")
    if not outdir.parent.is_dir():
        raise FileNotFoundError(
            f"cannot create output folder {outdir}: {outdir.parent} does not exist"
        )
    return outdir


def _created(outdir: Path) -> Path:
    """The checked output folder, created once the inputs are known to exist."""
    outdir.mkdir(exist_ok=True)
    if not os.access(outdir, os.W_OK | os.X_OK):
        raise PermissionError(f"output folder {outdir} is not writable; choose another one")
    return outdir


@dataclass
class Plan:
    """A checked batch before it runs: the rows already known and the inputs to run.

    rows : per input, its row when already decided (``skipped``, or ``failed`` before
        running), else None. todo : (input index, :class:`Task`, record file) to run.
    """

    config: BatchConfig
    outdir: Path
    method: str
    rows: list[dict[str, Any] | None]
    todo: list[tuple[int, Task, Path]]

    @property
    def n_inputs(self) -> int:
        """How many inputs the batch has."""
        return len(self.rows)


def plan_batch(
    inputs: Sequence[str | Path],
    outdir: str | Path,
    config: BatchConfig | None = None,
    *,
    force: bool = False,
    full_hash: bool = False,
) -> Plan:
    """Check everything a batch needs and decide per input whether it must run.

    Usage errors (unknown method or parameter, bad frame, calibration or chunk size, no
    input, an unusable output folder) raise here, before any worker starts. See
    :func:`run_batch` for the arguments.
    """
    from margtrack import __version__, frames, methods

    config = config or BatchConfig()
    estimator = methods.create(config.method, config.params)  # unknown names fail here
    resolved = {"method": estimator.name, "params": estimator.params.as_dict()}
    if config.frame is not None:
        frames.check_frame(config.frame)
    calibration_fp = None
    if config.calibration is not None:
        from margtrack.calibration import load_calibration

        load_calibration(config.calibration)  # a broken file fails before any work
        calibration_fp = fingerprint(config.calibration, full=True)
    if config.chunk_samples < 1:
        raise ValueError(f"chunk_samples must be 1 or more, got {config.chunk_samples}")
    profile_fp = None
    if config.read_kwargs.get("profile") is not None:  # its content, not only its name
        profile_fp = fingerprint(config.read_kwargs["profile"], full=True)
    out_folder = _checked_outdir(Path(outdir))
    paths = expand_inputs(inputs, exclude=out_folder)  # no input: no folder left behind
    names = output_names(paths)
    _created(out_folder)

    # "default" resolved: rows name the method that ran
    config = dataclasses.replace(config, method=estimator.name)
    plan = Plan(config, out_folder, estimator.name, [None] * len(paths), [])
    for i, (path, name) in enumerate(zip(paths, names, strict=True)):
        out = out_folder / name
        rec_file = record_path(out_folder, out)
        reading = _reading(path, config.read_kwargs)
        if "profile" in reading:
            reading["profile"] = profile_fp
        try:
            key = job_key(
                fingerprint(path, full=full_hash), **resolved, frame=config.frame,
                calibration=calibration_fp, read_kwargs=reading, version=__version__,
            )
        except OSError as exc:
            plan.rows[i] = _failed_row(str(path), None, estimator.name,
                                       f"cannot read {path}: {exc}")
            continue
        record = read_record(rec_file)
        if (
            not force and record and record.get("status") == "done"
            and record.get("key") == key and out.is_file()
        ):
            plan.rows[i] = {**record.get("row", {}), "file": str(path), "status": "skipped",
                            "error": None}
        elif record is None and out.exists() and not force:
            plan.rows[i] = _failed_row(
                str(path), None, estimator.name,
                f"output {out} exists and was not written by margtrack batch (no record in "
                f"{rec_file.parent}); it was kept: pass --force to replace it",
            )
        else:
            plan.todo.append((i, Task(str(path), str(out), key), rec_file))
    return plan


def execute(
    plan: Plan, pool: Pool | None = None, progress: Progress | None = None
) -> BatchResult:
    """Run ``plan``'s inputs on ``pool`` (None: in-process) and write the summary.

    The result's ``seconds`` is this call's wall time (not the cluster's start).
    """
    started = time.perf_counter()
    pool = pool or Pool(None, "in-process")
    rows = list(plan.rows)
    finished = 0

    def finish(i: int, row: dict[str, Any]) -> None:
        nonlocal finished
        rows[i] = row
        finished += 1
        if progress is not None:
            progress(row, finished, len(rows))

    for i, row in enumerate(plan.rows):
        if row is not None:
            finish(i, row)
    for _, task, rec_file in plan.todo:
        # from here the output is the batch's own, even if this run is killed mid-way
        write_record(rec_file, {"key": task.key, "status": "pending", "file": task.file})
        _remove_stale_temps(Path(task.output))
    tasks = [t for _, t, _ in plan.todo]
    for j, row, error in pool.map(process_one, tasks, plan.config, key_prefix="margtrack-batch"):
        i, task, rec_file = plan.todo[j]
        if error is not None:  # the cluster's, not the input's (a worker kept dying)
            row = _failed_row(task.file, None, plan.method, f"{type(error).__name__}: {error}")
        write_record(rec_file, {"key": task.key, "status": row["status"], "file": task.file,
                                "row": row})
        # a worker killed while writing leaves its temporary file; the job is over now
        _remove_stale_temps(Path(task.output))
        finish(i, row)

    done_rows = tuple(r for r in rows if r is not None)
    csv_path, parquet_path, note = write_summary(done_rows, plan.outdir)
    return BatchResult(done_rows, csv_path, parquet_path, note, pool.description,
                       time.perf_counter() - started)


def run_batch(
    inputs: Sequence[str | Path],
    outdir: str | Path,
    config: BatchConfig | None = None,
    *,
    pool: Pool | None = None,
    force: bool = False,
    full_hash: bool = False,
    progress: Progress | None = None,
) -> BatchResult:
    """Run ``config``'s method on every recording of ``inputs``; outputs in ``outdir``.

    Parameters
    ----------
    inputs : files, folders and globs (:func:`~margtrack.batch.inputs.expand_inputs`).
    outdir : the output folder (created if its parent exists): ``<name>.h5`` per input
        (names from :func:`~margtrack.batch.inputs.output_names`), ``summary.csv``,
        ``summary.parquet`` and the records in ``.margtrack-batch/``.
    config : method, parameters, frame, calibration, units, chunk size.
    pool : where to run (:func:`~margtrack.batch.cluster.open_pool`); None: in-process.
    force : redo every input and replace outputs the batch did not write.
    full_hash : fingerprint inputs by every byte (:mod:`margtrack.batch.state`).
    progress : told each finished row (skipped ones too), how many are finished, of how many.

    Usage errors raise before anything runs (:func:`plan_batch`); a failing input is a
    ``failed`` row and the others go on (:func:`execute`).
    """
    plan = plan_batch(inputs, outdir, config, force=force, full_hash=full_hash)
    return execute(plan, pool, progress)
