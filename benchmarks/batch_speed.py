"""Throughput of ``margtrack batch``: in-process loop, batch in-process, 1 and 2 Dask workers.

Run ``python benchmarks/batch_speed.py [--data FOLDER] [--trials N] [--method NAME]``.

Input: the BROAD trials of ../shared/data/broad (all 16 by default, each read where it
lies), outputs to a temporary folder removed at the end. Printed, per way of running:
recordings/s, samples/s (input samples over wall time), and the ratio of its wall time to
the plain in-process loop (the overhead):

- ``loop``: ``for f in files: run_file(f, out)`` in this process (no hashing, no records,
  no summary: the floor);
- ``batch, in-process``: :func:`margtrack.batch.run_batch` with ``--workers 1``;
- ``batch, 1 worker`` / ``batch, 2 workers``: on an embedded ``LocalCluster`` of worker
  processes; the cluster's start and each worker's first import and kernel load (a warm-up
  task) are timed apart and not included;
- ``rerun (all skipped)``: the same batch again, where every output is current.

The numba kernels are compiled (cached) before anything is timed. Speed-up from a second
worker needs a second free core: on a shared machine the figure says how busy it was.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import shutil
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from margtrack.batch import Pool, open_pool, run_batch
from margtrack.batch.inputs import expand_inputs, output_names
from margtrack.run.chunked import run_file

BROAD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "broad"


def _warm(method: str, trial: str) -> None:
    """Import margtrack and load the method's kernels (a short run) in this process."""
    from margtrack import io, methods

    methods.create(method).run(io.read(trial).slice(0, 500))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=BROAD)
    parser.add_argument("--trials", type=int, default=16, help="how many trials (sorted)")
    parser.add_argument("--method", default="default")
    args = parser.parse_args()
    console = Console()
    files = expand_inputs([args.data])[: args.trials]
    if not files:
        raise SystemExit(f"no recordings in {args.data}")
    console.print(f"{len(files)} recordings from {args.data}, method {args.method}")
    _warm(args.method, str(files[0]))
    rows = []
    work = Path(tempfile.mkdtemp(prefix="margtrack-batch-speed-"))
    try:
        start = time.perf_counter()
        samples = 0
        loop_out = work / "loop"
        loop_out.mkdir()
        for f, name in zip(files, output_names(files), strict=True):
            samples += run_file(f, loop_out / name, args.method).samples
        loop_s = time.perf_counter() - start
        rows.append(("loop (run_file per file)", loop_s, ""))

        start = time.perf_counter()
        result = run_batch(files, work / "inproc", _config(args.method))
        rows.append(("batch, in-process", time.perf_counter() - start, _check(result)))
        start = time.perf_counter()
        result = run_batch(files, work / "inproc", _config(args.method))
        rows.append(("rerun (all skipped)", time.perf_counter() - start, _check(result)))

        for n in (1, 2):
            t0 = time.perf_counter()
            with _cluster(n) as pool:
                pool.client.run(_warm, args.method, str(files[0]))
                ready_s = time.perf_counter() - t0
                start = time.perf_counter()
                result = run_batch(files, work / f"w{n}", _config(args.method), pool=pool)
                seconds = time.perf_counter() - start
            rows.append((f"batch, {n} worker{'s' if n > 1 else ''}", seconds,
                         _check(result) + f"cluster ready in {ready_s:.1f} s"))
    finally:
        shutil.rmtree(work, ignore_errors=True)

    table = Table(title=f"margtrack batch: {len(files)} recordings, {samples:,} samples")
    for col in ("way", "wall s", "recordings/s", "samples/s", "vs loop", "note"):
        table.add_column(col, justify="left" if col in ("way", "note") else "right")
    for way, seconds, note in rows:
        table.add_row(way, f"{seconds:.2f}", f"{len(files) / seconds:.2f}",
                      f"{samples / seconds:,.0f}", f"{seconds / loop_s:.2f}x", note)
    console.print(table)


@contextlib.contextmanager
def _cluster(n: int):
    """A LocalCluster of ``n`` worker processes (``open_pool(1)`` would stay in-process)."""
    if n > 1:
        with open_pool(n) as pool:
            yield pool
        return
    from distributed import Client, LocalCluster

    with (
        LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                     dashboard_address=None, silence_logs=logging.ERROR) as cluster,
        Client(cluster) as client,
    ):
        yield Pool(client, "local Dask cluster, 1 worker process")


def _config(method: str):
    from margtrack.batch import BatchConfig

    return BatchConfig(method=method)


def _check(result) -> str:
    counts = result.counts()
    if counts["failed"]:
        raise SystemExit(f"{counts['failed']} recordings failed: {result.failed[0]['error']}")
    return f"{counts['done']} done, {counts['skipped']} skipped; "


if __name__ == "__main__":
    main()
