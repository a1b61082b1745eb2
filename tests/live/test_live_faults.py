"""Field faults of issue 17: each affects only its sensor, is counted, and the engine goes on.

Socket faults (a reboot, a flood) go over real UDP on 127.0.0.1; the others through
``Engine.push`` with a simulated wall clock (``now_s``), so they are deterministic.
"""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from margtrack import quaternion as quat
from margtrack.estimator.compiled import UNRUN
from margtrack.live.engine import Engine
from margtrack.live.faults import Fault, FaultyStream, default_faults
from margtrack.live.lines import LineDecoder, format_line, parse_line_seq
from margtrack.live.protocol import BaseSource, SourceInfo, SourceStats
from margtrack.live.udp import UdpSource, send_lines

RATE_HZ = 100.0


def _names(n):
    return tuple(f"s{i}" for i in range(n))


def _engine(n, method="default", **kw):
    return Engine(SourceInfo(_names(n), RATE_HZ, True), method, avatars=None, **kw)


def _run(engine, stream, record=None):
    """Feed a FaultyStream tick by tick (arrival = now = the tick's time); flush at the end."""
    decoder = LineDecoder(engine.info.sensor_names, True, SourceStats())
    for t, lines in stream.ticks():
        pose = engine.push(decoder.feed("".join(lines).encode(), arrival_s=t, final=True),
                           now_s=t)
        if record is not None and pose is not None:
            record.append(pose)
    engine.push([], now_s=1e6, flush=True)
    return decoder.stats


def _yaw(q):
    return quat.to_euler(q)[..., 0]


def _accounted(counts):
    """Lines per sensor with a fate: processed, late, repeated, with a bad time, discarded."""
    return (counts["processed"] + counts["late"] + counts["duplicates"] + counts["bad_time"]
            + counts["discarded"])


def _wait(predicate, timeout_s=20.0):
    end = time.perf_counter() + timeout_s
    while not predicate() and time.perf_counter() < end:
        time.sleep(0.02)
    return predicate()


def test_a_reboot_over_udp_resyncs_the_sensors_and_keeps_every_sample():
    # issue: clocks at 100 s restart at 0: frames stayed at 100, all 600 later samples "late"
    stream = FaultyStream(3, RATE_HZ, 4.0, [Fault("reboot", s, 2.0) for s in range(3)])
    ticks = list(stream.ticks())
    source = UdpSource(_names(3), port=0, rate_hz=RATE_HZ)
    source.open()
    engine = Engine(source.info, "default", avatars=None).start(source)
    try:
        before = [line for t, lines in ticks if t < 2.0 - 1e-9 for line in lines]
        after = [line for t, lines in ticks if t >= 2.0 - 1e-9 for line in lines]
        send_lines(before, source.address, per_datagram=3)
        assert _wait(lambda: engine.stats().frames >= 199)
        send_lines(after, source.address, per_datagram=3)
        assert _wait(lambda: engine.stats().frames >= 399)
        time.sleep(0.1)
    finally:
        engine.stop()
    summary = engine.summary()
    assert summary["engine"]["error"] is None
    for name in _names(3):
        sensor = summary["sensors"][name]
        assert sensor["received"] == 400 and sensor["resyncs"] == 1 and sensor["late"] == 0
        assert sensor["processed"] == 400  # stopping processes the frame still waiting
    assert summary["engine"]["frames"] == 400
    # session time: from 0, on past the reboot (not back to the device's 0 s)
    assert 3.9 < engine.session_time_s < 30.0 and engine.session_origin_s == 100.0


def test_one_line_stamped_1e9_costs_that_line_only():
    # issue: 57 to 359 of the 600 samples after it dropped as late, published time 1e9
    stream = FaultyStream(3, RATE_HZ, 4.0, [Fault("stamp", 1, 1.0, value=1e9)])
    engine = _engine(3)
    poses = []
    _run(engine, stream, poses)
    stats = engine.stats()
    counts = stats.health.counts
    assert stats.frames == 400 and stats.late_samples == 0
    assert counts["bad_time"].tolist() == [0, 1, 0]
    assert counts["processed"].tolist() == [400, 399, 400]
    assert counts["held"].tolist() == [0, 1, 0] and counts["resyncs"].tolist() == [0, 0, 0]
    # poses on the 25 Hz display ticks up to the last frame, in session time (not 1e9)
    assert 3.95 < max(p.t_s for p in poses) < 4.0 and engine.session_time_s == pytest.approx(3.99)


def test_a_first_line_with_zero_acc_only_delays_that_sensor():
    # issue: "cannot initialise sensor 0" stopped the engine; the 398 lines after it ignored
    stream = FaultyStream(2, RATE_HZ, 2.0, [Fault("zero_acc", 0, 0.0)])
    engine = _engine(2)
    _run(engine, stream)
    stats = engine.stats()
    assert stats.engine_error is None and stats.frames == 200
    assert stats.health.counts["processed"].tolist() == [200, 200]
    assert stats.health.counts["faults"].tolist() == [1, 0]  # ACC_IGNORED, not used
    yaw = _yaw(engine.latest.q_sensor)
    truth = [stream.truth_yaw_rad(s, 1.99) for s in range(2)]
    np.testing.assert_allclose(yaw, truth, atol=math.radians(3.0))


@pytest.mark.parametrize("method", ["robust", "ekf"])
def test_a_gyro_of_1e300_is_flagged_on_that_sensor_and_the_others_are_untouched(method):
    # issue: robust's quaternion NaN for that sensor forever, ekf stopped the engine
    faulty = FaultyStream(3, RATE_HZ, 2.0, [Fault("gyro", 1, 0.5, value=1e300)])
    clean = FaultyStream(3, RATE_HZ, 2.0)
    runs = {}
    for name, stream in (("faulty", faulty), ("clean", clean)):
        engine = _engine(3, method)
        engine.start_recording()
        _run(engine, stream)
        runs[name] = (engine, engine.stop_recording().q_sensor)
    engine, q = runs["faulty"]
    assert np.isfinite(q).all() and engine.stats().engine_error is None
    assert engine.stats().health.counts["faults"].tolist() == [0, 1, 0]
    assert engine.stats().health.counts["processed"].tolist() == [200, 200, 200]
    np.testing.assert_allclose(q[:, [0, 2]], runs["clean"][1][:, [0, 2]], atol=1e-12)
    # sensor 1 lost one sample's rotation at most and goes on turning with the truth
    err = quat.angle_between(q[-1, 1], runs["clean"][1][-1, 1])
    assert err < math.radians(1.0)


@pytest.mark.parametrize("path", ["run_into", "run"])
@pytest.mark.parametrize("fault", ["raises", "nan"])
def test_a_sensor_whose_filter_fails_is_reinitialised_alone(monkeypatch, fault, path):
    # one sensor's filter raising (ekf's ZeroDivisionError in the issue) or returning NaN at
    # samples whose acc x is 123: on the in-place path (run_into, raising as the kernel does:
    # sensors before the failing one finished, the ones after untouched) and on run
    engine = _engine(3)
    cls = type(engine._estimator)
    real_run, real_run_into = cls.run, cls.run_into

    def faulty_run(self, *args, **kwargs):
        acc = np.asarray(kwargs["acc"])
        marked = acc[..., 0] == 123.0  # (S, N)
        if fault == "raises" and marked.any():
            raise ZeroDivisionError("float division by zero")
        est = real_run(self, *args, **kwargs)
        if fault == "nan" and marked.any():
            est.quat[marked] = np.nan
        return est

    def faulty_run_into(self, t, gyr, acc, mag, q_out, x_out, flags_out, *args, **kwargs):
        marked = acc[..., 0] == 123.0  # (S, N)
        before = self.state
        real_run_into(self, t, gyr, acc, mag, q_out, x_out, flags_out, *args, **kwargs)
        if fault == "nan":
            q_out[marked] = np.nan
        elif marked.any():
            s, k = (int(v) for v in np.argwhere(marked)[0])
            after = self.state
            after.rows[s + 1 :] = before.rows[s + 1 :]
            self.state = after
            flags_out[s, k:] = UNRUN
            flags_out[s + 1 :] = UNRUN
            raise ZeroDivisionError("float division by zero")

    if path == "run":
        monkeypatch.setattr(engine._filters, "_hot", False)
        monkeypatch.setattr(cls, "run", faulty_run)
    else:
        monkeypatch.setattr(cls, "run_into", faulty_run_into)
    decoder = LineDecoder(_names(3), True, SourceStats())
    stream = FaultyStream(3, RATE_HZ, 2.0)
    q_log = []
    for t, lines in stream.ticks():
        if abs(t - 0.5) < 1e-9:  # sensor 1's sample at 0.5 s triggers the failure
            lines[1] = lines[1].replace(",0.0,0.0,9.81,", ",123.0,0.0,9.81,", 1)
        engine.push(decoder.feed("".join(lines).encode(), arrival_s=t, final=True), now_s=t)
        q_log.append(engine.latest.q_sensor if engine.latest is not None else None)
    stats = engine.stats()
    assert stats.engine_error is None and stats.frames == 200
    assert stats.health.counts["reinitialised"].tolist() == [0, 1, 0]
    why = stats.health.sensor(1)["last_error"]
    assert ("ZeroDivisionError" in why) if fault == "raises" else ("non-finite" in why)
    assert stats.health.counts["processed"].tolist() == [200, 200, 200]
    final = engine.latest.q_sensor
    assert np.isfinite(final).all()
    truth = [stream.truth_yaw_rad(s, 1.99) for s in range(3)]
    np.testing.assert_allclose(_yaw(final), truth, atol=math.radians(3.0))
    # the other sensors went on exactly as without the fault (they saw the same samples)
    clean = _engine(3)
    _run(clean, FaultyStream(3, RATE_HZ, 2.0))
    np.testing.assert_array_equal(final[[0, 2]], clean.latest.q_sensor[[0, 2]])


def test_a_flood_over_udp_is_processed_or_counted_lost_line_by_line():
    # issue: 100,000 lines in 2 s: 19,426 frames processed, the summary said "dropped 9"
    n_sensors, n_frames = 3, 10_000  # 30,000 lines sent as fast as the sender can
    source = UdpSource(_names(n_sensors), port=0, rate_hz=1000.0)
    source.open()
    engine = Engine(source.info, "bachmann", avatars=None).start(source)
    try:
        acc, mag = [0.0, 0.0, 9.81], [0.0, 20.0, -35.0]
        lines = [format_line(100.0 + k / 1000.0, s, [0.0, 0.0, 0.1], acc, mag, seq=k)
                 for k in range(n_frames) for s in range(n_sensors)]
        send_lines(lines[:-n_sensors], source.address)
        time.sleep(0.3)  # the last line of each sensor after a pause: losses before it count
        send_lines(lines[-n_sensors:], source.address)
        assert _wait(lambda: engine.stats().health.counts["received"].sum()
                     + engine.stats().lost_samples >= n_frames * n_sensors, 30.0)
        # the last lines' fates once the engine has got to them (0.2 s alone; longer on a
        # machine busy with other tests)
        _wait(lambda: np.array_equal(_accounted(engine.stats().health.counts),
                                     engine.stats().health.counts["received"]), 10.0)
    finally:
        engine.stop()
    counts = engine.stats().health.counts
    np.testing.assert_array_equal(counts["received"] + counts["lost"], n_frames)
    # each line has one fate
    np.testing.assert_array_equal(_accounted(counts), counts["received"])
    assert source.receive_buffer_bytes > 0 and engine.stats().engine_error is None


def test_losses_without_sequence_numbers_are_counted_from_timestamp_gaps():
    engine = _engine(2)
    decoder = LineDecoder(_names(2), True, SourceStats())
    acc, mag = [0.0, 0.0, 9.81], [0.0, 20.0, -35.0]
    for k in range(100):
        t = 100.0 + k / RATE_HZ
        lines = [format_line(t, s, [0.0, 0.0, 0.0], acc, mag) for s in range(2)
                 if not (s == 1 and 40 <= k < 43)]  # 3 samples of sensor 1 lost
        engine.push(decoder.feed("".join(lines).encode(), arrival_s=k / RATE_HZ, final=True),
                    now_s=k / RATE_HZ)
    counts = engine.stats().health.counts
    assert counts["lost"].tolist() == [0, 3] and counts["gaps"].tolist() == [0, 1]
    assert counts["received"].tolist() == [100, 97] and counts["held"].tolist() == [0, 3]


def test_a_silent_sensor_stops_turning_and_resumes_with_a_gap():
    # issue: a sensor that stopped while turning at 1 rad/s kept turning (56 -> 179 deg)
    stream = FaultyStream(2, RATE_HZ, 5.0, [Fault("silent", 1, 1.0, 2.4)])
    stream.rate_rad_s[:] = 1.0
    engine = _engine(2)
    poses, stale_seen = [], []
    decoder = LineDecoder(_names(2), True, SourceStats())
    for t, lines in stream.ticks():
        pose = engine.push(decoder.feed("".join(lines).encode(), arrival_s=t, final=True),
                           now_s=t)
        if pose is not None:
            poses.append(pose)
            stale_seen.append((t, bool(engine.stats().health.stale[1])))
    engine.push([], now_s=1e6, flush=True)
    silent = [p for p in poses if 1.1 <= p.t_s < 3.4]
    yaw1 = np.unwrap([_yaw(p.q_sensor[1]) for p in silent])
    # at most stale_after_s (0.05 s) of the last rate was integrated: yaw stays put
    assert np.ptp(yaw1) < 0.06
    assert all(stale for t, stale in stale_seen if 1.1 <= t < 3.4)
    assert not any(stale for t, stale in stale_seen if t < 0.99 or t > 3.5)
    sensor = engine.summary()["sensors"]["s1"]
    assert sensor["stale_s"] == pytest.approx(2.4 - 0.05, abs=0.02)
    assert sensor["gaps"] == 1 and sensor["processed"] == 500 - 240
    # after it returns the filter restarts from acc/mag: the heading follows the truth
    end = _yaw(poses[-1].q_sensor[1]) - stream.truth_yaw_rad(1, poses[-1].t_s)
    assert abs(np.angle(np.exp(1j * end))) < math.radians(3.0)


class _BrokenSource(BaseSource):
    """A line source whose port fails after a few polls (a serial adapter pulled out)."""

    def __init__(self) -> None:
        super().__init__(SourceInfo(_names(2), RATE_HZ, True, "broken"))
        self.polls = 0

    def poll(self, timeout_s):
        self.polls += 1
        if self.polls > 3:
            raise OSError("device reports readiness to read but returned no data")
        return []


def test_an_engine_stopped_by_its_source_reports_it_in_the_summary(tmp_path):
    out = tmp_path / "summary.json"
    engine = Engine(SourceInfo(_names(2), RATE_HZ, True), "bachmann", avatars=None,
                    summary_path=str(out))
    with engine.start(_BrokenSource()):
        assert engine.wait(5.0)
    assert not engine.running and "OSError" in engine.error
    summary = json.loads(out.read_text())
    assert "returned no data" in summary["engine"]["error"]
    assert set(summary["sensors"]) == {"s0", "s1"} and summary["engine"]["frames"] == 0
    assert summary["sensors"]["s0"]["received"] == 0
    assert not list(tmp_path.glob(".summary.json.tmp-*"))  # written atomically


def test_headless_cli_writes_the_summary_and_keeps_an_existing_one(tmp_path):
    from margtrack.cli import app

    out = tmp_path / "s.json"
    args = ["live", "--demo", "--preset", "left_arm", "--speed", "inf", "--duration", "1.5",
            "--headless", "--summary", str(out), "--stale-after-s", "0.2"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    summary = json.loads(out.read_text())
    assert summary["engine"]["error"] is None and summary["engine"]["frames"] > 0
    assert summary["engine"]["stale_after_s"] == 0.2
    for sensor in summary["sensors"].values():
        assert sensor["processed"] == summary["engine"]["frames"] == sensor["received"]
        assert sensor["lost"] == sensor["resyncs"] == sensor["reinitialised"] == 0
    before = out.read_text()
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and "already exists" in result.output
    assert out.read_text() == before


def test_fault_soak_short_every_fault_mixed_unaffected_sensors_all_processed():
    duration = 5.0
    stream = FaultyStream(15, RATE_HZ, duration, default_faults(duration))
    engine = _engine(15)
    stats_in = _run(engine, stream)
    expected = stream.expected()
    summary = engine.summary()
    assert summary["engine"]["error"] is None and summary["engine"]["frames"] == 500
    assert stats_in.malformed == 1  # the garbage line, rejected with its reason
    c = engine.stats().health.counts
    for s in range(15):
        name = f"s{s}"
        sensor = summary["sensors"][name]
        assert sensor["received"] == expected["sent"][s] + expected["duplicates"][s], name
        assert sensor["lost"] == expected["dropped"][s], name
        assert sensor["resyncs"] == expected["resyncs"][s], name
        assert sensor["bad_time"] == expected["bad_stamps"][s] + expected["duplicates"][s]
        if s not in stream.affected:
            assert sensor["processed"] == 500 and sensor["held"] == 0, name
            assert sensor["faults"] == 0 and sensor["gaps"] == 0, name
    assert c["processed"][[0, 2, 3, 8]].tolist() == [500] * 4  # reboot, acc 0, gyro, reboot
    assert summary["sensors"]["s4"]["stale_s"] == pytest.approx(1.5 - 0.05, abs=0.02)
    assert c["reinitialised"].sum() == 0
    # every sensor, faulty or not, ends on the true heading
    yaw = _yaw(engine.latest.q_sensor)
    truth = np.array([stream.truth_yaw_rad(s, duration - 0.01) for s in range(15)])
    np.testing.assert_allclose(np.angle(np.exp(1j * (yaw - truth))), 0.0,
                               atol=math.radians(3.0))


def test_bad_fault_and_engine_settings_and_sequence_fields_are_refused():
    with pytest.raises(ValueError, match="unknown fault kind"):
        Fault("meteor", 0, 1.0)
    with pytest.raises(ValueError, match="names sensor 5"):
        FaultyStream(3, faults=[Fault("silent", 5, 1.0, 1.0)])
    with pytest.raises(ValueError, match="stale_after_s must be"):
        _engine(2, stale_after_s=-1.0)
    with pytest.raises(ValueError, match="jump_s must be"):
        _engine(2, clock_jump_s=math.inf)
    with pytest.raises(ValueError, match="sequence number"):
        parse_line_seq("1.0,0,0,0,0,0,0,9.8,1,2,3,-4", ["a"])
    with pytest.raises(ValueError, match="sequence number"):
        parse_line_seq("1.0,0,0,0,0,0,0,9.8,1,2,3,1.5", ["a"])
    with pytest.raises(ValueError, match="seq must be"):
        format_line(0.0, 0, [0, 0, 0], [0, 0, 9.8], None, seq=-1)
    assert parse_line_seq("1.0,0,0,0,0,0,0,9.8,7", ["a"], with_mag=False)[5] == 7
    stats = SourceStats()
    chunks = LineDecoder(["a"], True, stats).feed(b"1.0,0,0,0,0,0,0,9.8,1,2,3,x\n")
    assert chunks == [] and stats.malformed == 1 and "sequence number" in stats.last_error


def test_sensors_on_clocks_of_their_own_are_aligned_at_their_first_sample():
    # sensor 1's clock reads 5000 s when sensor 0's reads 100 s: one session time for both
    engine = _engine(2)
    decoder = LineDecoder(_names(2), True, SourceStats())
    acc, mag = [0.0, 0.0, 9.81], [0.0, 20.0, -35.0]
    for k in range(200):
        lines = [format_line(clock + k / RATE_HZ, s, [0.0, 0.0, 0.0], acc, mag, seq=k)
                 for s, clock in ((0, 100.0), (1, 5000.0))]
        engine.push(decoder.feed("".join(lines).encode(), arrival_s=k / RATE_HZ, final=True),
                    now_s=k / RATE_HZ)
    counts = engine.stats().health.counts
    assert engine.stats().frames == 200 and engine.session_time_s == pytest.approx(1.99)
    assert counts["processed"].tolist() == [200, 200] and counts["held"].tolist() == [0, 0]
    assert counts["resyncs"].tolist() == [0, 1]  # sensor 1 aligned once, at its first line


def test_a_block_source_whose_clock_goes_back_is_resynchronised_whole():
    # a replay or simulator restarting its clock (every sensor at once): nothing discarded
    from margtrack.live.protocol import Chunk

    engine = _engine(2)
    acc = np.tile([0.0, 0.0, 9.81], (2, 50, 1))
    mag = np.tile([0.0, 20.0, -35.0], (2, 50, 1))
    gyr = np.zeros((2, 50, 3))
    for start in (10.0, 0.0):  # 0.5 s from 10 s, then the clock restarts at 0
        t = start + np.arange(50) / RATE_HZ
        engine.push([Chunk(t, np.arange(2), gyr, acc, mag, np.zeros(50))], now_s=0.0)
    stats = engine.stats()
    assert stats.frames == 100 and stats.late_samples == 0
    assert stats.health.counts["resyncs"].tolist() == [1, 1]
    assert engine.session_time_s == pytest.approx(0.99)  # 0.49 + one period + 0.49


class _SlowFirstSource(BaseSource):
    """A source whose first poll takes 6 s, as the worker's first frames do while numba
    compiles the kernels on a cold cache (no stop request interrupts either)."""

    def __init__(self) -> None:
        super().__init__(SourceInfo(_names(2), RATE_HZ, True, "slow first poll"))
        self.polls = 0

    def poll(self, timeout_s):
        self.polls += 1
        if self.polls == 1:
            time.sleep(6.0)
        return []


def test_a_stop_before_the_first_pose_waits_for_the_worker_beyond_the_usual_5_s():
    engine = Engine(SourceInfo(_names(2), RATE_HZ, True), "bachmann", avatars=None)
    engine.start(_SlowFirstSource())
    time.sleep(0.2)
    t0 = time.perf_counter()
    engine.stop()  # no RuntimeError: "the engine's worker did not stop within 5.0 s"
    assert 5.0 < time.perf_counter() - t0 < 10.0
    assert not engine.running and engine.latest is None and engine.error is None
