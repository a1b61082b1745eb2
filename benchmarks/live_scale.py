"""How many sensors the live engine sustains in real time at 100 Hz, and what limits it.

For each method (Bachmann's filter ``bachmann``, 000 Appendix A, and the default method,
``robust``), in one run on this machine:

1. filter rates on one batch as the engine runs it, S = 100000 sensors x 4 frames: the
   kernel's multi-sensor entry alone (the one ``run_into`` takes: ``kernel.lanes``,
   sensors in lockstep blocks, for a method that has it, else ``kernel.run``, over threads
   with the sensors shared among them, ``estimator/sensor_threads.py``) on
   prepared arrays, the engine's hot path (``CompiledEstimator.run_into``: reused buffers,
   the state in place) and the public ``run`` (validation, input and state copies, new
   outputs); whether the kernel call runs on both cores (the CPU time of the threads other
   than the caller); the hot path's rate for batches of 1 to 16 frames;
2. throughput: the engine fed as fast as it takes (an unpaced replay, 4 frames a batch,
   25 Hz display, every person's body model) at the largest S tried, in CPU and wall time:
   the sensors it could carry at 100 Hz if nothing else ran on the machine;
3. real-time runs: simulated people (``PeopleSimulation``, 15 sensors each, walking, MEMS
   noise) tiled to S sensors and replayed at real speed (``ReplaySource``, 100 Hz, looping)
   into an ``Engine`` with the body model of every person, a 25 Hz display clock and one
   subscriber, for ``--seconds`` s. S is *sustained* when at the end the engine is less than
   0.1 s of session time behind real time and the 95th percentile of the published poses'
   latency (frame arrival to publishing) is under 0.1 s; a failed run is repeated once
   (the machine is shared). S doubles until a run fails, then the gap is bisected;
4. where the time goes at the largest sustained S: the worker's busy time split into the
   filters (the estimator's ``run`` and the per-sensor isolation around it), the body model
   (000 eqs. 7, 11 for every person at 25 Hz), publishing, and polling / assembling frames;
   with ``--profile``, a cProfile of an unpaced run at that S: its top entries and the
   filters' time split into the kernel, the rest of ``run_into`` (its O(1) checks) and the
   live code around it (copies of inputs that are not contiguous, holds, counts).

The machine is shared: the load average is printed beside every figure (2 cores here; a
load above 2 means other processes took CPU from the engine and its figures are lower
bounds). The paper's system ran 3 real + 13 simulated sensors at 100 Hz on an 866 MHz
Pentium III.

Run: python benchmarks/live_scale.py [--seconds 3] [--methods bachmann default] [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import math
import os
import pstats
import time

import numpy as np

from margtrack import methods
from margtrack.estimator.compiled import PARALLEL_MIN_SAMPLES
from margtrack.live.engine import Engine
from margtrack.live.replay import ReplaySource
from margtrack.live.simulator import PeopleSimulation
from margtrack.sim import DEFAULT_DIP_DEG

RATE_HZ = 100.0
LOOP_FRAMES = 50  # 0.5 s of motion, replayed in a loop (memory: S x 50 x 9 doubles)
BASE_PEOPLE = 8


def load() -> str:
    """The 1-minute load average, as text."""
    return f"load {os.getloadavg()[0]:.1f}"


def params(method: str) -> dict[str, float]:
    """Bachmann's filter is given the simulated dip as its reference (as a calibration
    would): measured from a first sample taken in motion it would be off."""
    return {"mag_dip_ref_deg": DEFAULT_DIP_DEG} if methods.get(method).name == "bachmann" else {}


def base_signals() -> tuple[np.ndarray, ...]:
    """0.5 s of 8 walking people (120 sensors), after the start ramp."""
    people = PeopleSimulation(n_people=BASE_PEOPLE, rate_hz=RATE_HZ, seed=11)
    t, gyr, acc, mag = people.signals(400, LOOP_FRAMES)
    return t, gyr, acc, mag, people.skeleton.names


def tiled_source(base: tuple[np.ndarray, ...], n_people: int, speed: float = 1.0,
                 chunk_frames: int | None = None) -> ReplaySource:
    t, gyr, acc, mag, segments = base
    reps = -(-n_people // BASE_PEOPLE)
    k = len(segments)

    def tile(x: np.ndarray) -> np.ndarray:
        return np.tile(x, (reps, 1, 1))[: n_people * k]

    names = [f"p{a}/{s}" for a in range(n_people) for s in segments]
    return ReplaySource(t, tile(gyr), tile(acc), tile(mag), names, speed=speed, loop=True,
                        chunk_frames=chunk_frames, description=f"{n_people} simulated people")


def filter_rates(method: str, n_sensors: int = 100_000, n: int = 4) -> dict[str, float]:
    """Samples/s of one batch as the engine runs it (S sensors x ``n`` frames a call).

    ``kernel``: the kernel's entry alone on prepared arrays; ``run_into``: the engine's
    hot path (:meth:`CompiledEstimator.run_into`: O(1) checks, reused buffers, the state in
    place); ``run``: the public ``run`` (validation, input and state copies, new outputs);
    ``other_threads``: the share of the hot path's CPU time spent outside the calling
    thread (about 0.5 when both cores share the kernel, 0 when it runs on one);
    ``cpu_per_wall``: CPU time over wall time of the hot path (2 on two free cores).
    """
    rng = np.random.default_rng(0)
    gyr = rng.normal(0, 0.5, (n_sensors, n, 3))
    acc = rng.normal(0, 0.5, (n_sensors, n, 3)) + [0.0, 0.0, 9.81]
    mag = rng.normal(0, 0.5, (n_sensors, n, 3)) + [0.0, 25.0, -43.0]
    est = methods.create(method, params(method))
    # as the engine asks: no extra outputs (the lockstep blocks then write none; the
    # per-sensor kernels, called directly below, write every one)
    width = 0 if est._in_lanes(n_sensors) else est.run_width
    q, x = np.empty((n_sensors, n, 4)), np.empty((n_sensors, n, width))
    flags = np.empty((n_sensors, n), dtype=np.uint16)
    reps = 10
    series = iter([np.arange(n) / RATE_HZ + r * n / RATE_HZ for r in range(4 * reps + 4)])
    est.run(gyr=gyr, acc=acc, mag=mag, t=next(series), check_units=False)  # compile / load
    out = {}
    start = time.perf_counter()
    for _ in range(reps):
        est.run(gyr=gyr, acc=acc, mag=mag, t=next(series), check_units=False)
    out["run"] = reps * n_sensors * n / (time.perf_counter() - start)
    est.run_into(next(series), gyr, acc, mag, q, x, flags)
    wall, cpu, own = time.perf_counter(), time.process_time(), time.thread_time()
    for _ in range(reps):
        est.run_into(next(series), gyr, acc, mag, q, x, flags)
    wall, cpu, own = (time.perf_counter() - wall, time.process_time() - cpu,
                      time.thread_time() - own)
    out["run_into"] = reps * n_sensors * n / wall
    out["other_threads"] = (cpu - own) / cpu
    out["cpu_per_wall"] = cpu / wall
    state = est.state
    times = [next(series) for _ in range(reps + 1)]  # no gap
    for a in (gyr, acc, mag, *times):  # as run() passes them: the same specialisation
        a.flags.writeable = False
    parallel = n_sensors * n >= PARALLEL_MIN_SAMPLES
    # the kernel call run_into makes
    est._run_kernel(state.rows, state.clock, times[0], gyr, acc, mag, 3, q, x, flags,
                    parallel=parallel)
    start = time.perf_counter()
    for t in times[1:]:
        est._run_kernel(state.rows, state.clock, t, gyr, acc, mag, 3, q, x, flags,
                        parallel=parallel)
    out["kernel"] = reps * n_sensors * n / (time.perf_counter() - start)
    return out


def batch_scan(method: str, n_sensors: int = 100_000,
               frames: tuple[int, ...] = (1, 2, 4, 8, 16)) -> dict[int, float]:
    """Samples/s of the engine's hot path (``run_into``) for batches of each number of
    frames of ``n_sensors`` sensors: whether larger batches would help."""
    rng = np.random.default_rng(1)
    est = methods.create(method, params(method))
    out, t0 = {}, 0.0
    for n in frames:
        gyr = rng.normal(0, 0.5, (n_sensors, n, 3))
        acc = rng.normal(0, 0.5, (n_sensors, n, 3)) + [0.0, 0.0, 9.81]
        mag = rng.normal(0, 0.5, (n_sensors, n, 3)) + [0.0, 25.0, -43.0]
        q, x = np.empty((n_sensors, n, 4)), np.empty((n_sensors, n, 0))  # as the engine
        flags = np.empty((n_sensors, n), dtype=np.uint16)
        reps = max(32 // n, 2)
        for r in range(reps + 1):
            if r == 1:
                start = time.perf_counter()
            t = t0 + np.arange(n) / RATE_HZ
            t0 = float(t[-1]) + 1.0 / RATE_HZ
            est.run_into(t, gyr, acc, mag, q, x, flags)
        out[n] = reps * n_sensors * n / (time.perf_counter() - start)
    return out


def throughput(method: str, base: tuple[np.ndarray, ...], n_people: int, frames: int = 200,
               profile: bool = False) -> dict:
    """The engine unpaced (4 frames a batch): frames per second of CPU and of wall time."""
    source = tiled_source(base, n_people, speed=math.inf, chunk_frames=4)
    engine = Engine(source.info, method, params(method), display_hz=25.0)
    engine.subscribe(lambda pose: None)
    source.open()
    for _ in range(30):  # warm-up past the first second (the magnetic norm references)
        engine.push(source.poll(0.0))
    profiler = cProfile.Profile() if profile else None
    wall, cpu, done = time.perf_counter(), time.process_time(), 0
    if profiler is not None:
        profiler.enable()
    while done < frames:
        chunks = source.poll(0.0)
        done += chunks[0].n_frames
        engine.push(chunks)
    if profiler is not None:
        profiler.disable()
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    n_sensors = source.info.n_sensors
    out = {"sensors": n_sensors, "frames": done, "wall_s": wall, "cpu_s": cpu,
           "wall_sensors": n_sensors * done / wall / RATE_HZ,
           "cpu_sensors": n_sensors * done / cpu / RATE_HZ * os.cpu_count(),
           "stats": engine.stats()}
    if profiler is not None:
        text = io.StringIO()
        pstats.Stats(profiler, stream=text).sort_stats("tottime").print_stats(10)
        out["profile"] = text.getvalue()
        out["split"] = profile_split(profiler, done)
    return out


def realtime(method: str, base: tuple[np.ndarray, ...], n_people: int, seconds: float) -> dict:
    """One real-time run of ``n_people`` x 15 sensors; its figures."""
    source = tiled_source(base, n_people)
    engine = Engine(source.info, method, params(method), display_hz=25.0)
    engine.subscribe(lambda pose: None)
    engine.start(source)
    try:
        time.sleep(seconds)
        now = time.perf_counter()
        behind_s = (now - source.started_s) - engine.session_time_s  # session: 0 at start
        stats = engine.stats()
    finally:  # far behind, the worker may be in a long catch-up batch: let it end
        engine.stop(timeout_s=600.0)
    busy = stats.time_filter_s + stats.time_body_s + stats.time_publish_s
    return {
        "sensors": source.info.n_sensors,
        "people": n_people,
        "behind_s": behind_s,
        "p50_ms": stats.latency_p50_s * 1e3,
        "p95_ms": stats.latency_p95_s * 1e3,
        "frames": stats.frames,
        "batches": stats.batches,
        "ok": behind_s < 0.1 and stats.latency_p95_s < 0.1 and not stats.error,
        "stats": stats,
        "busy_s": busy + stats.time_assemble_s,
        "wall_s": seconds,
        "error": stats.error,
        "load": load(),
    }


def row(r: dict) -> str:
    return (f"  {r['sensors']:>7} sensors ({r['people']:>5} people): "
            f"behind {r['behind_s']:7.3f} s, "
            f"latency p50 {r['p50_ms']:7.1f} ms p95 {r['p95_ms']:7.1f} ms, {r['frames']} frames "
            f"in {r['batches']} batches -> {'sustained' if r['ok'] else 'NOT sustained'} "
            f"[{r['load']}]" + (f" ({r['error']})" if r["error"] else ""))


def tried(method: str, base: tuple[np.ndarray, ...], n_people: int, seconds: float) -> dict:
    """A real-time run, repeated once if it failed (the machine is shared: a run fails when
    other processes take the CPU for long enough)."""
    r = realtime(method, base, n_people, seconds)
    print(row(r), flush=True)
    if not r["ok"]:
        r = realtime(method, base, n_people, seconds)
        print(row(r) + " (repeated)", flush=True)
    return r


def search(method: str, base: tuple[np.ndarray, ...], seconds: float, start: int,
           max_people: int) -> dict | None:
    """Largest sustained people count by doubling (the last step capped at ``max_people``),
    then bisection (module docstring)."""
    n, best, worst = start, None, None
    while True:
        r = tried(method, base, n, seconds)
        if not r["ok"]:
            worst = n
            break
        best = r
        if n >= max_people:
            break
        n = min(2 * n, max_people)
    lo = best["people"] if best else 0
    hi = worst if worst else lo
    for _ in range(3):
        if hi - lo <= max(lo // 8, 1):
            break
        mid = (lo + hi) // 2
        r = tried(method, base, mid, seconds)
        if r["ok"]:
            best, lo = r, mid
        else:
            hi = mid
    return best


def breakdown(best: dict) -> str:
    """The worker's measured time split of a real-time run."""
    st = best["stats"]
    wall = best["wall_s"]
    parts = {
        "filters (estimator run + isolation)": st.time_filter_s,
        "body model + recording": st.time_body_s,
        "publishing": st.time_publish_s,
        "source polling + frame assembly": st.time_assemble_s,
    }
    lines = [f"  worker busy {best['busy_s'] / wall * 100:.0f} % of {wall:.1f} s wall time:"]
    for name, seconds in parts.items():
        lines.append(f"    {name:<36} {seconds / wall * 100:5.1f} % of wall time "
                     f"({seconds / max(st.frames, 1) * 1e3:.3f} ms per frame)")
    return "\n".join(lines)


def profile_split(profiler: cProfile.Profile, frames: int) -> str:
    """Where an unpaced run's time went, from its cProfile (cumulative times per layer)."""
    entries = pstats.Stats(profiler).stats  # (file, line, name) -> (cc, nc, tt, ct, callers)

    def total(path: str, name: str, own: bool = False) -> float:
        return sum(v[2] if own else v[3] for (f, _, n), v in entries.items()
                   if f.endswith(path) and n == name)

    # the kernel called by run_into itself, or over threads (run_threaded, its wall time
    # in this thread: the calling thread's part and the wait for the others)
    kernel = sum(t for (f, _, n), v in entries.items()
                 if "/methods/" in f and n in ("run", "lanes")
                 for (cf, _, cn), (_, _, t, _) in v[4].items()
                 if not (cf.endswith("sensor_threads.py") and cn == "part"))
    kernel += total("estimator/sensor_threads.py", "run_threaded")
    run = (total("estimator/compiled.py", "run_into") + total("estimator/compiled.py",
                                                             "_run_arrays")
           or total("estimator/contract.py", "run"))
    filters = total("live/filtering.py", "run")
    pose = total("live/avatars.py", "pose")
    push = total("live/engine.py", "push")
    process = total("live/engine.py", "process")
    parts = {
        "filter kernel (numba, threads)": kernel,
        "estimator run_into() around the kernel": run - kernel,
        "live filtering around it (input copies)": filters - run,
        "body model (every person)": pose,
        "rest of the batch (stats, hooks)": process - filters - pose,
        "source polling + frame assembly": push - process,
    }
    lines = [f"  profile split of {push:.2f} s in push() ({frames} frames):"]
    for name, seconds in parts.items():
        lines.append(f"    {name:<36} {seconds / push * 100:5.1f} % "
                     f"({seconds / frames * 1e3:.3f} ms per frame)")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="length of each real-time run")
    parser.add_argument("--methods", nargs="+", default=["bachmann", "default"])
    parser.add_argument("--start-people", type=int, default=100)
    parser.add_argument("--max-people", type=int, default=16000)
    parser.add_argument("--throughput-people", type=int, default=4000,
                        help="people (x15 sensors) of the unpaced throughput run")
    parser.add_argument("--profile", action="store_true",
                        help="cProfile an unpaced run at the largest sustained S")
    args = parser.parse_args()
    base = base_signals()
    print(f"live engine scale at {RATE_HZ:.0f} Hz, 15 sensors per person, display 25 Hz, "
          f"{args.seconds} s real-time runs, {os.cpu_count()} CPUs, {load()}")
    from multi_sensor_speed import print_floors  # the sibling benchmark's floors

    print_floors(base[1].reshape(-1, 3))  # the simulated people's rates, one after another
    summary = []
    for method in args.methods:
        name = methods.get(method).name
        rates = filter_rates(method)
        kernel_rate = rates["kernel"]
        print(f"\n{name}: one batch of 100000 sensors x 4 frames: kernel alone "
              f"{kernel_rate / 1e6:.2f} M samples/s ({1e9 / kernel_rate:.1f} ns/sample over "
              f"the threads; {kernel_rate / RATE_HZ:.0f} sensors at "
              f"100 Hz), the engine's run_into {rates['run_into'] / 1e6:.2f} M samples/s "
              f"({rates['run_into'] / kernel_rate:.2f} x kernel), run() "
              f"{rates['run'] / 1e6:.2f} M samples/s ({rates['run'] / kernel_rate:.2f} x kernel) "
              f"[{load()}]")
        print(f"  both cores? threads other than the caller did "
              f"{rates['other_threads'] * 100:.0f} % of the kernel's CPU time (50 %: both "
              f"share it), CPU/wall {rates['cpu_per_wall']:.2f} (2.0 on two free cores)")
        scan = batch_scan(method)
        print("  batch size (frames of 100000 sensors): " + ", ".join(
            f"{n}: {r / 1e6:.2f} M/s" for n, r in scan.items()) + f" [{load()}]")
        tp = throughput(method, base, args.throughput_people)
        print(f"  unpaced engine, {tp['sensors']} sensors: {tp['frames']} frames in "
              f"{tp['wall_s']:.2f} s wall, {tp['cpu_s']:.2f} s CPU -> "
              f"{tp['wall_sensors']:.0f} sensors at 100 Hz by wall time, "
              f"{tp['cpu_sensors']:.0f} by CPU time on {os.cpu_count()} cores [{load()}]")
        best = search(method, base, args.seconds, args.start_people, args.max_people)
        if best is None:
            print("  not even the smallest count was sustained")
            continue
        print(f"  largest sustained: {best['sensors']} sensors ({best['people']} avatars)")
        print(breakdown(best))
        if args.profile:
            prof = throughput(method, base, best["people"], profile=True)
            print(f"  cProfile of an unpaced run at {prof['sensors']} sensors (top by own time):")
            print("\n".join("    " + line.strip()[:110]
                            for line in prof["profile"].splitlines()[6:18] if line.strip()))
            print(prof["split"])
        summary.append((name, best["sensors"], tp["wall_sensors"], kernel_rate / RATE_HZ))
    print("\nsummary (sensors at 100 Hz: sustained in real time | unpaced engine | kernel alone):")
    for name, sensors, unpaced, bound in summary:
        print(f"  {name:<10} {sensors:>7} | {unpaced:>9.0f} | {bound:>9.0f}")


if __name__ == "__main__":
    main()
