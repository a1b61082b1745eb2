"""margtrack batch on a real Dask cluster: `dask scheduler` and two `dask worker` processes.

The scheduler and workers are started here on 127.0.0.1 and stopped after the module,
even when a test fails. Inputs: 4 of the 16 BROAD trials (each read where it lies in
../shared; all 16 take minutes on two busy cores) and a truncated copy of one.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from margtrack.batch import open_pool, run_batch

DASK = Path(sys.executable).with_name("dask")
TRIALS = ("02_undisturbed_slow_rotation_B", "10_undisturbed_slow_translation_A",
          "11_undisturbed_slow_translation_B", "26_disturbed_phone_vibration_A")


def _wait(condition, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} not ready after {timeout_s:g} s")
        time.sleep(0.2)


class Cluster:
    """A scheduler and workers as subprocesses (each in its own session), stopped by ``stop``."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.procs: list[subprocess.Popen] = []
        self.workers: list[subprocess.Popen] = []
        self.address = ""

    def _start(self, *args: str, log: str) -> subprocess.Popen:
        out = (self.folder / log).open("w")
        proc = subprocess.Popen([str(DASK), *args], stdout=out, stderr=subprocess.STDOUT,
                                start_new_session=True)
        self.procs.append(proc)
        return proc

    def start(self, n_workers: int) -> None:
        import json

        file = self.folder / "scheduler.json"
        self._start("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                    "--scheduler-file", str(file), log="scheduler.log")
        _wait(lambda: file.is_file() and file.stat().st_size > 0, 60, "dask scheduler")
        self.address = json.loads(file.read_text())["address"]
        for k in range(n_workers):
            # no nanny: the worker is this process, so kill -9 ends it for good
            self.workers.append(self._start(
                "worker", self.address, "--nworkers", "1", "--nthreads", "1", "--no-nanny",
                "--no-dashboard", "--host", "127.0.0.1", "--name", f"w{k}", log=f"w{k}.log",
            ))

    def stop(self) -> None:
        for proc in reversed(self.procs):
            if proc.poll() is None:
                proc.terminate()
        for proc in reversed(self.procs):
            try:
                proc.wait(timeout=3)  # a worker may wait on its gone peer; then kill it
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    if not DASK.is_file():
        pytest.skip(f"the dask command is not installed beside {sys.executable}")
    c = Cluster(tmp_path_factory.mktemp("dask"))
    try:
        c.start(2)
        from distributed import Client

        with Client(c.address, timeout=30) as client:
            client.wait_for_workers(2, timeout=60)
        yield c
    finally:
        c.stop()


@pytest.fixture(scope="module")
def inputs(broad_folder, tmp_path_factory):
    bad = tmp_path_factory.mktemp("bad") / "truncated_trial.hdf5"
    data = (broad_folder / f"{TRIALS[0]}.hdf5").read_bytes()
    bad.write_bytes(data[: len(data) // 3])
    return [str(broad_folder / f"{t}.hdf5") for t in TRIALS] + [str(bad)]


@pytest.fixture(scope="module")
def reference(inputs, tmp_path_factory):
    """The same batch in this process: the oracle."""
    return run_batch(inputs, tmp_path_factory.mktemp("here"))


def _quats(row) -> np.ndarray:
    with h5py.File(row["output"]) as f:
        return f["quat"][:]


def _assert_same(result, reference) -> None:
    assert [r["status"] for r in result.rows] == ["done"] * 4 + ["failed"]
    for a, b in zip(reference.rows[:4], result.rows[:4], strict=True):
        np.testing.assert_allclose(_quats(b), _quats(a), rtol=0, atol=1e-12)
        for key in ("samples", "gaps", "fault_samples", "rest_samples", "mag_ignored_pct"):
            assert b[key] == a[key], key
        assert b["total_rmse_deg"] == pytest.approx(a["total_rmse_deg"], rel=1e-12)


def test_batch_on_a_scheduler_equals_in_process_and_reruns_skip(cluster, inputs, reference,
                                                                tmp_path):
    assert reference.counts() == {"done": 4, "skipped": 0, "failed": 1}
    assert "truncated_trial.hdf5" in reference.rows[4]["error"]
    with open_pool(scheduler=cluster.address) as pool:
        assert pool.n_workers == 2
        result = run_batch(inputs, tmp_path / "out", pool=pool)
        _assert_same(result, reference)
        assert reference.rows[4]["error"] == result.rows[4]["error"]
    # the rerun from the command line on the same scheduler: every output is current
    from typer.testing import CliRunner

    from margtrack.batch.summary import read_summary_csv
    from margtrack.cli import app

    cli = CliRunner().invoke(
        app, ["batch", *inputs, "-o", str(tmp_path / "out"), "--scheduler", cluster.address]
    )
    assert cli.exit_code == 1, cli.output  # the truncated file failed again
    assert "5 recordings: 0 done, 4 skipped, 1 failed" in cli.output
    again = read_summary_csv(tmp_path / "out" / "summary.csv")
    assert [r["status"] for r in again] == ["skipped"] * 4 + ["failed"]
    assert [r["total_rmse_deg"] for r in again[:4]] == [
        r["total_rmse_deg"] for r in result.rows[:4]
    ]


def test_a_worker_killed_during_the_run_does_not_stop_the_batch(cluster, inputs, reference,
                                                                tmp_path):
    by_name = {f"w{k}": w for k, w in enumerate(cluster.workers)}  # the --name given
    killed: list[tuple[subprocess.Popen, list[str]]] = []

    with open_pool(scheduler=cluster.address) as pool:

        def progress(row, finished, total):
            # at the first finished input, kill -9 a worker that is running one
            if killed:
                return
            info = pool.client.scheduler_info()["workers"]
            for address, keys in pool.client.processing().items():
                proc = by_name.get(str(info[address]["name"]))
                if keys and proc is not None:
                    os.kill(proc.pid, signal.SIGKILL)
                    killed.append((proc, list(keys)))
                    return

        result = run_batch(inputs, tmp_path / "out", pool=pool, progress=progress)
    assert killed, "no worker was busy at the first finished input"
    proc, keys = killed[0]
    assert any(str(k).startswith("margtrack-batch") for k in keys)
    assert proc.wait(timeout=10) == -signal.SIGKILL
    _assert_same(result, reference)  # its input was rerun on the other worker
    assert not list((tmp_path / "out").glob(".*.tmp-*"))  # no half-written file is left
