"""OSC source (live/osc.py) fed by a real python-osc sender over UDP on 127.0.0.1."""

from __future__ import annotations

import math
import socket
import threading
import time

import numpy as np
import pytest
from pythonosc.osc_bundle_builder import OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder
from pythonosc.udp_client import SimpleUDPClient
from typer.testing import CliRunner

from margtrack.live.engine import Engine
from margtrack.live.osc import OscSource, send_osc


def _collect(source: OscSource, n: int, timeout_s: float = 5.0) -> list:
    chunks: list = []
    end = time.perf_counter() + timeout_s
    while len(chunks) < n and time.perf_counter() < end:
        chunks.extend(source.poll(0.05))
    return chunks


def _message(address: str, args: list, kind: str | None = None):
    b = OscMessageBuilder(address=address)
    for a in args:
        b.add_arg(a, kind) if kind else b.add_arg(a)
    return b.build()


@pytest.fixture
def source():
    src = OscSource(["left", "right"], port=0)
    src.open()
    yield src
    src.close()


def test_margtrack_messages_round_trip_exactly(source) -> None:
    addr = source.address
    assert addr[0] == "127.0.0.1"
    send_osc(addr, 0, 12.345678901234, [0.1, -0.2, 0.3], [0.0, 0.5, 9.81], [20.0, -3.0, -40.0])
    send_osc(addr, "right", 12.345678901234, [1e-3, 0, 0], [0, 0, 9.8], [21.0, 0.0, -41.0])
    chunks = _collect(source, 2)
    assert len(chunks) == 2
    a, b = chunks
    assert a.t_s[0] == 12.345678901234 and a.sensors.tolist() == [0]
    assert a.gyr[0, 0].tolist() == [0.1, -0.2, 0.3]
    assert a.acc[0, 0].tolist() == [0.0, 0.5, 9.81]
    assert a.mag[0, 0].tolist() == [20.0, -3.0, -40.0]
    assert b.sensors.tolist() == [1] and b.mag[0, 0].tolist() == [21.0, 0.0, -41.0]
    assert source.stats.samples == 2 and source.stats.malformed == 0


def test_ngimu_sensors_bundle_is_converted(source) -> None:
    """x-io NGIMU layout: deg/s, g, uT, hPa; the bundle's time tag is the sample time."""
    bundle = OscBundleBuilder(1_700_000_000.25)
    bundle.add_content(_message("/right/sensors",
                                [90.0, 0.0, -180.0, 0.0, 0.0, 1.0, 20.0, 0.0, -40.0, 1013.0]))
    SimpleUDPClient(*source.address).send(bundle.build())
    (chunk,) = _collect(source, 1)
    assert chunk.sensors.tolist() == [1]
    assert chunk.t_s[0] == pytest.approx(1_700_000_000.25, abs=1e-6)
    np.testing.assert_allclose(chunk.gyr[0, 0], [math.pi / 2, 0.0, -math.pi], rtol=1e-6)
    np.testing.assert_allclose(chunk.acc[0, 0], [0.0, 0.0, 9.80665], rtol=1e-6)
    np.testing.assert_allclose(chunk.mag[0, 0], [20.0, 0.0, -40.0], rtol=1e-6)


BAD = [
    ("/margtrack/0/imu", [1.0, 0.0, 0.0], "expected 10 arguments"),  # wrong count
    ("/margtrack/0/imu", [1.0, 0, 0, 0, 0, 0, "9.81", 0, 0, 0], "argument 7 .az. is str"),
    ("/margtrack/0/imu", [1.0, 0, 0, float("nan"), 0, 0, 9.8, 0, 0, 0], "argument 4 .gz. is "
                                                                       "not finite"),
    ("/margtrack/1/imu", [1.0, 0, 0, 0, 0, 0, float("inf"), 0, 0, 0], "not finite"),
    ("/margtrack/7/imu", [1.0, 0, 0, 0, 0, 0, 9.8, 0, 0, 0], "sensor index 7 out of range"),
    ("/margtrack/elbow/imu", [1.0, 0, 0, 0, 0, 0, 9.8, 0, 0, 0], "unknown sensor 'elbow'"),
    ("/accxyz", [0.1, 0.2, 0.3], "unknown OSC address"),
    ("/sensors", [0.0] * 10, "only a one-sensor source"),
]


@pytest.mark.parametrize(("address", "args", "reason"), BAD)
def test_bad_messages_are_counted_not_raised(source, address, args, reason) -> None:
    client = SimpleUDPClient(*source.address)
    client.send(_message(address, args))
    send_osc(source.address, 0, 2.0, [0, 0, 0], [0, 0, 9.8], [20, 0, -40])  # a good one after
    chunks = _collect(source, 1)
    assert len(chunks) == 1 and chunks[0].t_s[0] == 2.0
    assert source.stats.malformed == 1
    assert source.stats.last_error and __import__("re").search(reason,
                                                               source.stats.errors[0])


def test_garbage_datagram_is_counted(source) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(b"\x00\x01not osc at all", source.address)
        s.sendto(b"#bundle\x00\x00\x00", source.address)  # truncated bundle
    send_osc(source.address, 1, 3.0, [0, 0, 0], [0, 0, 9.8], [20, 0, -40])
    chunks = _collect(source, 1)
    assert [c.t_s[0] for c in chunks] == [3.0]
    assert source.stats.malformed == 2
    assert "does not parse" in source.stats.errors[0]


def test_non_monotonic_time_is_counted_and_delivered(source) -> None:
    for t in (5.0, 5.01, 0.0, 0.01):  # the sensor rebooted: its clock restarts
        send_osc(source.address, 0, t, [0, 0, 0], [0, 0, 9.8], [20, 0, -40])
    chunks = _collect(source, 4)
    assert [c.t_s[0] for c in chunks] == [5.0, 5.01, 0.0, 0.01]
    assert source.non_monotonic == 1 and source.stats.malformed == 0
    assert "not after" in source.stats.last_error


def test_engine_tracks_an_osc_stream(source) -> None:
    """Two sensors at rest, 1 s at 100 Hz, plus junk: the engine runs and keeps every frame."""
    engine = Engine(source.info, "default", avatars=None)
    client = SimpleUDPClient(*source.address)
    with engine.start(source):
        for i in range(100):
            for s in (0, 1):
                send_osc(source.address, s, i / 100, [0, 0, 0], [0, 0, 9.81], [20, 0, -40])
            if i % 10 == 0:
                client.send(_message("/margtrack/0/imu", ["junk"]))
        end = time.perf_counter() + 5.0
        while engine.data_time_s < 0.98 and time.perf_counter() < end:
            time.sleep(0.02)
    stats = engine.stats()
    assert not stats.error
    assert source.stats.samples == 200 and source.stats.malformed == 10
    assert engine.data_time_s == pytest.approx(0.99)
    # ENU, level, horizontal field along the sensor's x: x points north = yaw +90 deg
    q = engine.latest.q_sensor * np.sign(engine.latest.q_sensor[:, :1])
    np.testing.assert_allclose(q, [[math.sqrt(0.5), 0, 0, math.sqrt(0.5)]] * 2, atol=1e-6)


def test_cli_live_osc_headless() -> None:
    from margtrack.cli import app

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]

    def sender() -> None:
        time.sleep(0.8)
        for i in range(50):
            send_osc(("127.0.0.1", port), 0, i / 100, [0, 0, 0], [0, 0, 9.81], [20, 0, -40])

    thread = threading.Thread(target=sender)
    thread.start()
    result = CliRunner().invoke(app, ["live", "--osc", str(port), "--sensors", "1",
                                      "--headless", "--duration", "2"])
    thread.join()
    assert result.exit_code == 0, result.output
    assert "OSC 127.0.0.1" in result.output
    bad = CliRunner().invoke(app, ["live", "--osc", str(port), "--headless"])
    assert bad.exit_code == 2 and "need --sensors" in bad.output
