"""The live engine under field faults over real UDP on 127.0.0.1: a soak and a flood.

1. Soak: :class:`margtrack.live.faults.FaultyStream`, 15 sensors at 100 Hz for
   ``--seconds`` (60) s with every fault of issue 17 mixed in (:func:`default_faults`:
   reboots, a line stamped 1e9, acc = 0 lines, a gyro of 1e300, a sensor silent for 30 %
   of the run, lost lines, a duplicate, a garbage line), sent in real time by a sender
   thread (one datagram per tick) to a :class:`UdpSource` feeding an :class:`Engine`
   (default method, no body model). Printed: per sensor sent, received, processed, lost,
   resyncs, stale time; whether every unaffected sensor's samples were all processed;
   latency p50/p95 of every published pose (frame arrival to publishing).
2. Flood: ``--flood-lines`` (100,000) lines of 3 sensors with sequence numbers sent
   evenly over ``--flood-seconds`` (2; 0: as fast as it can) by a sender *process* (the
   issue: "100,000 lines in 2 s"; a separate process, as a real sender is), the last
   line of each sensor after a pause; printed sent, received, lost, processed, latency,
   and the check received + lost == sent per sensor.

Run: python benchmarks/live_soak.py [--seconds 60] [--flood-lines 100000] [--flood-seconds 2]
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import threading
import time

import numpy as np

from margtrack.live.engine import Engine
from margtrack.live.faults import FaultyStream, default_faults
from margtrack.live.lines import format_line
from margtrack.live.udp import UdpSource


def _latencies(engine: Engine) -> list[float]:
    out: list[float] = []
    engine.subscribe(lambda pose: out.append(pose.latency_s))
    return out


def soak(seconds: float) -> bool:
    """The fault soak; returns whether every unaffected sensor was processed whole."""
    stream = FaultyStream(15, 100.0, seconds, default_faults(seconds))
    names = tuple(f"s{i}" for i in range(15))
    source = UdpSource(names, port=0, rate_hz=100.0)
    source.open()
    engine = Engine(source.info, "default", avatars=None)
    latency = _latencies(engine)
    engine.start(source)
    address = source.address
    late_sends = 0

    def send() -> None:
        nonlocal late_sends
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            start = time.perf_counter() + 0.2
            for t, lines in stream.ticks():
                wait = start + t - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
                elif wait < -0.01:
                    late_sends += 1
                if lines:
                    sock.sendto("".join(lines).encode(), address)

    sender = threading.Thread(target=send, name="soak-sender")
    t0 = time.perf_counter()
    sender.start()
    sender.join()
    time.sleep(0.5)
    engine.stop()
    wall = time.perf_counter() - t0
    summary = engine.summary()
    expected = stream.expected()
    print(f"soak: {seconds:.0f} s, 15 sensors at 100 Hz, faults on sensors "
          f"{sorted(stream.affected)} ({', '.join(f.kind for f in stream.faults)}); "
          f"wall {wall:.1f} s, sender ticks late by > 10 ms: {late_sends}")
    print(f"engine: error {summary['engine']['error']}, frames {summary['engine']['frames']}, "
          f"session {summary['engine']['session_s']:.2f} s, malformed lines "
          f"{summary['engine']['malformed_lines']}")
    print(" sensor   sent  recv  proc  lost  held  late  bad_t  resync  stale_s   faults  reinit")
    whole = True
    for s, name in enumerate(names):
        c = summary["sensors"][name]
        sent = int(expected["sent"][s] + expected["duplicates"][s])
        mark = "*" if s in stream.affected else " "
        print(f" {name:>4}{mark} {sent:6d} {c['received']:5d} {c['processed']:5d} {c['lost']:5d} "
              f"{c['held']:5d} {c['late']:5d} {c['bad_time']:6d} {c['resyncs']:7d} "
              f"{c['stale_s']:8.2f} {c['faults']:8d} {c['reinitialised']:7d}")
        if s not in stream.affected and c["processed"] != sent:
            whole = False
    lat = np.asarray(latency)
    sent_total = int((expected["sent"] + expected["duplicates"]).sum())
    processed = sum(c["processed"] for c in summary["sensors"].values())  # type: ignore[misc]
    lost = sum(c["lost"] for c in summary["sensors"].values())  # type: ignore[misc]
    print(f"soak totals: sent {sent_total}, processed {processed}, lost {lost}; poses "
          f"{lat.size}, latency p50 {np.percentile(lat, 50) * 1e3:.2f} ms, p95 "
          f"{np.percentile(lat, 95) * 1e3:.2f} ms; every unaffected sensor processed whole: "
          f"{whole}")
    return whole


def flood(n_lines: int, span_s: float) -> bool:
    """The flood; returns whether received + lost == sent for every sensor."""
    n_sensors = 3
    n_frames = -(-n_lines // n_sensors)  # at least n_lines
    names = tuple(f"s{i}" for i in range(n_sensors))
    source = UdpSource(names, port=0, rate_hz=1000.0)
    source.open()
    engine = Engine(source.info, "default", avatars=None)
    latency = _latencies(engine)
    engine.start(source)
    n_sent = n_frames * n_sensors
    sender = subprocess.run(
        [sys.executable, __file__, "--send-flood", str(source.address[1]), str(n_frames),
         str(round(span_s * 1000))],
        capture_output=True, text=True, check=True)
    send_s = float(sender.stdout.split()[0])
    end = time.perf_counter() + 60.0
    while time.perf_counter() < end:
        c = engine.stats().health.counts
        if (c["received"] + c["lost"] >= n_frames).all():
            break
        time.sleep(0.1)
    time.sleep(0.3)
    engine.stop()
    c = engine.stats().health.counts
    ok = bool(((c["received"] + c["lost"]) == n_frames).all())
    lat = np.asarray(latency)
    print(f"flood: {n_sent} lines ({n_sensors} sensors x {n_frames}) sent in {send_s:.2f} s "
          f"({n_sent / send_s:.0f} lines/s); receive buffer granted "
          f"{source.receive_buffer_bytes} bytes")
    for s, name in enumerate(names):
        print(f"  {name}: sent {n_frames}, received {c['received'][s]}, lost {c['lost'][s]}, "
              f"processed {c['processed'][s]}, received + lost == sent: "
              f"{c['received'][s] + c['lost'][s] == n_frames}")
    print(f"flood totals: sent {n_sent}, processed {int(c['processed'].sum())}, lost "
          f"{int(c['lost'].sum())}; latency p50 {np.percentile(lat, 50) * 1e3:.2f} ms, p95 "
          f"{np.percentile(lat, 95) * 1e3:.2f} ms")
    return ok


def send_flood(port: int, n_frames: int, span_ms: int, n_sensors: int = 3) -> None:
    """The flood sender (run as its own process), spread evenly over ``span_ms`` (0: as fast
    as it can); prints the seconds it took."""
    lines = [format_line(100.0 + k / 1000.0, s, [0.0, 0.0, 0.1], [0.0, 0.0, 9.81],
                         [0.0, 20.0, -35.0], seq=k).encode()
             for k in range(n_frames) for s in range(n_sensors)]
    address = ("127.0.0.1", port)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        t0 = time.perf_counter()
        rate = len(lines) / (span_ms / 1000.0) if span_ms > 0 else 0.0
        for i, data in enumerate(lines[:-n_sensors]):
            if rate and i % 500 == 0:
                wait = t0 + i / rate - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
            sock.sendto(data, address)
        send_s = time.perf_counter() - t0
        time.sleep(0.5)
        for data in lines[-n_sensors:]:
            sock.sendto(data, address)
    print(f"{send_s:.6f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--flood-lines", type=int, default=100_000)
    parser.add_argument("--flood-seconds", type=float, default=2.0,
                        help="spread the flood over this long (0: as fast as possible)")
    parser.add_argument("--send-flood", nargs=3, type=int, metavar=("PORT", "FRAMES", "MS"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.send_flood:
        send_flood(*args.send_flood)
        return
    ok_soak = soak(args.seconds)
    ok_flood = flood(args.flood_lines, args.flood_seconds)
    print(f"result: soak unaffected sensors whole {ok_soak}; flood accounted {ok_flood}")


if __name__ == "__main__":
    main()
