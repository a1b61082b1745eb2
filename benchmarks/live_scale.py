"""How many sensors the live engine sustains in real time at 100 Hz, and what limits it.

For each method (Bachmann's filter ``bachmann``, 000 Appendix A, and the default method), in
one run on this machine:

1. kernel rate: the method's numba kernel alone on prepared arrays, S = 3000 sensors x 100
   samples (a compiled method's ``kernel.run``, screening included; otherwise
   ``Estimator._process``), and ``Estimator.run`` around it (validation, copies);
2. real-time runs: simulated people (``PeopleSimulation``, 15 sensors each, walking, MEMS
   noise) tiled to S sensors and replayed at real speed (``ReplaySource``, 100 Hz, looping)
   into an ``Engine`` with the body model of every person, a 25 Hz display clock and one
   subscriber, for ``--seconds`` s. S is *sustained* when at the end the engine is less than
   0.1 s of data behind real time and the 95th percentile of the published poses' latency
   (frame arrival to publishing) is under 0.1 s. S doubles until a run fails, then the gap
   is bisected;
3. where the time goes at the largest sustained S: the worker thread's busy time split into
   the filters' kernel (kernel rate x samples), the Python around the filters (``run``
   minus kernel: validation, contiguous copies, state copies), the body model (000 eqs. 7,
   11 for every person at 25 Hz), publishing, and polling the source / assembling frames.

The paper's system ran 3 real + 13 simulated sensors at 100 Hz on an 866 MHz Pentium III.

Run: python benchmarks/live_scale.py [--seconds 3] [--methods bachmann default]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from margtrack import methods
from margtrack.estimator.compiled import CompiledEstimator
from margtrack.live.engine import Engine
from margtrack.live.replay import ReplaySource
from margtrack.live.simulator import PeopleSimulation
from margtrack.sim import DEFAULT_DIP_DEG

RATE_HZ = 100.0
LOOP_FRAMES = 50  # 0.5 s of motion, replayed in a loop (memory: S x 50 x 9 doubles)
BASE_PEOPLE = 8


def params(method: str) -> dict[str, float]:
    """Bachmann's filter is given the simulated dip as its reference (as a calibration
    would): measured from a first sample taken in motion it would be off."""
    return {"mag_dip_ref_deg": DEFAULT_DIP_DEG} if methods.get(method).name == "bachmann" else {}


def base_signals() -> tuple[np.ndarray, ...]:
    """0.5 s of 8 walking people (120 sensors), after the start ramp."""
    people = PeopleSimulation(n_people=BASE_PEOPLE, rate_hz=RATE_HZ, seed=11)
    t, gyr, acc, mag = people.signals(400, LOOP_FRAMES)
    return t, gyr, acc, mag, people.skeleton.names


def tiled_source(base: tuple[np.ndarray, ...], n_people: int) -> ReplaySource:
    t, gyr, acc, mag, segments = base
    reps = -(-n_people // BASE_PEOPLE)
    k = len(segments)

    def tile(x: np.ndarray) -> np.ndarray:
        return np.tile(x, (reps, 1, 1))[: n_people * k]

    names = [f"p{a}/{s}" for a in range(n_people) for s in segments]
    return ReplaySource(t, tile(gyr), tile(acc), tile(mag), names, speed=1.0, loop=True,
                        description=f"{n_people} simulated people")


def kernel_rates(method: str, n_sensors: int = 3000, n: int = 100) -> tuple[float, float]:
    """Samples/s of the kernel alone and of ``run`` (S sensors, n samples per call)."""
    rng = np.random.default_rng(0)
    gyr = rng.normal(0, 0.5, (n_sensors, n, 3))
    acc = rng.normal(0, 0.5, (n_sensors, n, 3)) + [0.0, 0.0, 9.81]
    mag = rng.normal(0, 0.5, (n_sensors, n, 3)) + [0.0, 25.0, -43.0]
    t = np.arange(n) / RATE_HZ
    est = methods.create(method, params(method))
    est.run(gyr=gyr, acc=acc, mag=mag, t=t, check_units=False)  # compile / load the cache
    reps = 10
    start = time.perf_counter()
    for r in range(reps):
        est.run(gyr=gyr, acc=acc, mag=mag, t=t + (r + 1) * n / RATE_HZ, check_units=False)
    run_rate = reps * n_sensors * n / (time.perf_counter() - start)
    state = est.state
    if isinstance(est, CompiledEstimator):
        # the compiled entry point on its own (screening and method, one call per series)
        width = max(sum(w for _, w in est.outputs_layout), 1)
        q, x = np.empty((n_sensors, n, 4)), np.empty((n_sensors, n, width))
        flags = np.empty((n_sensors, n), dtype=np.uint16)
        series = [t + (reps + r + 1) * n / RATE_HZ for r in range(reps + 1)]  # no gap
        for a in (gyr, acc, mag, *series):  # as run() passes them: the same specialisation
            a.flags.writeable = False
        est.kernel.run(state.rows, state.clock, est._coefs, series[0], gyr, acc, mag, 3, q, x,
                       flags)  # warm-up (loads the cache)
        start = time.perf_counter()
        for times in series[1:]:
            est.kernel.run(state.rows, state.clock, est._coefs, times, gyr, acc, mag, 3, q, x,
                           flags)
        kernel_rate = reps * n_sensors * n / (time.perf_counter() - start)
        return kernel_rate, run_rate
    dt = np.full(n, 1.0 / RATE_HZ)
    start = time.perf_counter()
    for _ in range(reps):
        est._process(state, gyr, acc, mag, dt)
    kernel_rate = reps * n_sensors * n / (time.perf_counter() - start)
    return kernel_rate, run_rate


def realtime(method: str, base: tuple[np.ndarray, ...], n_people: int, seconds: float) -> dict:
    """One real-time run of ``n_people`` x 15 sensors; its figures."""
    source = tiled_source(base, n_people)
    engine = Engine(source.info, method, params(method), display_hz=25.0)
    engine.subscribe(lambda pose: None)
    with engine.start(source):
        time.sleep(seconds)
        now = time.perf_counter()
        behind_s = (now - source.started_s) + float(source.t_s[0]) - engine.data_time_s
        stats = engine.stats()
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
    }


def row(r: dict) -> str:
    return (f"  {r['sensors']:>7} sensors ({r['people']:>5} people): "
            f"behind {r['behind_s']:7.3f} s, "
            f"latency p50 {r['p50_ms']:7.1f} ms p95 {r['p95_ms']:7.1f} ms, {r['frames']} frames "
            f"in {r['batches']} batches -> {'sustained' if r['ok'] else 'NOT sustained'}"
            + (f" ({r['error']})" if r["error"] else ""))


def search(method: str, base: tuple[np.ndarray, ...], seconds: float, max_people: int) -> dict:
    """Largest sustained people count by doubling, then bisection (module docstring)."""
    n, best, worst = 100, None, None
    while n <= max_people:
        r = realtime(method, base, n, seconds)
        print(row(r), flush=True)
        if not r["ok"]:
            worst = n
            break
        best, n = r, n * 2
    lo = best["people"] if best else 0
    hi = worst if worst else lo
    for _ in range(3):
        if hi - lo <= max(lo // 8, 1):
            break
        mid = (lo + hi) // 2
        r = realtime(method, base, mid, seconds)
        print(row(r), flush=True)
        if r["ok"]:
            best, lo = r, mid
        else:
            hi = mid
    return best


def breakdown(best: dict, kernel_rate: float) -> str:
    st = best["stats"]
    wall = best["wall_s"]
    kernel = st.samples / kernel_rate
    parts = {
        "filter kernel (numba)": kernel,
        "Python around the filters": max(st.time_filter_s - kernel, 0.0),
        "body model + recording": st.time_body_s,
        "publishing": st.time_publish_s,
        "source polling + frame assembly": st.time_assemble_s,
    }
    lines = [f"  worker busy {best['busy_s'] / wall * 100:.0f} % of {wall:.1f} s wall time:"]
    for name, seconds in parts.items():
        lines.append(f"    {name:<34} {seconds / wall * 100:5.1f} % of wall time "
                     f"({seconds / max(st.frames, 1) * 1e3:.3f} ms per frame)")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="length of each real-time run")
    parser.add_argument("--methods", nargs="+", default=["bachmann", "default"])
    parser.add_argument("--max-people", type=int, default=12800)
    args = parser.parse_args()
    base = base_signals()
    print(f"live engine scale at {RATE_HZ:.0f} Hz, 15 sensors per person, display 25 Hz, "
          f"{args.seconds} s real-time runs")
    summary = []
    for method in args.methods:
        name = methods.get(method).name
        kernel_rate, run_rate = kernel_rates(method)
        print(f"\n{name}: kernel {kernel_rate / 1e6:.2f} M samples/s "
              f"({kernel_rate / RATE_HZ:.0f} sensors at 100 Hz), run() "
              f"{run_rate / 1e6:.2f} M samples/s ({run_rate / kernel_rate:.2f} x kernel)")
        best = search(method, base, args.seconds, args.max_people)
        if best is None:
            print("  not even the smallest count was sustained")
            continue
        print(f"  largest sustained: {best['sensors']} sensors ({best['people']} avatars)")
        print(breakdown(best, kernel_rate))
        summary.append((name, best["sensors"], kernel_rate / RATE_HZ))
    print("\nsummary (sensors sustained in real time at 100 Hz | kernel-only bound):")
    for name, sensors, bound in summary:
        print(f"  {name:<10} {sensors:>7} | {bound:>9.0f}")


if __name__ == "__main__":
    main()
