"""Safe outputs: checked before computing, never the input, kept unless forced, atomic."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

import margtrack as mt
from margtrack import io, methods
from margtrack.cli import app
from margtrack.io.safe_output import atomic_output, check_output
from margtrack.run.chunked import run_file

runner = CliRunner()


def _invoke(*args: object):
    return runner.invoke(app, [str(a) for a in args], env={"COLUMNS": "300"})


def _temps(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name)


@pytest.fixture(scope="module")
def rec_file(tmp_path_factory) -> Path:
    rec = mt.sim.simulate_motion("random", duration_s=10, rate_hz=100, seed=5)
    path = tmp_path_factory.mktemp("safe") / "rec.h5"
    io.write(rec, path)
    return path


def test_existing_output_is_refused_and_kept(tmp_path) -> None:
    out = tmp_path / "out.h5"
    out.write_bytes(b"good")
    with pytest.raises(FileExistsError, match=r"out\.h5 already exists and was kept.*--force"):
        check_output(out)
    assert out.read_bytes() == b"good"
    assert check_output(out, force=True) == out
    with atomic_output(check_output(out, force=True)) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".out.h5.tmp-")
        tmp.write_bytes(b"new")
        assert out.read_bytes() == b"good"  # replaced only at the end
    assert out.read_bytes() == b"new" and _temps(tmp_path) == []


def test_the_input_is_never_the_output(tmp_path, monkeypatch) -> None:
    src = tmp_path / "rec.h5"
    src.write_bytes(b"recording")
    (tmp_path / "link.h5").symlink_to(src)
    os.link(src, tmp_path / "hard.h5")
    monkeypatch.chdir(tmp_path)
    for same in (src, Path("rec.h5"), tmp_path / "sub" / ".." / "rec.h5", tmp_path / "link.h5",
                 tmp_path / "hard.h5"):
        with pytest.raises(ValueError, match="would destroy the recording"):
            check_output(same, [src], force=True)  # force never allows it
    with pytest.raises(ValueError, match="would destroy"):
        check_output(tmp_path, [tmp_path], force=True)  # an input folder as output
    assert src.read_bytes() == b"recording"
    assert check_output(tmp_path / "other.h5", [src]) == tmp_path / "other.h5"


def test_missing_or_wrong_folder_is_refused(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match=r"folder .*nope does not exist.*mkdir -p"):
        check_output(tmp_path / "nope" / "out.h5")
    with pytest.raises(IsADirectoryError, match="is a folder"):
        check_output(tmp_path, force=True)
    (tmp_path / "file").write_text("x")
    with pytest.raises(NotADirectoryError, match="is a file, not a folder"):
        check_output(tmp_path / "file" / "out.h5")


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into any folder, test as a user")
def test_read_only_folder_is_refused(tmp_path) -> None:
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(PermissionError, match="is not writable"):
            check_output(folder / "out.h5")
    finally:
        folder.chmod(0o700)


def test_output_errors_come_before_any_computation(tmp_path) -> None:
    # the input is broken too: a refusal that names the output, not the input, came first
    broken = tmp_path / "broken.h5"
    broken.write_bytes(b"not hdf5 at all")
    calls: list[int] = []
    existing = tmp_path / "done.h5"
    existing.write_bytes(b"kept")
    for output, error in ((tmp_path / "missing" / "o.h5", FileNotFoundError),
                          (existing, FileExistsError), (broken, ValueError)):
        with pytest.raises(error) as info:
            run_file(broken, output, "robust", progress=lambda d, n: calls.append(d))
        assert "not a readable HDF5" not in str(info.value)
    assert calls == [] and existing.read_bytes() == b"kept"
    # an unsupported output extension also fails before the input is read
    with pytest.raises(ValueError, match=r"unsupported extension '\.txt'"):
        run_file(broken, tmp_path / "o.txt", "robust")
    assert _temps(tmp_path) == []


def test_an_exception_mid_write_keeps_the_previous_output(tmp_path, rec_file) -> None:
    out = tmp_path / "out.h5"
    out.write_bytes(b"previous")
    with pytest.raises(RuntimeError, match="disk full"), atomic_output(out) as tmp:
        tmp.write_bytes(b"half a fi")
        raise RuntimeError("disk full")
    assert out.read_bytes() == b"previous" and _temps(tmp_path) == []
    # the library writers go through it: a bad estimate fails without touching the file
    estimate = methods.create("robust").run(io.read(rec_file))
    bad = type(estimate)(**{**estimate.__dict__, "outputs": {"x": np.zeros(3)}})
    for name in ("out.h5", "out.csv"):
        target = tmp_path / name
        target.write_bytes(b"previous")
        with pytest.raises(ValueError, match="first axis must be N"):
            io.write_estimate(bad, target)
        assert target.read_bytes() == b"previous"
    assert _temps(tmp_path) == []
    io.write_estimate(estimate, out)  # a good write replaces it, leaving no temporary file
    with h5py.File(out) as f:
        np.testing.assert_array_equal(f["quat"][()], estimate.quat)
    assert _temps(tmp_path) == []


def test_kill_9_during_a_large_write_leaves_the_old_output(tmp_path) -> None:
    out = tmp_path / "big.csv"
    out.write_text("the previous good output\n")
    script = textwrap.dedent(f"""
        import sys
        import numpy as np
        from margtrack.estimator import Estimate
        from margtrack.io.estimate_writer import EstimateWriter
        n = 20_000
        q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        with EstimateWriter({str(out)!r}) as writer:
            for k in range(100_000):  # far more than the test waits for
                t = (k * n + np.arange(n)) / 100.0
                writer.append(Estimate(quat=q, t=t, frame="ENU", method="x", params={{}}))
                if k == 2:
                    print("writing", flush=True)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "writing"
        temps = _temps(tmp_path)
        assert len(temps) == 1 and (tmp_path / temps[0]).stat().st_size > 1_000_000
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=30) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert out.read_text() == "the previous good output\n"


def test_cli_run_refuses_the_input_and_existing_outputs(tmp_path, rec_file) -> None:
    before = rec_file.read_bytes()
    result = _invoke("run", rec_file, "-o", rec_file, "--force")
    assert result.exit_code == 2 and "would destroy the recording" in result.output
    assert rec_file.read_bytes() == before
    out = tmp_path / "est.csv"
    assert _invoke("run", rec_file, "-o", out).exit_code == 0
    first = out.read_bytes()
    out.write_bytes(b"edited by hand")
    result = _invoke("run", rec_file, "-o", out)
    assert result.exit_code == 2
    assert "already exists and was kept" in result.output and "--force" in result.output
    assert out.read_bytes() == b"edited by hand"
    result = _invoke("run", rec_file, "-o", out, "--force", "--chunk-samples", "333")
    assert result.exit_code == 0, result.output
    assert out.read_bytes() == first  # chunks change nothing in the file
    result = _invoke("run", rec_file, "-o", tmp_path / "no" / "est.h5")
    assert result.exit_code == 2 and "does not exist" in result.output
    assert _temps(tmp_path) == []


def test_recording_writers_replace_atomically(tmp_path, rec_file) -> None:
    rec = io.read(rec_file)
    for name in ("copy.h5", "copy.csv"):
        target = tmp_path / name
        target.write_bytes(b"old")
        inode = target.stat().st_ino
        io.write(rec, target)
        assert target.stat().st_ino != inode  # a new file renamed into place, not rewritten
        np.testing.assert_array_equal(io.read(target).gyr, rec.gyr)
    assert _temps(tmp_path) == []
