"""LSL source (live/lsl.py) fed by a real pylsl StreamOutlet in this process.

Discovery: ``resolve_byprop("name", ...)`` finds an outlet of this process on this machine
within milliseconds (LSL's multicast/broadcast discovery works over loopback here).
"""

from __future__ import annotations

import itertools
import math
import threading
import time

import numpy as np
import pytest
from typer.testing import CliRunner

pylsl = pytest.importorskip("pylsl", reason="pylsl (live extra) is not installed")

from margtrack.live.engine import Engine  # noqa: E402
from margtrack.live.lsl import LslSource, imu_stream_info  # noqa: E402

_ids = itertools.count()


def _name() -> str:
    return f"margtrack-test-{time.monotonic_ns()}-{next(_ids)}"


def _collect(source: LslSource, frames: int, timeout_s: float = 5.0) -> list:
    chunks: list = []
    end = time.perf_counter() + timeout_s
    while sum(c.n_frames for c in chunks) < frames and time.perf_counter() < end:
        chunks.extend(source.poll(0.05))
    return chunks


def _frame(sensor_values: list[list[float]]) -> list[float]:
    return [v for values in sensor_values for v in values]


REST_A = [0.1, -0.2, 0.3, 0.0, 0.5, 9.81, 20.0, -3.0, -40.0]
REST_B = [0.0, 0.0, 0.0, 0.0, 0.0, 9.81, 0.0, 20.0, -40.0]


@pytest.fixture
def stream():
    name = _name()
    outlet = pylsl.StreamOutlet(imu_stream_info(name, ["a", "b"], 100.0))
    source = LslSource(name, timeout_s=5.0)
    source.open()
    yield outlet, source
    source.close()
    del outlet


def test_frames_round_trip_exactly(stream) -> None:
    outlet, source = stream
    assert source.info.sensor_names == ("a", "b")
    assert source.info.has_mag and source.info.rate_hz == 100.0
    for i in range(5):
        outlet.push_sample(_frame([REST_A, REST_B]), 50.0 + i / 100)
    chunks = _collect(source, 5)
    t = np.concatenate([c.t_s for c in chunks])
    np.testing.assert_array_equal(t, 50.0 + np.arange(5) / 100)
    assert all(c.sensors.tolist() == [0, 1] for c in chunks)  # complete frames: one block
    gyr = np.concatenate([c.gyr for c in chunks], axis=1)
    mag = np.concatenate([c.mag for c in chunks], axis=1)
    assert gyr[0, 3].tolist() == REST_A[0:3] and mag[1, 4].tolist() == REST_B[6:9]
    assert source.stats.samples == 10 and source.stats.malformed == 0


def test_units_from_the_description_are_converted() -> None:
    name = _name()
    info = pylsl.StreamInfo(name, "IMU", 6, 50.0, pylsl.cf_float32, name)
    channels = info.desc().append_child("channels")
    for axis, unit in zip(("gx", "gy", "gz", "ax", "ay", "az"), ["deg/s"] * 3 + ["g"] * 3,
                          strict=True):
        ch = channels.append_child("channel")
        ch.append_child_value("label", axis)  # one sensor: no prefix
        ch.append_child_value("unit", unit)
    outlet = pylsl.StreamOutlet(info)
    source = LslSource(name)
    source.open()
    try:
        assert source.info.sensor_names == ("sensor0",) and not source.info.has_mag
        outlet.push_sample([90.0, 0.0, 0.0, 0.0, 0.0, 1.0], 7.0)
        (chunk,) = _collect(source, 1)
        np.testing.assert_allclose(chunk.gyr[0, 0], [math.pi / 2, 0, 0], rtol=1e-6)
        np.testing.assert_allclose(chunk.acc[0, 0], [0, 0, 9.80665], rtol=1e-6)
        assert chunk.mag is None
    finally:
        source.close()


def test_non_finite_sensor_is_left_out_of_its_frame(stream) -> None:
    outlet, source = stream
    bad_b = list(REST_B)
    bad_b[4] = math.nan
    outlet.push_chunk([_frame([REST_A, REST_B]), _frame([REST_A, bad_b]),
                       _frame([REST_A, REST_B])], [1.0, 1.01, 1.02])
    chunks = _collect(source, 3)
    assert [(c.t_s.tolist(), c.sensors.tolist()) for c in chunks] == [
        ([1.0], [0, 1]), ([1.01], [0]), ([1.02], [0, 1])]
    assert source.stats.malformed == 1 and "sensor 'b' has a non-finite" in \
        source.stats.errors[0]
    assert source.stats.samples == 5


def test_non_monotonic_time_is_counted_and_delivered(stream) -> None:
    outlet, source = stream
    # a sender restarted with its clock (1.0, not 0.0: LSL takes 0.0 for "now")
    outlet.push_chunk([_frame([REST_A, REST_B])] * 4, [9.0, 9.01, 1.0, 1.01])
    chunks = _collect(source, 4)
    assert np.concatenate([c.t_s for c in chunks]).tolist() == [9.0, 9.01, 1.0, 1.01]
    assert source.non_monotonic == 1 and "went back" in source.stats.last_error


def test_bad_streams_are_refused_with_the_reason() -> None:
    with pytest.raises(ValueError, match="no LSL stream named 'nobody-sends-this'"):
        LslSource("nobody-sends-this", timeout_s=0.3)
    name = _name()
    strings = pylsl.StreamOutlet(pylsl.StreamInfo(name, "IMU", 6, 0, pylsl.cf_string, name))
    with pytest.raises(ValueError, match="carries strings"):
        LslSource(name)
    name2 = _name()
    info = pylsl.StreamInfo(name2, "MARG", 3, 0, pylsl.cf_double64, name2)
    ch = info.desc().append_child("channels")
    for label in ("a/gx", "a/gy", "a/temp"):
        ch.append_child("channel").append_child_value("label", label)
    unlabeled = pylsl.StreamOutlet(info)
    with pytest.raises(ValueError, match="'a/temp' is not <sensor>/<axis>"):
        LslSource(name2)
    name3 = _name()
    eeg = pylsl.StreamOutlet(pylsl.StreamInfo(name3, "EEG", 6, 0, pylsl.cf_float32, name3))
    with pytest.raises(ValueError, match="type 'EEG'"):
        LslSource(name3)
    del strings, unlabeled, eeg


def test_engine_tracks_an_lsl_stream(stream) -> None:
    outlet, source = stream
    engine = Engine(source.info, "default", avatars=None)
    with engine.start(source):
        for i in range(100):
            outlet.push_sample(_frame([REST_A, REST_B]), 20.0 + i / 100)
        end = time.perf_counter() + 5.0
        while engine.data_time_s < 0.98 and time.perf_counter() < end:
            time.sleep(0.02)
    assert not engine.stats().error
    assert engine.data_time_s == pytest.approx(0.99)  # session time: 0 at the first frame
    q = engine.latest.q_sensor[1] * np.sign(engine.latest.q_sensor[1, 0])
    np.testing.assert_allclose(q, [1, 0, 0, 0], atol=1e-6)  # ENU, level, y north


def test_cli_live_lsl_headless() -> None:
    from margtrack.cli import app

    name = _name()
    outlet = pylsl.StreamOutlet(imu_stream_info(name, ["pelvis"], 100.0))
    stop = threading.Event()

    def sender() -> None:
        i = 0
        while not stop.is_set():
            outlet.push_sample(REST_B, 100.0 + i / 100)
            i += 1
            time.sleep(0.01)

    thread = threading.Thread(target=sender)
    thread.start()
    try:
        result = CliRunner().invoke(app, ["live", "--lsl", name, "--headless", "--duration",
                                          "1.5", "--no-calibrate"])
    finally:
        stop.set()
        thread.join()
    assert result.exit_code == 0, result.output
    assert f"LSL {name}: 1 sensors" in result.output
