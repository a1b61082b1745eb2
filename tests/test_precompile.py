"""margtrack.precompile and ``margtrack compile``: kernels into numba's cache ahead of use."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from margtrack.precompile import precompile

#: counts numba's compilations while a method is used as precompile uses it
COUNT_COMPILES = """\
import sys
import numba
import numba.core.event as event
from margtrack.precompile import _compile_method

class Count(event.Listener):
    n = ended = 0
    def on_start(self, ev):
        Count.n += 1
    def on_end(self, ev):
        Count.ended += 1

with event.install_listener("numba:compile", Count()):
    numba.njit(lambda x: x + 1)(1)  # not cached: one compilation, so the count is live
    assert Count.n == 1, Count.n
    for name in sys.argv[1:]:
        _compile_method(name)
assert Count.ended == Count.n, (Count.n, Count.ended)
print("COMPILED", Count.n - 1)
"""


def _run(args: list[str], cache: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    env.pop("NUMBA_DISABLE_JIT", None)
    proc = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env,
                          timeout=600, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc


def _compiles(names: list[str], cache: Path) -> int:
    out = _run(["-c", COUNT_COMPILES, *names], cache).stdout.split()
    return int(out[out.index("COMPILED") + 1])


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"),
                    reason="NUMBA_DISABLE_JIT: nothing compiles, nothing to cache")
def test_the_compile_command_fills_the_cache_so_later_processes_compile_nothing(tmp_path):
    cache = tmp_path / "numba"
    # (one method: each costs a process compiling its kernels for half a minute; the pool
    # of several is what the suite's own precompilation runs on, tests/conftest.py)
    proc = _run(["-c", "from margtrack.cli import app; app()", "compile", "triad",
                 "--jobs", "2"], cache)
    assert "1 method ready" in proc.stdout and "triad" in proc.stdout
    # processes started afterwards load every kernel from the cache
    assert _compiles(["triad"], cache) == 0


def test_an_unknown_method_is_refused_before_any_process_starts():
    with pytest.raises(ValueError, match=r"unknown method 'no-such'.*available: default"):
        precompile(["triad", "no-such"], jobs=2)


@pytest.mark.parametrize("jobs", [0, -1])
def test_jobs_below_one_are_refused(jobs):
    with pytest.raises(ValueError, match=f"jobs must be at least 1, got {jobs}"):
        precompile(["triad"], jobs=jobs)


def test_nothing_is_compiled_without_numba_jit(monkeypatch):
    monkeypatch.setenv("NUMBA_DISABLE_JIT", "1")
    assert precompile(["triad"]) == {}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["compile", "triad", "no-such"], "unknown method 'no-such'"),
        (["compile", "triad", "--jobs", "0"], "jobs must be at least 1, got 0"),
    ],
)
def test_the_command_refuses_bad_arguments_in_a_line(args, message):
    from typer.testing import CliRunner

    from margtrack.cli import app

    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2
    assert message in result.output
    assert "Traceback" not in result.output


def test_a_method_is_used_with_each_of_its_kernel_variants(monkeypatch):
    import margtrack.precompile as pre

    used = []
    monkeypatch.setattr(pre, "_use_variant", lambda name, params, *samples: used.append(
        (name, params, samples[0].shape)))
    pre._compile_method("ekf")
    pre._compile_method("gyro")
    assert used == [("ekf", {}, (400, 3)), ("ekf", {"bias_states": True}, (400, 3)),
                    ("gyro", {}, (400, 3))]


def test_the_pool_gets_the_longest_compilations_first_and_sums_a_methods_parts(monkeypatch):
    import margtrack.precompile as pre

    order = []

    def compile_group(units):
        order.append(units)
        return [10.0 if params else 1.0 for _, params in units]

    monkeypatch.setattr(pre, "_compile_group", compile_group)
    done = []
    seconds = pre.precompile(["triad", "bachmann", "bachmann-accmag", "ekf", "robust"], jobs=1,
                             progress=lambda name, s: done.append(name))
    # the methods with lockstep blocks first (the longest to compile); ekf and its
    # bias-state variant are two tasks (other kernels); bachmann and bachmann-accmag one
    # (the same kernels)
    assert sorted(order[:2]) == [[("bachmann", {}), ("bachmann-accmag", {})], [("robust", {})]]
    assert sorted(order[2:], key=str) == sorted([[("ekf", {})], [("ekf", {"bias_states": True})],
                                                 [("triad", {})]], key=str)
    assert seconds == {"triad": 1.0, "bachmann": 1.0, "bachmann-accmag": 1.0, "ekf": 11.0,
                       "robust": 1.0}
    assert sorted(done) == sorted(seconds) and done.count("ekf") == 1
