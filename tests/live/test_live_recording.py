"""Raw live recording (live/recording.py RawRecorder, io/live_hdf5.py) and its exact replay."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from margtrack import io
from margtrack.io.live_hdf5 import read_live_recording, write_live_recording
from margtrack.live.engine import Engine
from margtrack.live.protocol import Chunk
from margtrack.live.recording import RawRecorder
from margtrack.live.replay import LiveReplaySource, replay_path
from margtrack.live.simulator import PeopleSimulation, SimulatorSource


def _pieces(chunk: Chunk, size: int) -> list[Chunk]:
    """A block chunk cut into chunks of ``size`` frames (more engine batches)."""
    out = []
    for i in range(0, chunk.n_frames, size):
        sl = slice(i, i + size)
        out.append(Chunk(chunk.t_s[sl], chunk.sensors, chunk.gyr[:, sl], chunk.acc[:, sl],
                         None if chunk.mag is None else chunk.mag[:, sl], chunk.arrival_s[sl]))
    return out


def _session(duration_s: float = 3.0, nan_at: int | None = None):
    """A recorded session: simulator -> engine (batches of 7 frames), a parameter change,
    a calibration; returns (engine, raw recording, poses, orientation recording)."""
    sim = PeopleSimulation(n_people=1, preset="lower", motion="walk", seed=3)
    src = SimulatorSource(sim, speed=math.inf, duration_s=duration_s)
    engine = Engine(src.info, "default", calibrate_at_start=True)
    recorder = RawRecorder(engine)
    recorder.start()
    engine.start_recording()
    poses = []
    engine.subscribe(poses.append)
    src.open()
    batch = 0
    while not src.finished:
        for piece in _pieces(src.poll(0.0)[0], 7):
            if nan_at is not None and batch == nan_at:
                piece.gyr[1, 0, 0] = np.nan  # one sensor sends one bad sample
            engine.push([piece])
            batch += 1
            if batch == 20:
                engine.set_params(tau_acc_s=1.0, bias_max_deg_s=3.0)
    return engine, recorder.stop(), poses, engine.stop_recording()


def _replay(raw, attach: bool = True):
    source = LiveReplaySource(raw)
    engine = Engine(source.info, raw.method, raw.params)
    poses = []
    engine.subscribe(poses.append)
    engine.start_recording()
    if attach:
        engine.start(source)  # attaches the replay: events re-applied
        assert engine.wait(60.0)
        engine.stop()
    else:  # the same batches without the events
        source.open()
        while not source.finished:
            engine.push(source.poll(0.0))
    return engine, poses, engine.stop_recording()


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    engine, raw, poses, orient = _session()
    path = tmp_path_factory.mktemp("rec") / "session.hdf5"
    write_live_recording(raw, path)
    return engine, raw, poses, orient, path


def test_recording_holds_the_stream_and_events(session) -> None:
    engine, raw, _, orient, path = session
    back = read_live_recording(path)
    assert back.sensor_names == engine.info.sensor_names
    assert back.n_frames == orient.n_frames == 301
    assert np.array_equal(back.t_s, orient.t_s)
    assert np.array_equal(back.gyr, raw.gyr) and np.array_equal(back.mag, raw.mag)
    # simulator blocks of 100, 100, 100 and 1 frames, each cut into pieces of 7
    assert back.batch_frames.tolist() == ([7] * 14 + [2]) * 3 + [1]
    kinds = [(e.frame, e.kind) for e in back.events]
    assert kinds[0] == (0, "calibration")  # identity offsets at the start
    assert (135, "params") in kinds  # the 21st batch starts at frame 100 + 5 * 7
    assert back.events[kinds.index((135, "params"))].data["params"]["tau_acc_s"] == 1.0
    cal = [e for e in back.events if e.kind == "calibration" and e.frame > 0]
    assert len(cal) == 1 and 0 < cal[0].frame < 135  # the still second at the start
    assert cal[0].t_s == back.t_s[cal[0].frame]
    assert back.method == engine.method and back.params["tau_acc_s"] == 3.0


def test_replay_reproduces_the_session_poses(session) -> None:
    _, _, poses, orient, path = session
    engine, replayed, orient2 = _replay(read_live_recording(path))
    assert [p.index for p in replayed] == [p.index for p in poses]
    assert len(poses) > 10
    for a, b in zip(poses, replayed, strict=True):
        assert a.t_s == b.t_s
        np.testing.assert_allclose(b.q_sensor, a.q_sensor, atol=1e-9, rtol=0)
        np.testing.assert_allclose(b.q_segment, a.q_segment, atol=1e-9, rtol=0)
    np.testing.assert_allclose(orient2.q_sensor, orient.q_sensor, atol=1e-9, rtol=0)
    assert engine.params.tau_acc_s == 1.0 and engine.params.bias_max_deg_s == 3.0


def test_replay_without_the_events_differs(session) -> None:
    """The events matter: without them the segments and (after the change) sensors differ."""
    _, raw, poses, orient, _ = session
    _, replayed, orient2 = _replay(raw, attach=False)
    seg = max(np.abs(a.q_segment - b.q_segment).max() for a, b in zip(poses, replayed,
                                                                        strict=True))
    assert seg > 1e-3
    assert np.abs(orient2.q_sensor[135:] - orient.q_sensor[135:]).max() > 1e-9
    np.testing.assert_array_equal(orient2.q_sensor[:135], orient.q_sensor[:135])


def test_read_any_and_recordings(session) -> None:
    engine, raw, _, _, path = session
    recs = io.read_any(path)
    assert [r.name for r in recs] == list(engine.info.sensor_names)
    np.testing.assert_array_equal(recs[2].gyr, raw.gyr[2])
    np.testing.assert_array_equal(recs[2].t, raw.t_s)
    with pytest.raises(ValueError, match="live recording of several sensors"):
        io.read(path)


def test_non_finite_sample_is_kept_and_flagged(tmp_path) -> None:
    _, raw, _, _ = _session(1.0, nan_at=3)
    path = write_live_recording(raw, tmp_path / "nan.hdf5")
    back = read_live_recording(path)
    assert np.isnan(back.gyr[1, 21, 0])  # batch 3's first frame: kept as sent
    recs = back.recordings
    name = back.sensor_names[1]
    assert recs[name].meta["dropped_frames"] == [21]
    assert recs[name].t.size == back.n_frames - 1
    assert recs[back.sensor_names[0]].t.size == back.n_frames


def test_write_is_atomic_and_refuses_overwrite(session, tmp_path) -> None:
    _, raw, _, _, path = session
    out = tmp_path / "a.hdf5"
    write_live_recording(raw, out)
    before = out.read_bytes()
    with pytest.raises(FileExistsError, match="--force"):
        write_live_recording(raw, out)
    assert out.read_bytes() == before
    write_live_recording(raw, out, force=True)
    assert [p.name for p in tmp_path.iterdir()] == ["a.hdf5"]  # no temporary file left
    back = read_live_recording(path)
    with pytest.raises(ValueError, match="is the input"):
        write_live_recording(back, path, force=True)


def test_truncated_file_is_named(session, tmp_path) -> None:
    path = session[4]
    bad = tmp_path / "cut.hdf5"
    bad.write_bytes(path.read_bytes()[:5000])
    with pytest.raises(ValueError, match=r"cut\.hdf5.*truncated"):
        read_live_recording(bad)


def _damaged(src, dst, edit) -> None:
    dst.write_bytes(src.read_bytes())
    with h5py.File(dst, "r+") as f:
        edit(f)


def test_missing_sensor_group_is_named(session, tmp_path) -> None:
    path, name = session[4], session[0].info.sensor_names[1]
    bad = tmp_path / "missing.hdf5"
    _damaged(path, bad, lambda f: f.__delitem__(f"sensors/{name}"))
    with pytest.raises(ValueError, match=rf"missing\.hdf5: sensor group 'sensors/{name}'"):
        read_live_recording(bad)


def test_non_monotonic_time_is_named(session, tmp_path) -> None:
    path, name = session[4], session[0].info.sensor_names[0]

    def edit(f):
        t = f[f"sensors/{name}/t"]
        values = t[()]
        values[50] = values[10]
        t[...] = values

    bad = tmp_path / "clock.hdf5"
    _damaged(path, bad, edit)
    with pytest.raises(ValueError, match=r"clock\.hdf5.*/t is not strictly increasing: t\[49\]"):
        read_live_recording(bad)


def test_foreign_file_is_refused(tmp_path) -> None:
    other = tmp_path / "other.hdf5"
    with h5py.File(other, "w") as f:
        f["t"] = np.arange(3.0)
    with pytest.raises(ValueError, match="not a margtrack live recording"):
        read_live_recording(other)


def test_replay_path_of_a_live_recording(session) -> None:
    source = replay_path(session[4], speed=math.inf)
    assert isinstance(source, LiveReplaySource)
    assert source.method == session[1].method
    with pytest.raises(ValueError, match="replays as recorded"):
        replay_path(session[4], loop=True)


def test_cli_record_then_replay(tmp_path) -> None:
    """``margtrack live --record`` headless, then ``--replay`` of the file, same frames."""
    from margtrack.cli import app

    out = tmp_path / "cli.hdf5"
    runner = CliRunner()
    # 5 s: the first batch waits for the compiled filters to load (about 2 s here)
    args = ["live", "--demo", "--preset", "lower", "--headless", "--speed", "5",
            "--duration", "5", "--record", str(out)]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    assert "raw recording:" in first.output and out.is_file()
    again = runner.invoke(app, args)
    assert again.exit_code == 2 and "--force" in again.output
    rec = read_live_recording(out)
    assert rec.n_frames > 100
    replay = runner.invoke(app, ["live", "--replay", str(out), "--headless", "--speed", "inf"])
    assert replay.exit_code == 0, replay.output
    assert f"replaying {rec.n_frames} frames" in replay.output
    assert f"{rec.n_frames} frames, " in replay.output  # the engine processed every frame


def test_page_recording_writes_numbered_raw_files(tmp_path) -> None:
    """The page's Start/Stop recording for the raw stream (live/calibration_panel.py)."""
    import types

    from margtrack.live.calibration_panel import page_recording

    sim = PeopleSimulation(n_people=1, preset="lower", motion="walk", seed=4)
    src = SimulatorSource(sim, speed=math.inf, duration_s=1.5)  # blocks of 100 and 51
    engine = Engine(src.info, "default")
    viewer = types.SimpleNamespace(engine=engine, out_dir=tmp_path / "out")
    hooks = len(engine.after_batch)
    paths = []
    src.open()
    for _ in range(2):
        page_recording(viewer, True)
        assert len(engine.after_batch) == hooks + 1
        engine.push(src.poll(0.0))
        paths.append(page_recording(viewer, False))
        assert len(engine.after_batch) == hooks  # detached after its recording
    assert [p.name for p in paths] == ["live_raw.hdf5", "live_raw_2.hdf5"]
    first, second = (read_live_recording(p) for p in paths)
    assert first.n_frames == 100 and second.n_frames == 51
    assert page_recording(viewer, False) is None  # nothing running: nothing written
    page_recording(viewer, True)
    with pytest.raises(ValueError, match="holds no frame"):  # the page shows the message
        page_recording(viewer, False)
    assert len(engine.after_batch) == hooks


def test_cli_page_mode_record(tmp_path) -> None:
    """``margtrack live`` with the page (viser on a free loopback port) and ``--record``:
    the recorder starts with the engine, so the file replays the whole session."""
    pytest.importorskip("viser", reason="viser (live extra) is not installed")
    from margtrack.cli import app

    out = tmp_path / "page.hdf5"
    result = CliRunner().invoke(app, ["live", "--demo", "--preset", "lower", "--port", "0",
                                      "--speed", "10", "--duration", "5", "--record", str(out),
                                      "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    rec = read_live_recording(out)
    assert rec.n_frames > 50
    assert rec.t_s[0] == 0.0  # from the session's first frame
    assert [e.kind for e in rec.events][:1] == ["calibration"]


def test_cli_sensor_calibration_option(tmp_path) -> None:
    from margtrack.calibration import Calibration, save_calibration
    from margtrack.cli import app

    cal = save_calibration(Calibration(source="test"), tmp_path / "c.json")
    args = ["live", "--demo", "--preset", "lower", "--headless", "--speed", "20",
            "--duration", "0.5"]
    ok = CliRunner().invoke(app, [*args, "--sensor-calibration", f"pelvis={cal}"])
    assert ok.exit_code == 0, ok.output
    bad = CliRunner().invoke(app, [*args, "--sensor-calibration", f"elbow={cal}"])
    assert bad.exit_code == 2 and "give NAME=FILE with NAME one of pelvis" in bad.output


def test_replay_reproduces_a_stale_sensor_and_its_restart(tmp_path) -> None:
    """Line-by-line samples of two sensors; sensor b is silent for 1 s (stale, then its
    filter restarts): the replay holds and restarts it where the session did."""
    from margtrack.live.protocol import SourceInfo

    info = SourceInfo(("a", "b"), 100.0, True, "lines")
    engine = Engine(info, "default", avatars=None)
    recorder = RawRecorder(engine)
    recorder.start()
    engine.start_recording()
    rng = np.random.default_rng(0)
    now = 0.0
    for i in range(600):
        chunks = []
        for s in (0, 1):
            if s == 1 and 200 <= i < 300:
                continue
            gyr = rng.normal(0.0, 0.1, (1, 1, 3))
            acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.05, (1, 1, 3))
            mag = np.array([0.0, 20.0, -40.0]).reshape(1, 1, 3)
            chunks.append(Chunk(np.array([100.0 + i / 100]), np.array([s]), gyr, acc, mag,
                                np.array([now])))
        now += 0.01
        engine.push(chunks, now_s=now)
    engine.push([], now_s=now + 1.0, flush=True)
    path = write_live_recording(recorder.stop(), tmp_path / "stale.hdf5")
    session = engine.stop_recording()
    raw = read_live_recording(path)
    assert raw.t_s[0] == 0.0 and raw.meta["session_origin_s"] == 100.0  # device time kept
    assert raw.held[1].sum() == 100 and raw.stale[1].sum() > 50 and not raw.stale[0].any()
    assert raw.restart[1].any() and not raw.restart[0].any()
    assert raw.recordings["b"].t.size == 500  # the held samples are not b's own
    _, _, replayed = _replay(raw)
    np.testing.assert_allclose(replayed.q_sensor, session.q_sensor, atol=1e-9, rtol=0)
    _, _, plain = _replay(raw, attach=False)  # the same frames without the session's flags
    assert np.abs(plain.q_sensor[:, 1] - session.q_sensor[:, 1]).max() > 1e-3
