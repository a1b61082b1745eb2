"""The engine: equal to an offline run, live parameter changes, statistics, shutdown."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from margtrack import body, methods
from margtrack import quaternion as quat
from margtrack.live.engine import MAX_BATCH_FRAMES, Engine
from margtrack.live.lines import format_line
from margtrack.live.protocol import iter_chunks
from margtrack.live.replay import ReplaySource, replay_path
from margtrack.live.simulator import PeopleSimulation, SimulatorSource
from margtrack.live.udp import UdpSource, send_lines
from margtrack.methods.bachmann import BachmannParams


def _live_threads():
    return [t for t in threading.enumerate() if t.name.startswith("margtrack-live")]


@pytest.fixture(scope="module")
def xio_replay(xio_folder):
    full = replay_path(xio_folder, speed=math.inf)
    n = 400  # 8 s at 50 Hz: still reference pose, then walking
    return ReplaySource(full.t_s[:n], full.gyr[:, :n], full.acc[:, :n], full.mag[:, :n],
                        full.info.sensor_names, speed=math.inf, chunk_frames=13)


def test_engine_poses_equal_an_offline_run_of_the_filter_and_body_model(xio_replay):
    source = xio_replay
    engine = Engine(source.info, "default", calibrate_at_start=True, display_hz=25.0)
    poses = engine.subscribe_queue(maxsize=1000)
    engine.start_recording()
    with engine.start(source):
        assert engine.wait(20.0)
    recorded = engine.stop_recording()
    assert not _live_threads()
    assert engine.avatars.skeleton.names[0] == "pelvis" and len(engine.avatars.skeleton) == 7
    # offline: the same filter over the whole series in one call
    offline = methods.create(methods.DEFAULT_METHOD).run(
        gyr=source.gyr, acc=source.acc, mag=source.mag, t=source.t_s)
    q_off = np.swapaxes(offline.quat, 0, 1)  # (N, S, 4)
    np.testing.assert_allclose(recorded.q_sensor, q_off, atol=1e-9)
    session_t = source.t_s - source.t_s[0]  # session time starts at 0 at the first frame
    np.testing.assert_array_equal(recorded.t_s, session_t)
    assert engine.session_origin_s == source.t_s[0] and engine.session_time_s == session_t[-1]
    # calibration: body.calibrate on the same window of offline orientations
    t0, t1 = engine.calibration_window_s
    window = (session_t >= t0) & (session_t <= t1)
    skeleton, index = engine.avatars.skeleton, engine.avatars.index[0]
    offline_cal = body.calibrate(skeleton, q_off[window][:, index])
    np.testing.assert_allclose(engine.calibrations[0].offsets, offline_cal.offsets, atol=1e-9)
    published = [poses.get_nowait() for _ in range(poses.qsize())]
    assert len(published) >= 25  # at least one per display tick crossed by a batch
    root = engine.avatars.root_positions_m[0]
    identity = engine.avatars.identity()[0]
    # the calibration is in force from the end of its batch: the source's chunks of 13
    # frames run in parts of at most MAX_BATCH_FRAMES frames
    i1 = int(np.searchsorted(session_t, t1, side="right")) - 1  # the window's last frame
    chunk, offset = divmod(i1, 13)
    part_end = chunk * 13 + min(13, (offset // MAX_BATCH_FRAMES + 1) * MAX_BATCH_FRAMES)
    in_force_s = session_t[part_end - 1]
    checked = 0
    for pose in published:
        i = pose.index
        assert session_t[i] == pose.t_s
        np.testing.assert_allclose(pose.q_sensor, offline.quat[:, i], atol=1e-9)
        if t1 < pose.t_s <= in_force_s:
            continue
        checked += 1
        cal = identity if pose.t_s <= t1 else offline_cal
        track = body.track(skeleton, cal, q_off[i][index], root)
        np.testing.assert_allclose(pose.joints_m[0], track.joints_m[0], atol=1e-9)
        np.testing.assert_allclose(pose.ends_m[0], track.ends_m[0], atol=1e-9)
        assert np.max(quat.angle_between(pose.q_segment[0], track.q_segment[0])) < 1e-7
    assert checked >= len(published) - 1
    stats = engine.stats()
    assert stats.frames == 400 and stats.samples == 2800 and stats.dropped_samples == 0
    assert stats.batches == 30 * 2 + 2  # 30 chunks of 13 = 8 + 5 frames, then 10 = 8 + 2
    assert stats.poses_published == len(published) and stats.error == ""
    assert 0 <= stats.latency_p50_s <= stats.latency_max_s


def _sim_arrays(seconds=3.0):
    people = PeopleSimulation(preset="left_arm", motion="wave", seed=2)
    return people, people.signals(0, int(seconds * people.rate_hz) + 1)


def test_a_parameter_change_takes_effect_at_the_next_sample():
    people, (t, gyr, acc, mag) = _sim_arrays()
    source = ReplaySource(t, gyr, acc, mag, people.sensor_names, speed=math.inf, chunk_frames=1)
    engine = Engine(source.info, "bachmann")
    chunks = list(iter_chunks(source))
    k = 150
    for chunk in chunks[:k]:
        engine.push([chunk])
    with pytest.raises(ValueError, match="gain"):
        engine.set_params(gain=-1.0)
    default_gain = BachmannParams().gain
    assert engine.params.gain == default_gain
    engine.set_params(gain=2.0, mag_weight=0.3)
    assert engine.params.gain == 2.0 and engine.active_params.gain == default_gain
    engine.start_recording()
    for chunk in chunks[k:]:
        engine.push([chunk])
    assert engine.active_params.gain == 2.0
    q_live = engine.stop_recording().q_sensor
    est = methods.create("bachmann")
    est.run(gyr=gyr[:, :k], acc=acc[:, :k], mag=mag[:, :k], t=t[:k])
    est.set_params(gain=2.0, mag_weight=0.3)
    q_changed = est.run(gyr=gyr[:, k:], acc=acc[:, k:], mag=mag[:, k:], t=t[k:]).quat
    np.testing.assert_allclose(np.swapaxes(q_live, 0, 1), q_changed, atol=1e-12)
    q_unchanged = methods.create("bachmann").run(gyr=gyr, acc=acc, mag=mag, t=t).quat[:, k:]
    # the first sample after the call already ran with the new gain
    assert np.max(quat.angle_between(q_unchanged[:, 0], q_changed[:, 0])) > 1e-6


def test_poses_are_published_at_the_display_rate_with_stats():
    people, (t, gyr, acc, mag) = _sim_arrays(seconds=2.0)
    source = ReplaySource(t, gyr, acc, mag, people.sensor_names, speed=math.inf, chunk_frames=1)
    engine = Engine(source.info, "bachmann", display_hz=25.0)
    seen = []
    engine.subscribe(seen.append)
    broken = engine.subscribe(lambda pose: 1 / 0)
    for chunk in iter_chunks(source):
        engine.push([chunk])
        if len(seen) == 10:
            broken()  # unsubscribe the failing subscriber
    # 201 frames over 2 s at 100 Hz: a pose at t = 0, 0.04, ..., 2.0 (51 display ticks)
    np.testing.assert_allclose([p.t_s for p in seen], np.arange(51) * 0.04, atol=1e-12)
    stats = engine.stats()
    assert stats.poses_published == 51 and stats.subscriber_errors == 10
    assert "ZeroDivisionError" in stats.error
    assert stats.frames == 201 and stats.batches == 201
    assert stats.processing_s_per_sample == pytest.approx(stats.processing_s_per_frame / 3)
    np.testing.assert_allclose(stats.health.rate_hz, 100.0, rtol=1e-6)
    assert stats.health.mag_ok.all()
    assert stats.time_filter_s > 0 and stats.time_publish_s > 0


def test_calibration_finds_the_simulated_mounting_and_gives_up_when_never_still():
    people = PeopleSimulation(preset="lower", seed=7, still_s=2.0)
    source = SimulatorSource(people, speed=math.inf, duration_s=4.0)
    engine = Engine(source.info, "default", calibrate_at_start=True)
    with engine.start(source):
        assert engine.wait(20.0)
    assert engine.calibration_status.startswith("calibrated on 0.")
    errors = quat.angle_between(engine.calibrations[0].offsets, people.mounting[0])
    # the filter's heading error at the start, not the model's: the simulated hard-iron bias
    # (up to ~2 uT horizontal) over the 25 uT horizontal field gives up to atan(2/25) = 4.6 deg
    assert np.degrees(errors).max() < 5.0
    moving = PeopleSimulation(preset="lower", seed=7, still_s=0.0, ramp_s=0.01)
    engine = Engine(SimulatorSource(moving).info, "default")
    engine.request_calibration(duration_s=1.0, timeout_s=2.0)
    source = SimulatorSource(moving, speed=math.inf, duration_s=3.0)
    for chunk in iter_chunks(source):
        engine.push([chunk])
    assert engine.calibration_status.startswith("calibration failed: no still 1.0 s")


def test_engine_stops_cleanly_while_a_live_source_runs():
    source = SimulatorSource(PeopleSimulation(preset="right_leg"), speed=1.0)
    engine = Engine(source.info, "bachmann").start(source)
    queue = engine.subscribe_queue(maxsize=2)
    time.sleep(0.3)
    assert engine.running and _live_threads()
    start = time.perf_counter()
    engine.stop()
    assert time.perf_counter() - start < 1.0
    assert not engine.running and not _live_threads() and source.finished
    assert queue.qsize() <= 2  # a full queue drops its oldest pose, never blocks the engine
    with pytest.raises(ValueError, match="already started"):
        engine.start(source)


def test_engine_tracks_lines_sent_over_udp():
    names = ("s0", "s1")
    source = UdpSource(names, port=0, rate_hz=100.0)
    source.open()
    engine = Engine(source.info, "bachmann", max_wait_s=0.2).start(source)
    try:
        q = quat.from_axis_angle([1.0, 0.0, 0.0], math.radians(30.0))  # sensor 1 rolled 30 deg
        acc = quat.rotate_inverse(np.array([quat.identity(), q]), [0.0, 0.0, 9.81])
        mag = quat.rotate_inverse(np.array([quat.identity(), q]), [0.0, 20.0, -40.0])
        lines = [format_line(0.01 * i, s, [0, 0, 0], acc[s], mag[s])
                 for i in range(50) for s in (0, 1) if (i, s) != (20, 1)]
        lines.append("0.3,s1,broken")
        send_lines(lines, source.address, per_datagram=10)
        end = time.perf_counter() + 5.0
        while engine.stats().frames < 50 and time.perf_counter() < end:
            time.sleep(0.02)
    finally:
        engine.stop()
    stats = engine.stats()
    assert stats.frames == 50 and stats.malformed_lines == 1
    assert stats.health.dropped.tolist() == [0, 1] and stats.dropped_samples == 2
    np.testing.assert_allclose(quat.to_euler(engine.latest.q_sensor)[:, 2],
                               [0.0, math.radians(30.0)], atol=1e-9)
    assert engine.avatars is None and engine.latest.joints_m is None


def test_bad_engine_setups_are_refused():
    info = SimulatorSource().info
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        Engine(info, "nope")
    with pytest.raises(ValueError, match="display_hz must be"):
        Engine(info, display_hz=0.0)
    with pytest.raises(ValueError, match="no recording is running"):
        Engine(info).stop_recording()
    names = UdpSource(["a"], with_mag=False).info
    with pytest.raises(ValueError, match="needs a magnetometer"):
        Engine(names, "triad")
    with pytest.raises(ValueError, match="no body model"):
        Engine(names, "bachmann").request_calibration()
