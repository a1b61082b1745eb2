"""Kernels without numba until they run, and quick-start (ahead-of-time) builds.

``margtrack.kernels.jit`` defers numba to a kernel's first call; ``margtrack.kernels.aot``
serves that call from a pycc build when one matches. A build must give numba's result bit
for bit, and anything it was not built for (another dtype, layout, source, version) must go
to numba instead.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from margtrack import io, sim
from margtrack.cli.compiling import AOT_MESSAGE
from margtrack.kernels import aot, jit


def _python(code: str, cwd: Path, env: dict[str, str], *args: str
            ) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          cwd=cwd, env={**os.environ, **env}, timeout=600, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc


RUN_AND_REPORT = """\
import sys
from margtrack.cli import app
app(["run", "rec.h5", "-o", sys.argv[1]], standalone_mode=False)
print("NUMBA", "numba" in sys.modules)
"""


def test_importing_kernels_does_not_import_numba(tmp_path):
    proc = _python(
        "import sys\n"
        "import margtrack.bench.chunked, margtrack.filters.robust, margtrack.io, "
        "margtrack.kernels.contract\n"
        "from margtrack.kernels import robust\n"
        "print(type(robust.run).__name__, 'numba' in sys.modules)", tmp_path, {})
    assert proc.stdout.split() == ["LazyKernel", "False"]


def test_first_call_makes_every_kernel_a_numba_dispatcher():
    import numba
    from numba.core.registry import CPUDispatcher
    from numba.np.unsafe.ndarray import to_fixed_tuple

    from margtrack.kernels import contract, ekf_step, gradient, robust, screen

    rows, twin = np.zeros((2, screen.N_SCREEN)), np.zeros((2, screen.N_SCREEN))
    screen.fresh(rows)  # a first call (or a later one: the result is the same)
    screen.fresh.py_func(twin)
    assert jit.numba_loaded()
    assert isinstance(robust.run, CPUDispatcher) and isinstance(contract.run_series, CPUDispatcher)
    assert gradient.to_fixed_tuple is to_fixed_tuple
    assert ekf_step.literally is numba.literally  # the placeholder is rebound too
    np.testing.assert_array_equal(rows, twin)  # NaN where the Python twin puts NaN


@pytest.mark.parametrize(
    ("wanted", "value", "ok"),
    [
        (("array", "float64", 2, "C", False), np.zeros((3, 2)), True),
        (("array", "float64", 2, "C", False), np.zeros((3, 2), dtype=np.float32), False),
        (("array", "float64", 2, "C", False), np.zeros((3, 2), order="F"), False),
        (("array", "float64", 2, "C", False), np.zeros((3, 4))[:, ::2], False),
        (("array", "float64", 2, "A", False), np.zeros((3, 4))[:, ::2], True),
        (("array", "float64", 2, "C", False), np.zeros(3), False),
        (("array", "float64", 1, "C", True), np.zeros(3), True),  # writeable where read-only
        (("array", "float64", 1, "C", False), np.zeros(3).view(), True),
        (("int64",), 3, True),
        (("int64",), 3.0, False),
        (("float64",), 3.0, True),
        (("bool",), True, True),
        (("int64",), True, False),
        (("uint16",), np.uint16(2), True),
        (("float64",), "3.0", False),
    ],
)
def test_a_build_takes_only_the_types_it_was_compiled_for(wanted, value, ok):
    assert aot._accepts(wanted, aot.arg_spec(value)) is ok


def test_a_read_only_array_is_refused_where_the_kernel_writes():
    frozen = np.zeros(3)
    frozen.flags.writeable = False
    assert not aot._accepts(("array", "float64", 1, "C", False), aot.arg_spec(frozen))
    assert aot._accepts(("array", "float64", 1, "C", True), aot.arg_spec(frozen))


def _kernel_for_test(x):
    return x


def _write_build(root: Path, name: str, manifest: dict) -> Path:
    folder = root / "aot" / name
    folder.mkdir(parents=True)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    return folder


def test_stale_corrupt_foreign_and_broken_builds_are_ignored(tmp_path, monkeypatch):
    monkeypatch.setenv("MARGTRACK_AOT", "1")
    monkeypatch.setenv("MARGTRACK_CACHE_DIR", str(tmp_path))
    kernel = jit.LazyKernel(_kernel_for_test, {"cache": True})
    source = Path(__file__)
    current = {
        "format": aot.MANIFEST_VERSION,
        "module": "margtrack_aot_test",
        "versions": aot._versions(),
        "sources": {str(source): hashlib.sha256(source.read_bytes()).hexdigest()},
        "exports": [{"kernel": kernel.key, "name": "k0", "args": [["float64"]]}],
    }
    assert aot._current(current, aot._versions())
    # a build whose module file is missing: found in the index, not loadable -> numba
    _write_build(tmp_path, "missing_module", current)
    # edited kernel sources, another numpy, a corrupt manifest
    _write_build(tmp_path, "stale", {**current, "sources": {str(source): "0" * 64}})
    _write_build(tmp_path, "foreign", {**current, "versions": {**current["versions"],
                                                               "numpy": "0.0"}})
    (tmp_path / "aot" / "corrupt").mkdir()
    (tmp_path / "aot" / "corrupt" / "manifest.json").write_text("{not json")
    aot.forget()
    try:
        index = aot._load_index()
        assert [e.folder.name for e in index.by_kernel[kernel.key]] == ["missing_module"]
        assert aot.find(kernel, (1.0,)) is None
        assert not aot._current(json.loads(
            (tmp_path / "aot" / "stale" / "manifest.json").read_text()), aot._versions())
        monkeypatch.setenv("MARGTRACK_AOT", "0")
        assert not aot.enabled() and aot.find(kernel, (1.0,)) is None
    finally:
        aot.forget()


def test_a_failed_build_is_remembered_and_not_retried(tmp_path, monkeypatch):
    monkeypatch.setenv("MARGTRACK_AOT", "1")
    monkeypatch.setenv("MARGTRACK_CACHE_DIR", str(tmp_path))
    from numba import types

    kernel = jit.LazyKernel(_kernel_for_test, {"cache": True})
    recorded = aot.Recorded()
    recorded.calls[(kernel.key, "f8")] = (kernel, types.float64(types.float64))
    aot.forget()
    try:
        assert aot.worth_building(recorded)
        aot.remember_failure(RuntimeError("no C compiler"))
        assert not aot.worth_building(recorded)
        note = json.loads((tmp_path / "aot" / "failed.json").read_text())
        assert note["error"] == "RuntimeError: no C compiler"
    finally:
        aot.forget()


def test_quick_start_build_serves_the_next_run_bit_for_bit_without_numba(tmp_path):
    """``margtrack run`` builds robust's kernels; the next process runs them without numba."""
    rec = sim.simulate_motion("random", duration_s=20.0, rate_hz=100.0, seed=3)
    io.write(rec, tmp_path / "rec.h5")
    env = {"MARGTRACK_AOT": "1", "MARGTRACK_CACHE_DIR": str(tmp_path / "cache")}
    first = _python(RUN_AND_REPORT, tmp_path, env, "out.h5")  # numba, then the build
    assert "NUMBA True" in first.stdout and AOT_MESSAGE in first.stdout + first.stderr
    (manifest,) = (tmp_path / "cache" / "aot").glob("*/manifest.json")
    built = {e["kernel"] for e in json.loads(manifest.read_text())["exports"]}
    assert "margtrack.kernels.robust:run" in built

    second = _python(RUN_AND_REPORT, tmp_path, env, "aot.h5")
    assert "NUMBA False" in second.stdout, second.stdout + second.stderr
    assert AOT_MESSAGE not in second.stdout + second.stderr  # nothing left to build
    with h5py.File(tmp_path / "out.h5") as a, h5py.File(tmp_path / "aot.h5") as b:
        assert np.array_equal(a["quat"][()], b["quat"][()])
        assert np.array_equal(a["flags"][()], b["flags"][()])


def test_stale_builds_are_removed_after_a_day_and_current_ones_kept(tmp_path, monkeypatch):
    monkeypatch.setenv("MARGTRACK_CACHE_DIR", str(tmp_path))
    versions = aot._versions()
    base = {"format": aot.MANIFEST_VERSION, "module": "m", "sources": {}, "exports": []}
    old_stale = _write_build(tmp_path, "old_stale", {**base, "versions": {"numpy": "0"}})
    new_stale = _write_build(tmp_path, "new_stale", {**base, "versions": {"numpy": "0"}})
    old_current = _write_build(tmp_path, "old_current", {**base, "versions": versions})
    day_ago = time.time() - aot.STALE_AFTER_S - 60
    for folder in (old_stale, old_current):
        os.utime(folder / "manifest.json", (day_ago, day_ago))
    aot._prune(versions)
    assert not old_stale.exists() and new_stale.exists() and old_current.exists()


def test_no_home_folder_means_no_builds_not_an_error(tmp_path, monkeypatch):
    monkeypatch.delenv("MARGTRACK_CACHE_DIR", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setenv("MARGTRACK_AOT", "1")

    def no_home() -> Path:
        raise RuntimeError("Could not determine home directory.")

    monkeypatch.setattr(Path, "home", staticmethod(no_home))
    aot.forget()
    try:
        assert aot.find(jit.LazyKernel(_kernel_for_test, {"cache": True}), (1.0,)) is None
    finally:
        aot.forget()
