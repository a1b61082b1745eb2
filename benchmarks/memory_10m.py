"""Peak memory of `margtrack run` on a 10-million-sample recording (HDF5 and CSV output).

Issue 16, part 4: a long recording is processed in chunks through the estimator state, so
the peak resident memory stays bounded (target: under 500 MB) whatever the length.

The recording is simulated random motion at 100 Hz (``margtrack.sim.simulate_motion``, one
block of ``--block-s`` seconds tiled with continuous timestamps), with magnetometer, truth
and movement mask, written chunk by chunk in margtrack's HDF5 layout to ``--folder``
(default /tmp/margtrack_memory; reused when it already has the right length). Each output
format is then produced by a separate ``margtrack run`` process under ``/usr/bin/time -v``,
which reports the maximum resident set size.

    python benchmarks/memory_10m.py                      # 10M samples, .h5 and .csv
    python benchmarks/memory_10m.py --samples 2000000 --formats h5
    python benchmarks/memory_10m.py --chunk-samples 10000000   # the whole file at once
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np

import margtrack as mt
from margtrack.io import hdf5

RATE_HZ = 100.0


def make_recording(path: Path, n_samples: int, block_s: float, seed: int) -> None:
    """Write ``n_samples`` of tiled simulated motion to ``path`` without holding them all."""
    if path.is_file():
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") == hdf5.RECORDING_FORMAT and f["t"].shape == (n_samples,):
                print(f"reusing {path} ({n_samples} samples)")
                return
    block = mt.sim.simulate_motion("random", duration_s=block_s, rate_hz=RATE_HZ, seed=seed)
    m = block.n_samples
    tmp = path.with_name(path.name + ".part")
    started = time.perf_counter()
    with h5py.File(tmp, "w") as f:
        f.attrs["format"] = hdf5.RECORDING_FORMAT
        f.attrs["version"] = hdf5.VERSION
        f.attrs["frame"] = block.frame
        f.attrs["name"] = f"tiled_random_{n_samples}"
        f.attrs["meta"] = json.dumps({"tiled_from": f"simulate_motion random {block_s} s"})
        widths = {"t": (), "gyr": (3,), "acc": (3,), "mag": (3,), "quat_true": (4,)}
        for name, shape in widths.items():
            f.create_dataset(name, shape=(n_samples, *shape), dtype="f8",
                             chunks=(65536, *shape))
        f.create_dataset("movement", shape=(n_samples,), dtype=bool, chunks=(65536,))
        for start in range(0, n_samples, m):
            k = min(m, n_samples - start)
            f["t"][start : start + k] = (start + np.arange(k)) / RATE_HZ
            for name in ("gyr", "acc", "mag", "quat_true", "movement"):
                f[name][start : start + k] = getattr(block, name)[:k]
    tmp.replace(path)
    size_mb = path.stat().st_size / 1e6
    print(f"wrote {path}: {n_samples} samples, {size_mb:.0f} MB in "
          f"{time.perf_counter() - started:.1f} s")


def measure(command: list[str]) -> tuple[float, float, str]:
    """Run ``command`` under /usr/bin/time -v: (peak RSS MB, wall s, its stdout)."""
    result = subprocess.run(["/usr/bin/time", "-v", *command], capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{result.stdout}\n{result.stderr}")
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", result.stderr)[1])
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)",
                     result.stderr)[1]
    seconds = 0.0
    for part in wall.split(":"):
        seconds = 60.0 * seconds + float(part)
    return rss_kb / 1024.0, seconds, result.stdout


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000_000)
    parser.add_argument("--folder", type=Path, default=Path("/tmp/margtrack_memory"))
    parser.add_argument("--formats", default="h5,csv", help="Output formats, comma-separated.")
    parser.add_argument("--method", default="default")
    parser.add_argument("--chunk-samples", type=int, default=1_000_000)
    parser.add_argument("--block-s", type=float, default=1200.0)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--keep", action="store_true", help="Keep the outputs.")
    args = parser.parse_args()
    args.folder.mkdir(parents=True, exist_ok=True)
    rec = args.folder / f"rec_{args.samples}.h5"
    make_recording(rec, args.samples, args.block_s, args.seed)
    exe = Path(sys.executable).with_name("margtrack")
    print(f"margtrack run -m {args.method} --chunk-samples {args.chunk_samples}, "
          f"{args.samples} samples; target peak RSS < 500 MB")
    for fmt in args.formats.split(","):
        out = args.folder / f"est_{args.samples}.{fmt}"
        rss_mb, seconds, text = measure([
            str(exe), "run", str(rec), "-o", str(out), "-m", args.method, "--force",
            "--chunk-samples", str(args.chunk_samples),
        ])
        size_mb = out.stat().st_size / 1e6
        print(f"  .{fmt}: peak RSS {rss_mb:.0f} MB, {seconds:.1f} s, "
              f"{args.samples / seconds:,.0f} samples/s, output {size_mb:.0f} MB")
        for line in text.strip().splitlines():
            print(f"    {line}")
        if not args.keep:
            out.unlink()


if __name__ == "__main__":
    main()
