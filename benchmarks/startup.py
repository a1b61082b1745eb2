"""Whole-process start-up: ``margtrack run`` on a 10k-sample file against a vqf script.

Run: ``python benchmarks/startup.py [--repeat 10] [--no-cold]``. Prints:

1. the median wall time of a new process running ``margtrack run rec.h5 -o out.h5``
   (warm cache: the warm-up run compiles what is missing into numba's cache), and of a
   Python script doing the same with vqf (read the HDF5 with h5py,
   ``VQF.updateBatch``, write the quaternions with h5py), and the ratios (target: at most
   3); measured with hyperfine when it is installed, else a loop of subprocesses;
2. the import time of what ``margtrack run`` loads (``python -X importtime``): the total
   and the largest packages, and whether numba, ``scipy.optimize`` and ``viser`` were loaded;
3. the floor of any numba program: a new process that imports numba and calls one
   trivial cached kernel (numba's import and its first cache load, which installs its
   typing registries and imports scipy.linalg for BLAS, cost this much whatever the kernel);
4. a cold-cache ``margtrack demo`` (``NUMBA_CACHE_DIR`` pointed at an empty temporary
   folder): seconds to its first line of output (target: 2 s) and to the end.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

VQF_SCRIPT = """\
import sys
import h5py
import numpy as np
from vqf import VQF

with h5py.File(sys.argv[1], "r") as f:
    t, gyr, acc, mag = (f[k][()] for k in ("t", "gyr", "acc", "mag"))
rate_hz = 1.0 / float(np.median(np.diff(t)))
quat = VQF(1.0 / rate_hz).updateBatch(
    *(np.ascontiguousarray(x) for x in (gyr, acc, mag)))["quat9D"]
with h5py.File(sys.argv[2], "w") as f:
    f.create_dataset("t", data=t)
    f.create_dataset("quat", data=quat)
print(f"vqf: {len(t)} samples -> {sys.argv[2]}")
"""


NUMBA_FLOOR_KERNEL = """\
from numba import njit


@njit(cache=True)
def twice(x):
    return 2.0 * x
"""


def margtrack_exe() -> str:
    """The ``margtrack`` console script of this interpreter's environment."""
    exe = Path(sys.executable).with_name("margtrack")
    if not exe.is_file():
        raise SystemExit(f"no margtrack script beside {sys.executable}: pip install -e .")
    return str(exe)


def median_wall_s(commands: dict[str, list[str]], repeat: int) -> dict[str, float]:
    """Median wall time (s) of ``repeat`` new processes of each command.

    With hyperfine each command is measured by hyperfine (one warm-up run); without it the
    commands are run in turns (a, b, c, a, b, c, ...) after one warm-up run each, so a
    change in the machine's load affects them alike.
    """
    hyperfine = shutil.which("hyperfine")
    if hyperfine:
        out: dict[str, float] = {}
        with tempfile.TemporaryDirectory() as tmp:
            for label, command in commands.items():
                result = Path(tmp) / "result.json"
                subprocess.run(
                    [hyperfine, "--warmup", "1", "--runs", str(repeat), "--export-json",
                     str(result), "--style", "none", shlex.join(command)],
                    check=True, capture_output=True,
                )
                out[label] = float(json.loads(result.read_text())["results"][0]["median"])
        return out
    for command in commands.values():  # warm-up: file caches, numba caches
        subprocess.run(command, check=True, capture_output=True)
    times: dict[str, list[float]] = {label: [] for label in commands}
    for _ in range(repeat):
        for label, command in commands.items():
            start = time.perf_counter()
            subprocess.run(command, check=True, capture_output=True)
            times[label].append(time.perf_counter() - start)
    return {label: statistics.median(values) for label, values in times.items()}


def import_profile(command_code: str) -> tuple[float, list[tuple[str, float]], set[str]]:
    """Total import seconds, the largest top-level packages, and the modules loaded."""
    code = command_code + "\nimport sys\nprint('MODULES', ' '.join(sorted(sys.modules)))"
    proc = subprocess.run([sys.executable, "-X", "importtime", "-c", code],
                          capture_output=True, text=True, check=False)
    per_top: dict[str, float] = {}
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        _, self_us, name = (p.strip() for p in line.removeprefix("import time:").split("|"))
        if not self_us.isdigit():
            continue
        top = name.split(".")[0]
        per_top[top] = per_top.get(top, 0.0) + int(self_us) / 1e6
    modules = set()
    for line in proc.stdout.splitlines():
        if line.startswith("MODULES "):
            modules = set(line.split()[1:])
    ranked = sorted(per_top.items(), key=lambda kv: -kv[1])
    return sum(per_top.values()), ranked[:8], modules


def cold_demo(duration_s: float) -> tuple[float, float, str]:
    """Seconds to the first output line and to the end of ``margtrack demo`` with no cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        start = time.perf_counter()
        proc = subprocess.Popen([margtrack_exe(), "demo", "--duration", f"{duration_s:g}"],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                env=env)
        assert proc.stdout is not None
        first_line = proc.stdout.readline()
        first_s = time.perf_counter() - start
        proc.stdout.read()
        proc.wait()
        total_s = time.perf_counter() - start
        if proc.returncode != 0:
            raise SystemExit(f"margtrack demo failed with exit code {proc.returncode}")
    return first_s, total_s, first_line.strip()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10, help="runs per command")
    parser.add_argument("--samples", type=int, default=10_000, help="recording length")
    parser.add_argument("--no-cold", action="store_true", help="skip the cold-cache demo")
    parser.add_argument("--demo-duration", type=float, default=10.0, help="demo length, s")
    args = parser.parse_args()

    from margtrack import io, sim

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rec_path, script = folder / "rec.h5", folder / "vqf_run.py"
        rate_hz = 100.0
        rec = sim.simulate_motion("random", duration_s=(args.samples - 1) / rate_hz,
                                  rate_hz=rate_hz, seed=0)
        io.write(rec, rec_path)
        script.write_text(VQF_SCRIPT)
        ours = [margtrack_exe(), "run", str(rec_path), "-o", str(folder / "out.h5")]
        theirs = [sys.executable, str(script), str(rec_path), str(folder / "vqf.h5")]
        if "--force" in subprocess.run([margtrack_exe(), "run", "--help"], capture_output=True,
                                       text=True).stdout:
            ours.append("--force")  # the output exists after the first run
        (folder / "floor_kernel.py").write_text(NUMBA_FLOOR_KERNEL)
        floor = [sys.executable, "-c", "import floor_kernel; floor_kernel.twice(1.0)"]
        tool = "hyperfine" if shutil.which("hyperfine") else "a subprocess loop, in turns"
        print(f"{rec.n_samples} samples at {rate_hz:g} Hz; median of {args.repeat} runs "
              f"({tool}), warm numba cache; load average {os.getloadavg()[0]:.1f} on "
              f"{os.cpu_count()} CPUs")
        old_cwd = os.getcwd()
        os.chdir(folder)  # the floor kernel's module and cache live in the temporary folder
        try:
            t = median_wall_s({"ours": ours, "vqf": theirs, "floor": floor},
                              args.repeat)
        finally:
            os.chdir(old_cwd)
        print(f"margtrack run : {t['ours']:.3f} s")
        print(f"vqf script    : {t['vqf']:.3f} s")
        print(f"ratio         : {t['ours'] / t['vqf']:.2f} (target <= 3)")
        print(f"numba floor   : {t['floor']:.3f} s (a new process calling one trivial cached "
              f"@njit kernel: ratio {t['floor'] / t['vqf']:.2f} to the vqf script)")

        total, ranked, modules = import_profile(
            "from margtrack.cli import app\n"
            f"app({['run', str(rec_path), '-o', str(folder / 'imp.h5')]!r}, "
            "standalone_mode=False)"
        )
        print(f"imports of `margtrack run`: {total:.3f} s (python -X importtime, self times)")
        for name, seconds in ranked:
            print(f"  {name:<12} {seconds:.3f} s")
        for heavy in ("numba", "scipy.optimize", "viser", "matplotlib", "dask"):
            print(f"  {heavy} loaded: {heavy in modules}")

    if not args.no_cold:
        first_s, total_s, line = cold_demo(args.demo_duration)
        print(f"cold `margtrack demo --duration {args.demo_duration:g}` (empty NUMBA_CACHE_DIR):"
              f" first line after {first_s:.2f} s (target <= 2), done after {total_s:.1f} s")
        print(f"  first line: {line!r}")


if __name__ == "__main__":
    main()
