"""Start-up and a default install: lazy imports, the compile notice, completion, LICENSE, peers.

Properties, not timings (the figures are in benchmarks/startup.py).
"""

from __future__ import annotations

import io as stdio
import json
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console
from typer.testing import CliRunner

import margtrack
from margtrack import io, sim
from margtrack.cli import LAZY_COMMANDS, app
from margtrack.cli.compiling import MESSAGE, compile_notice

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("scipy.optimize", "viser", "matplotlib", "dask", "margtrack.calibration",
         "margtrack.live")


def _modules_after(code: str, cwd: Path) -> set[str]:
    """The modules a new interpreter has loaded after running ``code``."""
    script = code + "\nimport sys, json\nprint('MODULES=' + json.dumps(sorted(sys.modules)))"
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          cwd=cwd, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    line = next(x for x in proc.stdout.splitlines() if x.startswith("MODULES="))
    return set(json.loads(line.removeprefix("MODULES=")))


def test_run_in_a_new_process_imports_neither_calibration_nor_the_viewer(tmp_path):
    rec = sim.simulate_motion("random", duration_s=2.0, rate_hz=100.0, seed=0)
    io.write(rec, tmp_path / "rec.h5")
    loaded = _modules_after(
        "from margtrack.cli import app\n"
        "app(['run', 'rec.h5', '-o', 'out.h5'], standalone_mode=False)", tmp_path)
    assert (tmp_path / "out.h5").is_file()
    assert "margtrack.methods.robust" in loaded  # the run really happened in that process
    assert not [m for m in HEAVY if m in loaded], [m for m in HEAVY if m in loaded]


def test_help_imports_no_numba_and_lists_the_lazy_commands(tmp_path):
    loaded = _modules_after(
        "from margtrack.cli import app\n"
        "try:\n    app(['--help'])\nexcept SystemExit:\n    pass", tmp_path)
    assert "numba" not in loaded and "h5py" not in loaded
    assert not [m for m in HEAVY if m in loaded]
    text = CliRunner().invoke(app, ["--help"]).output
    for name, (help_text, _) in LAZY_COMMANDS.items():
        assert name in text and help_text.split()[0] in text


def test_lazy_commands_load_when_run():
    runner = CliRunner()
    calibrate = runner.invoke(app, ["calibrate", "--help"])
    assert calibrate.exit_code == 0
    for sub in ("guided", "accel", "gyro", "allan"):
        assert sub in calibrate.output
    live = runner.invoke(app, ["live", "--help"])
    assert live.exit_code == 0 and "--replay" in live.output
    wrong = runner.invoke(app, ["calibrate", "nonsense"])
    assert wrong.exit_code == 2 and "nonsense" in wrong.output
    run = runner.invoke(app, ["live", "--demo", "--preset", "left_arm", "--motion", "wave",
                              "--speed", "20", "--duration", "0.5", "--headless"])
    assert run.exit_code == 0, run.output
    assert "simulator: 1 person (wave, left_arm): 3 sensors" in run.output


def test_compile_notice_shows_only_while_numba_compiles():
    from numba import njit

    @njit(cache=False)
    def add_one(x):
        return x + 1.0

    out = stdio.StringIO()
    console = Console(file=out, force_terminal=False)
    with compile_notice(console) as notice:
        assert add_one(1.0) == 2.0  # compiles now
        assert add_one(2.0) == 3.0  # compiled: no event
    assert out.getvalue().count(MESSAGE) == 1
    assert len(notice.kernels) == 1 and notice.kernels[0].endswith("add_one")
    assert notice.depth == 0
    out2 = stdio.StringIO()
    with compile_notice(Console(file=out2, force_terminal=False)) as again:
        assert add_one(5.0) == 6.0
    assert out2.getvalue() == "" and again.kernels == []


def test_compile_notice_names_each_stage_that_compiles():
    """A long command (``demo``) names the stage being compiled, one line per stage in a
    log; a stage that compiles nothing prints nothing."""
    from numba import njit

    @njit(cache=False)
    def first(x):
        return x + 1.0

    @njit(cache=False)
    def second(x):
        return x * 2.0

    out = stdio.StringIO()
    with compile_notice(Console(file=out, force_terminal=False, width=200)) as notice:
        for n, kernel in enumerate((first, second, first), 1):
            notice.stage = f"stage {n} of 3"
            kernel(1.0)
            kernel(2.0)
    lines = out.getvalue().splitlines()
    assert lines == [f"{MESSAGE}: stage 1 of 3...", f"{MESSAGE}: stage 2 of 3..."]


def test_compile_notice_is_silent_on_a_cache_hit(tmp_path):
    """A cold cache prints the notice, the next process loads the cache and prints nothing."""
    (tmp_path / "kern.py").write_text(textwrap.dedent("""\
        from numba import njit

        @njit(cache=True)
        def twice(x):
            return 2.0 * x
        """))
    code = textwrap.dedent("""\
        import sys
        from rich.console import Console
        from margtrack.cli.compiling import compile_notice
        import kern
        with compile_notice(Console(file=sys.stdout, force_terminal=False)) as n:
            assert kern.twice(2.0) == 4.0
        print("KERNELS", n.kernels)
        """)
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PATH": "/usr/bin:/bin"}
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           cwd=tmp_path, env=env, timeout=300, check=True) for _ in range(2)]
    assert MESSAGE in runs[0].stdout and "kern.twice" in runs[0].stdout
    assert MESSAGE not in runs[1].stdout and "KERNELS []" in runs[1].stdout


def test_commands_that_run_kernels_carry_the_notice():
    from margtrack.cli import COMPILING_COMMANDS

    wrapped = {info.name or info.callback.__name__: info.callback
               for info in app.registered_commands}
    for name in ("run", "evaluate", "plot"):
        assert name in COMPILING_COMMANDS
        assert getattr(wrapped[name], "compile_notice", False), name


def test_dir_lists_the_api_for_completion():
    names = dir(margtrack)
    for name in ("create", "io", "sim", "body", "Recording", "quaternion", "frames",
                 "available_methods", "__version__"):
        assert name in names
    assert set(margtrack.__all__) <= set(names)
    for name in names:  # everything listed resolves
        assert getattr(margtrack, name) is not None


def test_license_is_mit_in_the_repository_and_declared_for_the_wheel():
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert text.startswith("MIT License") and "2026 margtrack developers" in text
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert project["license"] == "MIT" and project["license-files"] == ["LICENSE"]


@pytest.fixture
def two_broad_trials(broad_folder, tmp_path):
    """A BROAD folder with one undisturbed and one disturbed trial (links, not copies)."""
    index = json.loads((broad_folder / "trials.json").read_text(encoding="utf-8"))
    keep = [next(n for n in sorted(index["trials"]) if "undisturbed" in n),
            next(n for n in sorted(index["trials"]) if "_disturbed" in n)]
    index["trials"] = {n: index["trials"][n] for n in keep}
    folder = tmp_path / "broad"
    folder.mkdir()
    (folder / "trials.json").write_text(json.dumps(index), encoding="utf-8")
    for name in keep:
        (folder / f"{name}.hdf5").symlink_to(broad_folder / f"{name}.hdf5")
    return folder


def test_bench_broad_without_the_peer_libraries(two_broad_trials, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "vqf", None)  # `import vqf` now fails as if not installed
    with pytest.raises(ImportError):
        import vqf  # noqa: F401
    result = CliRunner().invoke(app, ["bench", "broad", str(two_broad_trials), "-m", "triad",
                                      "--external", "vqf", "--out", str(tmp_path / "b.png")])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "vqf is not installed" in text and "pip install vqf" in text
    assert "margtrack[dev]" in text and "Traceback" not in text
    rows = [line for line in result.output.splitlines() if line.startswith("│ triad")]
    assert len(rows) == 3  # all trials, undisturbed, disturbed
    total = float(rows[0].split("│")[2])
    assert np.isfinite(total) and 0.0 < total < 180.0
    assert (tmp_path / "b.png").is_file()
