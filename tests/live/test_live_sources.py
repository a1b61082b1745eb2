"""Replay sources: pacing at a speed factor, x-IMU3 body folders, BROAD and margtrack files."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from margtrack import io, sim
from margtrack.live.protocol import Pacer, iter_chunks
from margtrack.live.replay import ReplaySource, replay_path, replay_recordings
from margtrack.recording import resample


def _arrays(n: int = 101, s: int = 2, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    gyr = rng.normal(0, 0.1, (s, n, 3))
    acc = rng.normal(0, 0.1, (s, n, 3)) + [0, 0, 9.81]
    mag = rng.normal(0, 0.5, (s, n, 3)) + [0, 20, -40]
    return t, gyr, acc, mag


def _collect(source, timeout_s=0.05, limit_s=5.0):
    chunks, end = [], time.perf_counter() + limit_s
    source.open()
    while not source.finished and time.perf_counter() < end:
        chunks.extend(source.poll(timeout_s))
    source.close()
    return chunks


def test_replay_at_four_times_real_speed_takes_a_quarter_of_the_time():
    t, gyr, acc, mag = _arrays()  # 1.0 s of data at 100 Hz
    source = ReplaySource(t, gyr, acc, mag, speed=4.0)
    start = time.perf_counter()
    chunks = _collect(source)
    elapsed = time.perf_counter() - start
    assert 0.24 <= elapsed < 0.45  # 0.25 s of wall time, plus polling slack
    arrival = np.concatenate([c.arrival_s for c in chunks])
    # frame i is due at start + t_i / 4: the arrival stamps are the due times
    # arrival stamps are perf_counter values (seconds since boot): compare absolutely
    np.testing.assert_allclose(np.diff(arrival), 0.01 / 4, rtol=0, atol=1e-9)
    assert arrival[0] == pytest.approx(start, abs=0.02)
    np.testing.assert_array_equal(np.concatenate([c.gyr for c in chunks], axis=1), gyr)
    np.testing.assert_array_equal(np.concatenate([c.t_s for c in chunks]), t)


def test_unpaced_replay_delivers_everything_at_once_in_order():
    t, gyr, acc, mag = _arrays(n=1000, s=3)
    source = ReplaySource(t, gyr, acc, mag, speed=math.inf, chunk_frames=64)
    start = time.perf_counter()
    chunks = list(iter_chunks(source))
    assert time.perf_counter() - start < 0.5
    assert [c.n_frames for c in chunks] == [64] * 15 + [40]
    np.testing.assert_array_equal(np.concatenate([c.mag for c in chunks], axis=1), mag)
    assert source.stats.samples == 3000


def test_looping_replay_continues_the_timestamps():
    t, gyr, acc, _ = _arrays(n=10, s=1)
    source = ReplaySource(t, gyr, acc, None, speed=math.inf, chunk_frames=10, loop=True)
    source.open()
    first, second = source.poll(0.0)[0], source.poll(0.0)[0]
    np.testing.assert_allclose(second.t_s, t + 0.1, atol=1e-12)
    np.testing.assert_array_equal(second.acc, first.acc)
    assert not source.finished and first.mag is None


def test_pacer_maps_data_time_to_wall_time():
    clock = iter([10.0, 10.5]).__next__
    pacer = Pacer(2.0, speed=2.0, clock=clock)
    pacer.start()  # wall 10.0 = data 2.0
    np.testing.assert_allclose(pacer.due_time(np.array([2.0, 3.0])), [10.0, 10.5])
    assert pacer.data_time_now() == pytest.approx(3.0)  # wall 10.5 -> data 2.0 + 0.5 * 2
    with pytest.raises(ValueError, match="speed must be > 0"):
        Pacer(0.0, speed=0.0)


def test_bad_replay_arrays_are_refused():
    t, gyr, acc, _ = _arrays()
    with pytest.raises(ValueError, match=r"t_s must increase strictly: t\[4\]"):
        ReplaySource(np.r_[t[:5], t[4:-1]], gyr, acc)
    with pytest.raises(ValueError, match="acc has a non-finite value at sensor 1, sample 7"):
        bad = acc.copy()
        bad[1, 7, 2] = np.nan
        ReplaySource(t, gyr, bad)
    with pytest.raises(ValueError, match="sensor_names has 1 names for 2 sensors"):
        ReplaySource(t, gyr, acc, sensor_names=["a"])


@pytest.fixture(scope="module")
def xio_body(xio_folder):
    return io.read_xio_body(xio_folder)


def test_xio_body_folder_replays_its_seven_sensors_on_one_time_base(xio_body, xio_folder):
    source = replay_path(xio_folder, speed=math.inf)
    info = source.info
    assert info.sensor_names == (
        "left_foot", "left_lower_leg", "left_upper_leg", "pelvis",
        "right_foot", "right_lower_leg", "right_upper_leg",
    )
    assert info.has_mag and 49.0 < info.rate_hz < 51.0
    rec = xio_body["pelvis"]
    t = source.t_s
    assert t[0] >= max(r.t[0] for r in xio_body.values())
    assert t[-1] <= min(r.t[-1] for r in xio_body.values())
    np.testing.assert_allclose(np.diff(t), 1.0 / info.rate_hz, rtol=1e-9)
    np.testing.assert_allclose(source.gyr[3], resample(rec.t, rec.gyr, t), atol=1e-12)
    np.testing.assert_allclose(source.mag[3], resample(rec.t, rec.mag, t), atol=1e-12)


def test_margtrack_file_and_broad_trial_replay_unchanged(tmp_path, broad_folder):
    rec = sim.simulate(sim.limb_swing(duration_s=3.0, rate_hz=100.0), seed=3, name="arm")
    io.write(rec, tmp_path / "arm.h5")
    source = replay_path(tmp_path / "arm.h5", speed=math.inf)
    assert source.info.sensor_names == ("arm",)
    np.testing.assert_array_equal(source.acc[0], rec.acc)
    np.testing.assert_array_equal(source.t_s, rec.t)
    trial = sorted(broad_folder.glob("*.hdf5"))[0]
    broad = replay_path(trial, speed=math.inf)
    original = io.read_broad(trial)
    np.testing.assert_array_equal(broad.gyr[0], original.gyr)
    assert broad.info.rate_hz == pytest.approx(original.rate_hz, rel=1e-6)
    with pytest.raises(ValueError, match="give one recording file"):
        replay_path(broad_folder)


def test_recordings_on_one_clock_are_stacked_without_resampling():
    recs = [sim.simulate(sim.limb_swing(duration_s=2.0, rate_hz=50.0), seed=s, name=f"s{s}")
            for s in range(3)]
    source = replay_recordings(recs)
    assert source.info.sensor_names == ("s0", "s1", "s2")
    for s, r in enumerate(recs):
        np.testing.assert_array_equal(source.gyr[s], r.gyr)
