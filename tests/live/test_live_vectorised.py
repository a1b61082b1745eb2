"""The engine's per-sensor work done over all sensors at once equals the per-sensor loops.

Each vectorised path is checked against the per-sensor (or per-segment, per-sample) code it
replaced, written out here as the oracle, on random inputs: to the last bit where the
operations are the same, and the engine with several people against the offline filters
and body model.
"""

from __future__ import annotations

import itertools
import math
import subprocess
import sys
from collections import deque

import numpy as np
import pytest

from margtrack import body, methods
from margtrack import quaternion as quat
from margtrack.body.kinematics import people_pose
from margtrack.estimator.flags import DATA_FLAGS, FAULT_FLAGS, Flag
from margtrack.live.assembler import Frames
from margtrack.live.avatars import Avatars
from margtrack.live.batch_close_kernel import close_sensors
from margtrack.live.clocks import SensorClocks
from margtrack.live.engine import Engine
from margtrack.live.filtering import SensorFilters
from margtrack.live.protocol import Chunk, iter_chunks
from margtrack.live.replay import ReplaySource
from margtrack.live.simulator import PeopleSimulation
from margtrack.live.stats import StatsMeter


def _unit(rng, *shape):
    return quat.normalize(rng.normal(size=(*shape, 4)))


# -- body model -----------------------------------------------------------------------------
def _positions_per_segment(skeleton, q, root):
    """The former loop: one rotation per segment (000 eq. 11)."""
    joints = np.empty((*q.shape[:-2], len(skeleton), 3))
    joints[..., 0, :] = root
    for i in range(1, len(skeleton)):
        p = skeleton.parents[i]
        joints[..., i, :] = joints[..., p, :] + quat.rotate(q[..., p, :], skeleton.offsets_m[i])
    return joints, joints + quat.rotate(q, skeleton.ends_m)


@pytest.mark.parametrize("preset", ["full", "lower", "left_arm"])
def test_positions_equal_the_per_segment_loop_to_the_last_bit(preset):
    rng = np.random.default_rng(5)
    skeleton = body.Skeleton.from_height(1.8, preset, "NED")
    q = _unit(rng, 40, len(skeleton))
    root = rng.normal(size=(40, 3))
    for got, want in zip(body.positions(skeleton, q, root),
                         _positions_per_segment(skeleton, q, root), strict=True):
        np.testing.assert_array_equal(got, want)
    for got, want in zip(body.positions(skeleton, q[3]),
                         _positions_per_segment(skeleton, q[3], skeleton.root_position_m),
                         strict=True):
        np.testing.assert_array_equal(got, want)


def test_people_pose_equals_eq7_and_positions_per_person_to_the_last_bit():
    rng = np.random.default_rng(8)
    skeleton = body.Skeleton.from_height(1.7, "full", "ENU")
    n_people, k = 6, len(skeleton)
    index = rng.permutation(n_people * k).reshape(n_people, k)  # sensors in any order
    q_sensor = _unit(rng, n_people * k)
    q_sensor[index[2, 4]] *= -1.0  # the sign of an input must not matter
    offsets = _unit(rng, n_people, k)
    roots = rng.normal(size=(n_people, 3))
    q_seg, joints, ends = people_pose(skeleton, q_sensor, index, offsets, roots)
    for a in range(n_people):
        want_q = quat.canonical(quat.multiply(q_sensor[index[a]], offsets[a]))  # eq. 7
        np.testing.assert_array_equal(q_seg[a], want_q)
        want_j, want_e = body.positions(skeleton, want_q, roots[a])  # eq. 11
        np.testing.assert_array_equal(joints[a], want_j)
        np.testing.assert_array_equal(ends[a], want_e)
    assert (q_seg[..., 0] >= 0).all()
    # Avatars.pose is this function on the people's sensors
    names = [f"p{a}/{s}" for a in range(n_people) for s in skeleton.names]
    avatars = Avatars.from_names(names, 1.7, "ENU")
    got = avatars.pose(q_sensor, offsets)
    want = people_pose(avatars.skeleton, q_sensor, avatars.index, offsets,
                            avatars.root_positions_m)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)


def test_people_pose_shared_among_threads_equals_one_pass_and_names_the_first_bad(
        monkeypatch):
    """From THREADED_MIN_SEGMENTS segments the checks and the pose are split among threads
    (people and sensors in parts): the same bits as one pass, the first bad sensor named
    whichever part finds it."""
    import margtrack.body.kinematics as kinematics
    from margtrack.estimator.sensor_threads import thread_count

    rng = np.random.default_rng(9)
    skeleton = body.Skeleton.from_height(1.75, "full", "NED")
    n_people, k = 2100, len(skeleton)
    assert n_people * k >= kinematics.THREADED_MIN_SEGMENTS and thread_count() >= 2
    index = rng.permutation(n_people * k).reshape(n_people, k)
    q_sensor, offsets = _unit(rng, n_people * k), _unit(rng, n_people, k)
    roots = rng.normal(size=(n_people, 3))
    q_copy = np.full_like(q_sensor, np.nan)
    threaded = people_pose(skeleton, q_sensor, index, offsets, roots, q_copy=q_copy)
    np.testing.assert_array_equal(q_copy, q_sensor)  # copied in the check's pass
    monkeypatch.setattr(kinematics, "THREADED_MIN_SEGMENTS", 10 ** 9)
    q_copy[:] = np.nan
    for got, want in zip(threaded, people_pose(skeleton, q_sensor, index, offsets, roots,
                                               q_copy=q_copy), strict=True):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(q_copy, q_sensor)
    monkeypatch.undo()
    with pytest.raises(ValueError, match=r"q_copy must be a writeable C-contiguous float64 "
                                         r"array of shape \(31500, 4\), got float32"):
        people_pose(skeleton, q_sensor, index, offsets, roots,
                    q_copy=np.empty((31500, 4), np.float32))
    last = n_people * k - 1
    for bad_rows, named in (([last], last), ([last, 7], 7)):
        bad = q_sensor.copy()
        bad[bad_rows] = 2.0 * bad[bad_rows]
        with pytest.raises(ValueError, match=rf"q_sensor\[{named}\] is not a unit quaternion "
                                             r"\(norm 2\.0"):
            people_pose(skeleton, bad, index, offsets, roots)


def test_people_pose_refuses_bad_input_naming_it():
    skeleton = body.Skeleton.from_height(1.7, "left_arm", "ENU")
    q = quat.identity(3)
    index, off, roots = np.arange(3)[None], quat.identity((1, 3)), np.zeros((1, 3))
    bad = q.copy()
    bad[1] = [1.0, 1.0, 0.0, 0.0]
    bad[2] = [2.0, 0.0, 0.0, 0.0]  # the first of two is named, with its norm
    with pytest.raises(ValueError, match=r"q_sensor\[1\] is not a unit quaternion "
                                         r"\(norm 1\.4142135623730951\)"):
        people_pose(skeleton, bad, index, off, roots)
    bad[2] = [1.0 + 5e-7, 0.0, 0.0, 0.0]  # within the tolerance (1e-6): accepted
    bad[1] = [0.0, 0.0, 0.0, np.inf]
    with pytest.raises(ValueError, match=r"q_sensor\[1\] is not a unit quaternion \(norm inf"):
        people_pose(skeleton, bad, index, off, roots)
    bad[1] = q[1]
    assert people_pose(skeleton, bad, index, off, roots)[0].shape == (1, 3, 4)
    bad[1] = np.nan
    with pytest.raises(ValueError, match=r"q_sensor\[1\] is not a unit"):
        people_pose(skeleton, bad, index, off, roots)
    with pytest.raises(ValueError, match=r"index must name sensors 0\.\.2"):
        people_pose(skeleton, q, index + 1, off, roots)
    with pytest.raises(ValueError, match=r"need index \(A, 3\)"):
        people_pose(skeleton, q, index[:, :2], off, roots)
    with pytest.raises(ValueError, match=r"q_sensor must have shape \(S, 4\)"):
        people_pose(skeleton, q[:, :3], index, off, roots)


# -- filters: repairs, holds and counts ------------------------------------------------
def _hold_per_sample(q, hold, q_before):
    """The former loop: each held sample takes the one before it."""
    q = q.copy()
    for s in range(q.shape[0]):
        held = q_before[s]
        for k in range(q.shape[1]):
            if hold[s, k]:
                q[s, k] = held
            held = q[s, k]
    return q


def _close_former(q, flags, stale, held, q_last, processed, flagged):
    """The former numpy passes of SensorFilters over one batch (in place, as the kernel)."""
    bad = np.flatnonzero(~np.isfinite(q).all(axis=(1, 2)))
    q_before = q_last[bad]
    q_before[~np.isfinite(q_before).all(axis=1)] = (1.0, 0.0, 0.0, 0.0)
    q[bad] = _hold_per_sample(q[bad], ~np.isfinite(q[bad]).all(axis=2), q_before)
    flags[bad] |= np.uint16(Flag.INITIALISING)
    if stale is not None:
        q[:] = _hold_per_sample(q, stale, q_last)
    q_last[:] = q[:, -1]
    processed += (~held).sum(axis=1)
    flagged += np.count_nonzero(((flags & np.uint16(DATA_FLAGS)) != 0) & ~held, axis=1)
    return bad


@pytest.mark.parametrize("split", [1, 3])
def test_close_sensors_equals_the_former_numpy_passes(split):
    """Non-finite samples filled from the last finite one (or the last batch's, or the
    identity), stale ones held, the last orientation kept, the counts: the same bits as
    the numpy passes it replaced, whether the sensors are done in one part or three."""
    rng = np.random.default_rng(11)
    n_sensors, n = 40, 9
    q_last = _unit(rng, n_sensors)
    q_last[5] = np.nan  # a sensor whose last orientation is not finite: the identity
    processed = rng.integers(0, 50, n_sensors)
    flagged = rng.integers(0, 5, n_sensors)
    want = [q_last.copy(), processed.copy(), flagged.copy()]
    for batch in range(3):
        q = _unit(rng, n_sensors, n)
        q[[2, 5, 7], [0, 3, 8]] = np.nan
        q[7, 4, 2] = np.inf
        q[9, :] = np.nan  # a sensor with no finite sample
        flags = rng.integers(0, 1 << 10, (n_sensors, n)).astype(np.uint16)
        stale = (rng.random((n_sensors, n)) < 0.2) if batch != 1 else None
        held = rng.random((n_sensors, n)) < 0.3
        q_want, flags_want = q.copy(), flags.copy()
        bad_want = _close_former(q_want, flags_want, stale, held, *want)
        bad = np.zeros(n_sensors, dtype=np.bool_)
        edges = [n_sensors * k // split for k in range(split + 1)]
        for lo, hi in itertools.pairwise(edges):
            close_sensors(q, flags, np.zeros((0, 0), bool) if stale is None else stale, held,
                          q_last, processed, flagged, bad, np.uint16(DATA_FLAGS),
                          np.uint16(Flag.INITIALISING), lo, hi)
        np.testing.assert_array_equal(np.flatnonzero(bad), bad_want)
        np.testing.assert_array_equal(q, q_want)
        np.testing.assert_array_equal(flags, flags_want)
        for got, expected in zip((q_last, processed, flagged), want, strict=True):
            np.testing.assert_array_equal(got, expected)
    assert set(bad_want.tolist()) == {2, 5, 7, 9} and np.isfinite(q).all()
    np.testing.assert_array_equal(q[9], np.broadcast_to(q_last[9], (n, 4)))


def test_processed_and_fault_counts_equal_the_dense_per_sensor_sums():
    rng = np.random.default_rng(4)
    n_sensors, n = 5, 40
    filters = SensorFilters(methods.create("default", rate_hz=100.0), n_sensors)
    processed = np.zeros(n_sensors, dtype=np.int64)
    faults = np.zeros(n_sensors, dtype=np.int64)
    for batch in range(4):
        t = (batch * n + np.arange(n)) / 100.0
        gyr = rng.normal(0.0, 0.1, (n_sensors, n, 3))
        acc = np.tile([0.0, 0.0, 9.81], (n_sensors, n, 1)) + rng.normal(0, 0.1, (n_sensors, n, 3))
        mag = np.tile([0.0, 20.0, -40.0], (n_sensors, n, 1))
        bad = rng.random((n_sensors, n)) < 0.1  # flagged by the input policy
        acc[bad] = np.nan
        held = (rng.random((n_sensors, n)) < 0.2) if batch % 2 else np.zeros((n_sensors, n), bool)
        frames = Frames(t, gyr, acc, mag, t.copy(), held)
        _, flags = filters.run(frames)
        processed += (~held).sum(axis=1)  # the former dense formulas
        faults += np.count_nonzero(((flags & np.uint16(FAULT_FLAGS)) != 0) & ~held, axis=1)
        np.testing.assert_array_equal(filters.processed, processed)
        np.testing.assert_array_equal(filters.faults, faults)
    assert faults.sum() > 0 and (processed < 4 * n).any()


def test_sensor_rates_from_sparse_holds_equal_the_dense_window_sum():
    rng = np.random.default_rng(6)
    n_sensors = 4
    meter = StatsMeter(tuple(f"s{i}" for i in range(n_sensors)), window_s=0.5)
    window: deque = deque()
    t0 = 0.0
    for _ in range(60):
        n = int(rng.integers(1, 6))
        t = t0 + np.arange(1, n + 1) / 100.0
        t0 = float(t[-1])
        held = rng.random((n_sensors, n)) < (0.3 if rng.random() < 0.3 else 0.0)
        meter.batch(t, held, None, 1e-3, 0)
        window.append((t0, (~held).sum(axis=1)))  # the former per-batch (S,) counts
        while window and window[0][0] < t0 - 0.5:
            window.popleft()
        span = window[-1][0] - window[0][0]
        want = sum(c for _, c in list(window)[1:]) / span if len(window) >= 2 else 0.0
        np.testing.assert_array_equal(meter.health(np.zeros(n_sensors, np.int64)).rate_hz,
                                      np.broadcast_to(want, (n_sensors,)))


# -- clocks of block sources -------------------------------------------------------------------
class _PerSensorBlockClocks:
    """The former block path: per-sensor lists updated in a Python loop."""

    def __init__(self, n_sensors, period_s, jump_s=1.0):
        self.n, self.period, self.jump = n_sensors, period_s, jump_s
        self.origin = math.nan
        self.offset = [math.nan] * n_sensors
        self.last_session = [math.nan] * n_sensors
        self.received = [0] * n_sensors
        self.resyncs = [0] * n_sensors
        self.restarts = []
        self.block_last = math.nan

    def block(self, t, sensors):
        rows = [int(s) for s in sensors]
        for s in rows:
            self.received[s] += t.size
        if math.isnan(self.origin):
            self.origin = float(t[0])
            self.offset = [self.origin] * self.n
        offset = self.offset[rows[0]]
        first, last = float(t[0]) - offset, self.block_last
        if math.isfinite(last) and not (last < first <= last + self.jump):
            step = float(np.median(np.diff(t))) if t.size > 1 else self.period
            offset = float(t[0]) - (last + step)
            for s in rows:
                self.offset[s] = offset
                self.resyncs[s] += 1
            self.restarts.extend((s, last + step) for s in rows)
        session = t - offset
        self.block_last = float(session[-1])
        for s in rows:
            self.last_session[s] = float(session[-1])
        return session


def test_block_clocks_equal_the_per_sensor_loop():
    n_sensors = 6
    clocks = SensorClocks(n_sensors, 100.0)
    oracle = _PerSensorBlockClocks(n_sensors, 0.01)
    everyone, some = np.arange(n_sensors), np.array([4, 1, 2])
    blocks = [(50.0, everyone, 5), (50.05, some, 3), (50.08, everyone, 4),
              (3.0, everyone, 2), (3.02, some, 1), (900.0, everyone, 3), (900.03, some, 2)]
    for start, sensors, n in blocks:  # a reset to 3 s and a jump to 900 s on the way
        t = start + np.arange(n) / 100.0
        zeros = np.zeros((sensors.size, n, 3))
        chunk = Chunk(t, sensors, zeros, zeros, None, np.zeros(n))
        (mapped,) = clocks.map([chunk])
        np.testing.assert_array_equal(mapped.t_s, oracle.block(t, sensors))
    np.testing.assert_array_equal(clocks.offset_s, oracle.offset)
    np.testing.assert_array_equal(clocks.last_session_s, oracle.last_session)
    np.testing.assert_array_equal(clocks.received, oracle.received)
    np.testing.assert_array_equal(clocks.resyncs, oracle.resyncs)
    expanded = sorted((int(s), t) for rows, t in clocks.restarts for s in rows)
    assert expanded == sorted(oracle.restarts) and len(expanded) == 2 * n_sensors


# -- the engine with several people ------------------------------------------------------------
def test_an_engine_of_several_people_equals_the_offline_filters_and_body_model():
    people = PeopleSimulation(n_people=3, rate_hz=100.0, seed=9)
    t, gyr, acc, mag = people.signals(300, 60)
    source = ReplaySource(t, gyr, acc, mag, people.sensor_names, speed=math.inf,
                          chunk_frames=7)
    engine = Engine(source.info, "bachmann", display_hz=25.0)
    poses = []
    engine.subscribe(poses.append)
    engine.start_recording()
    for chunk in iter_chunks(source):
        engine.push([chunk])
    engine.push([], flush=True)
    q_live = engine.stop_recording().q_sensor  # (N, S, 4)
    offline = methods.create("bachmann").run(gyr=gyr, acc=acc, mag=mag, t=t).quat
    np.testing.assert_allclose(np.swapaxes(q_live, 0, 1), offline, atol=1e-12)
    avatars = engine.avatars
    assert avatars.n_people == 3 and len(poses) >= 6
    identity = avatars.identity()[0]
    for pose in poses:
        for a in range(3):
            track = body.track(avatars.skeleton, identity, pose.q_sensor[avatars.index[a]],
                               avatars.root_positions_m[a])
            np.testing.assert_allclose(pose.joints_m[a], track.joints_m[0], atol=1e-12)
            np.testing.assert_allclose(pose.ends_m[a], track.ends_m[0], atol=1e-12)
            np.testing.assert_allclose(pose.q_segment[a], track.q_segment[0], atol=1e-12)
    counts = engine.stats().health.counts
    assert counts["processed"].tolist() == [60] * 45 and counts["received"].sum() == 60 * 45


def test_the_live_package_exports_every_public_class_lazily():
    code = (
        "import sys, margtrack.live as live\n"
        "names = [n for n in live.__all__ if n != 'run_live']\n"
        "objs = [getattr(live, n) for n in names]\n"
        "assert all(o.__name__ == n for o, n in zip(objs, names)), names\n"
        "print(sorted(m for m in ('viser', 'serial', 'pylsl') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"
    import margtrack.live as live

    for name in ("OscSource", "LslSource", "RawRecorder", "LiveReplaySource", "FaultyStream",
                 "Pose", "Engine", "SensorHealth"):
        assert name in live.__all__ and name in dir(live)
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        live.Nope  # noqa: B018
