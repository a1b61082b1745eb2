"""Throughput of every recursive method on one long stream and on many sensors, against vqf.

Run ``python benchmarks/multi_sensor_speed.py [--sensors 1000] [--samples 1000]
[--stream 1000000] [--repeats 3]``.

Input: real BROAD samples (../shared/data/broad, 286 Hz; a simulated random motion when
the data are absent, said in the output). The many-sensor case takes ``--sensors``
windows of ``--samples`` samples at random places in the concatenated trials, one window
per sensor, sharing timestamps; the stream case is the concatenated trials tiled to
``--stream`` samples.

Measured in one run, wall clock (``time.perf_counter``), best of ``--repeats`` after a
warm-up call that compiles the kernels:

- margtrack ``create(method).run(gyr=, acc=, mag=, t=)`` on the (S, N, 3) arrays: one call,
  the sensors shared among the machine's threads (``estimator/sensor_threads.py``);
- vqf ``VQF(Ts).updateBatch(gyr, acc, mag)`` (C++), a Python loop over the same sensors,
  a fresh filter per sensor; the same for the stream.

Printed per method: M samples/s, ns per sample, the ratio to vqf (> 1: margtrack faster),
the same from the best CPU time of the process (all threads: ns of CPU per sample, the
steadier figure when the machine is shared),
and two floors in ns per sample for orientation: the memory floor (bytes a 9-D filter
must move per sample, 9 input and 4 output float64 = 104 bytes, over this machine's copy
bandwidth measured here with numpy) and the serial-chain floor (one quaternion
integration step per sample, a minimal numba loop over one stream, the shortest
dependent chain any filter has), each divided by the threads for the many-sensor case.
Also printed: the input screening alone (``estimator/screen_kernel.py``, which every method runs
before its own step) over the sensors' windows on one thread, and the load average before
and after (the machine may be shared: figures under load are slower).
"""

from __future__ import annotations

import argparse
import math
import os
import time
from collections.abc import Callable
from pathlib import Path

import numba
import numpy as np
from numba import njit

from margtrack import io, methods, sim

RATE_HZ = 285.714
BROAD = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "broad"
METHODS = ("gyro", "gradient", "bachmann", "robust", "ekf", "bias-kf")
BYTES_PER_SAMPLE = (9 + 4) * 8


def samples() -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """gyr, acc, mag (N, 3) of the concatenated BROAD trials (or a simulation)."""
    if BROAD.is_dir() and any(BROAD.glob("*.hdf5")):
        recs = [io.read_broad(t.path) for t in io.broad_trials(BROAD)]
        cat = [np.concatenate([getattr(r, k) for r in recs]) for k in ("gyr", "acc", "mag")]
        return cat[0], cat[1], cat[2], f"{len(recs)} BROAD trials"
    rec = sim.simulate_motion("random", duration_s=600.0, rate_hz=RATE_HZ, seed=1)
    return rec.gyr, rec.acc, rec.mag, "simulated random motion (BROAD absent)"


def best_times(func: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Best wall time and best CPU time (this process, all threads) of ``repeats`` calls
    after one warm-up call, s. On a loaded machine the CPU time is the steadier figure."""
    func()
    best = best_cpu = math.inf
    for _ in range(repeats):
        start, cpu = time.perf_counter(), time.process_time()
        func()
        best = min(best, time.perf_counter() - start)
        best_cpu = min(best_cpu, time.process_time() - cpu)
    return best, best_cpu


def best_seconds(func: Callable[[], object], repeats: int) -> float:
    """Best wall time of ``repeats`` calls after one warm-up call."""
    return best_times(func, repeats)[0]


@njit(cache=True)
def _integrate(gyr, dt, out):
    """Quaternion integration, one sample after the other: the serial-chain floor."""
    w, x, y, z = 1.0, 0.0, 0.0, 0.0
    for i in range(gyr.shape[0]):
        hx, hy, hz = 0.5 * dt * gyr[i, 0], 0.5 * dt * gyr[i, 1], 0.5 * dt * gyr[i, 2]
        w, x, y, z = (w - x * hx - y * hy - z * hz, x + w * hx + y * hz - z * hy,
                      y + w * hy - x * hz + z * hx, z + w * hz + x * hy - y * hx)
        n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w * n, x * n, y * n, z * n
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = w, x, y, z


def floors_ns(gyr: np.ndarray, repeats: int) -> tuple[float, float]:
    """(memory floor, serial-chain floor) in ns per sample on one thread."""
    big = np.random.default_rng(0).normal(size=(8_000_000,))
    dst = np.empty_like(big)
    seconds = best_seconds(lambda: np.copyto(dst, big), repeats)
    bandwidth = 2 * big.nbytes / seconds  # read + write
    out = np.empty((gyr.shape[0], 4))
    chain = best_seconds(lambda: _integrate(gyr, 1.0 / RATE_HZ, out), repeats)
    return 1e9 * BYTES_PER_SAMPLE / bandwidth, 1e9 * chain / gyr.shape[0]


def print_floors(gyr: np.ndarray, repeats: int = 3) -> None:
    """Print the two floors (one thread) for the rates of ``gyr`` (N, 3); for the other
    speed benchmarks, so each shows its ns/sample beside them."""
    memory_ns, chain_ns = floors_ns(np.ascontiguousarray(gyr), repeats)
    print(f"floors per sample, one thread: memory {memory_ns:.1f} ns ({BYTES_PER_SAMPLE} B at "
          f"the measured copy bandwidth), serial chain {chain_ns:.1f} ns (quaternion "
          "integration); load average " + " ".join(f"{x:.2f}" for x in os.getloadavg()))


def screening_ns(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, repeats: int) -> float:
    """ns per sample of the input screening alone over (S, N, 3) arrays, one thread."""
    from margtrack.estimator import screen_kernel as screen

    coef = methods.create("bachmann")._coefs[: screen.N_COEF].copy()
    n = gyr.shape[1]
    dts = np.full(n, 1.0 / RATE_HZ)
    dts[0] = 0.0
    tflags = np.zeros(n, dtype=np.int64)
    outs = [np.empty_like(gyr) for _ in range(3)]
    flags = np.empty(gyr.shape[:2], dtype=np.uint16)
    state = np.empty((gyr.shape[0], screen.N_SCREEN))

    def run() -> None:
        screen.fresh(state)
        screen.screen_samples(coef, dts, tflags, gyr, acc, mag, True, True, state, *outs, flags)

    return 1e9 * best_seconds(run, repeats) / flags.size


def vqf_batch(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray) -> Callable[[], object]:
    """A fresh vqf filter per sensor over (S, N, 3) arrays, one updateBatch each."""
    from vqf import VQF

    def run() -> object:
        for s in range(gyr.shape[0]):
            VQF(1.0 / RATE_HZ).updateBatch(gyr[s], acc[s], mag[s])
        return None

    return run


def margtrack_run(name: str, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray,
                  t: np.ndarray) -> Callable[[], object]:
    """One ``run`` of a fresh estimator over (S, N, 3) arrays."""
    return lambda: methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=t, check_units=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensors", type=int, default=1000)
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--stream", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--methods", default=",".join(METHODS))
    args = parser.parse_args()

    gyr, acc, mag, source = samples()
    rng = np.random.default_rng(0)
    starts = rng.integers(0, gyr.shape[0] - args.samples, args.sensors)
    windows = [np.ascontiguousarray(np.stack([x[s:s + args.samples] for s in starts]))
               for x in (gyr, acc, mag)]
    reps = -(-args.stream // gyr.shape[0])
    stream = [np.ascontiguousarray(np.tile(x, (reps, 1))[: args.stream]) for x in (gyr, acc, mag)]
    t_many = np.arange(args.samples) / RATE_HZ
    t_stream = np.arange(args.stream) / RATE_HZ
    threads = numba.get_num_threads()
    memory_ns, chain_ns = floors_ns(stream[0], args.repeats)
    print(f"input: {source}; {args.sensors} sensors x {args.samples} samples, and one stream "
          f"of {args.stream:,} samples; {threads} numba threads on {os.cpu_count()} CPUs")
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"floors per sample, one thread: memory {memory_ns:.1f} ns ({BYTES_PER_SAMPLE} B), "
          f"serial chain {chain_ns:.1f} ns (quaternion integration)")
    print(f"input screening alone, one thread: {screening_ns(*windows, args.repeats):.1f} ns "
          "per sample (every method runs it before its step)")
    n_many = args.sensors * args.samples
    try:
        vqf_many, vqf_many_cpu = best_times(vqf_batch(*windows), args.repeats)
        vqf_one, vqf_one_cpu = best_times(vqf_batch(*(x[None] for x in stream)), args.repeats)
    except ImportError:
        vqf_many = vqf_one = vqf_many_cpu = vqf_one_cpu = math.nan
        print("vqf is not installed (pip install vqf): no ratios")
    print(f"vqf: {n_many / vqf_many / 1e6:.2f} M/s over the sensors, "
          f"{args.stream / vqf_one / 1e6:.2f} M/s one stream; CPU ns/sample "
          f"{1e9 * vqf_many_cpu / n_many:.1f} and {1e9 * vqf_one_cpu / args.stream:.1f}")
    header = (f"{'method':<10}{'sensors M/s':>12}{'ns/sample':>10}{'x vqf':>7}"
              f"{'stream M/s':>12}{'ns/sample':>10}{'x vqf':>7}"
              f"{'CPU ns: sensors':>17}{'x vqf':>7}{'stream':>8}{'x vqf':>7}")
    print(header)
    for name in args.methods.split(","):
        many, many_cpu = best_times(margtrack_run(name, *windows, t_many), args.repeats)
        one, one_cpu = best_times(margtrack_run(name, *stream, t_stream), args.repeats)
        print(f"{name:<10}{n_many / many / 1e6:>12.2f}{1e9 * many / n_many:>10.1f}"
              f"{vqf_many / many:>7.2f}{args.stream / one / 1e6:>12.2f}"
              f"{1e9 * one / args.stream:>10.1f}{vqf_one / one:>7.2f}"
              f"{1e9 * many_cpu / n_many:>17.1f}{vqf_many_cpu / many_cpu:>7.2f}"
              f"{1e9 * one_cpu / args.stream:>8.1f}{vqf_one_cpu / one_cpu:>7.2f}")
    print(f"floors with {threads} threads over the sensors: memory {memory_ns / threads:.1f} ns, "
          f"serial chain {chain_ns / threads:.1f} ns; one stream: {memory_ns:.1f} and "
          f"{chain_ns:.1f} ns")
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
