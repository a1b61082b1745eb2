"""*Replay again* keeps what the session attached: sensor calibrations and the raw recording.

A real viser server (no browser) and real engines; the button's callback is called as the
page would call it.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from margtrack.calibration import Calibration, TriadCalibration
from margtrack.io.live_hdf5 import read_live_recording
from margtrack.live.calibration_panel import CalibratedSource
from margtrack.live.engine import Engine
from margtrack.live.live_replay import LiveReplaySource
from margtrack.live.replay import ReplaySource
from margtrack.live.viewer_replay import replay_of, rewound

N = 300  # frames of the replay: 3 s at 100 Hz
BIAS = np.array([0.02, -0.03, 0.01])  # rad/s, sensor 1's gyro bias, removed by its calibration


def _replay(speed: float = math.inf) -> ReplaySource:
    """Three sensors turning slowly about different axes, sensor 1 with a gyro bias."""
    rng = np.random.default_rng(5)
    t = 50.0 + 0.01 * np.arange(N)  # a device clock far from 0
    rate = np.array([[0.0, 0.0, 0.3], [0.2, 0.0, 0.0], [0.0, -0.25, 0.0]])
    gyr = np.repeat(rate[:, None, :], N, axis=1) + rng.normal(0.0, 0.002, (3, N, 3))
    gyr[1] += BIAS
    acc = np.tile([0.0, 0.0, 9.81], (3, N, 1)) + rng.normal(0.0, 0.02, (3, N, 3))
    mag = np.tile([0.0, 20.0, -40.0], (3, N, 1))
    return ReplaySource(t, gyr, acc, mag, ("a", "b", "c"), speed=speed, description="turns")


def _bias_calibration() -> Calibration:
    return Calibration(gyr=TriadCalibration("gyr", bias=tuple(BIAS)), source="test bias")


def test_rewound_keeps_the_wrapper_and_its_calibrations():
    plain = _replay()
    wrapped = CalibratedSource(plain, {1: _bias_calibration()})
    assert replay_of(wrapped) is plain and replay_of(plain) is plain
    assert replay_of(CalibratedSource(RawLike())) is None
    fresh = rewound(wrapped)
    assert isinstance(fresh, CalibratedSource) and fresh.inner is not plain
    assert replay_of(fresh) is not None and replay_of(fresh).speed == plain.speed
    assert fresh.calibrations().keys() == {1}
    np.testing.assert_array_equal(fresh.calibration(1).gyr.bias, BIAS)
    # the copy corrects sensor 1 as the original did: its mean rate is the turn, no bias
    chunk = fresh.poll(0.0)[0]
    np.testing.assert_allclose(chunk.gyr[1].mean(axis=0), [0.2, 0.0, 0.0], atol=1e-3)
    assert type(rewound(plain)) is ReplaySource and rewound(None) is None


class RawLike:
    """Not a replay: a source Replay again cannot rewind."""

    info = _replay().info


def _replayed_last_pose(path):
    """The last sensor orientations of a raw recording replayed through a new engine."""
    raw = read_live_recording(path)
    source = LiveReplaySource(raw)
    engine = Engine(source.info, raw.method, raw.params, avatars=None)
    engine.start(source)
    assert engine.wait(30.0)
    engine.stop()
    return raw, engine.latest.q_sensor


def _wait(condition, timeout_s: float, what: str) -> None:
    end = time.perf_counter() + timeout_s
    while not condition():
        if time.perf_counter() > end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def test_replay_again_carries_the_calibrations_and_the_raw_recorder(tmp_path):
    pytest.importorskip("viser", reason="the live page needs viser (pip install viser)")
    from margtrack.live.viewer_session import run_live

    source = CalibratedSource(_replay(), {1: _bias_calibration()})
    record = tmp_path / "raw.hdf5"
    session = run_live(source, "bachmann", port=0, block=False, out_dir=tmp_path,
                       record=record)
    try:
        viewer = session.viewer
        first = session.engine
        _wait(lambda: first.wait(0) and viewer._notice.visible, 20.0, "the replay's end")
        assert "Press *Replay again*" in viewer._notice.content
        panel = viewer.calibration_panel
        panel.source.set_calibration(2, _bias_calibration())  # as the guided panel would
        (tmp_path / "raw_run1.hdf5").write_bytes(b"an older file, kept")
        viewer._replay_again()  # the button
        second = session.engine
        assert second is not first and not first.running
        run1 = tmp_path / "raw_run1_2.hdf5"  # the taken name is never overwritten
        assert viewer.message == ("replaying again (the previous run had 300 frames); raw "
                                  f"recording of that run: {run1}")
        assert (tmp_path / "raw_run1.hdf5").read_bytes() == b"an older file, kept"
        _wait(lambda: second.wait(0), 20.0, "the second run's end")
        # the new engine reads a calibration wrapper with both sensors' calibrations
        assert panel.engine is second and isinstance(panel.source, CalibratedSource)
        assert viewer.source is panel.source and panel.source.inner is not source.inner
        assert panel.source.calibrations().keys() == {1, 2}
        # the first run's raw file replays its poses exactly; sensor 1 corrected (no bias)
        raw1, q1 = _replayed_last_pose(run1)
        assert raw1.n_frames == N
        np.testing.assert_allclose(q1, first.latest.q_sensor, atol=1e-9, rtol=0)
        np.testing.assert_allclose(raw1.gyr[1].mean(axis=0), [0.2, 0.0, 0.0], atol=1e-3)
        np.testing.assert_allclose(raw1.gyr[2].mean(axis=0), [0.0, -0.25, 0.0], atol=1e-3)
        # the recorder of --record went on with the new engine: the second run, from its
        # start, with sensor 2 corrected by the calibration set on the old wrapper
        saved = viewer.raw_recorder.save(record)
        raw2, q2 = _replayed_last_pose(saved)
        assert raw2.n_frames == N and raw2.t_s[0] == 0.0
        np.testing.assert_allclose(q2, second.latest.q_sensor, atol=1e-9, rtol=0)
        np.testing.assert_allclose(raw2.gyr[1].mean(axis=0), [0.2, 0.0, 0.0], atol=1e-3)
        np.testing.assert_allclose(raw2.gyr[2].mean(axis=0), [0.0, -0.25, 0.0] - BIAS,
                                   atol=1e-3)
        assert viewer.raw_runs == [run1]
    finally:
        session.stop()
    assert not [t for t in threading.enumerate() if t.name.startswith("margtrack-live")]


def test_replay_again_without_a_replay_does_nothing():
    """A source that is not a replay offers no Replay again (nothing to rewind)."""
    from margtrack.live.viewer_replay import replay_again

    class Viewer:
        new_engine = None
        source = RawLike()
        engine = Engine(_replay().info, "bachmann", avatars=None)

    assert replay_again(Viewer()) is None
