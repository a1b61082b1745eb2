"""The engine's hot path: ``run_into`` equals ``run`` to the bit, buffers are reused, and the
engine on it equals the engine on ``run`` under every field fault."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import methods
from margtrack.estimator.compiled import UNRUN
from margtrack.estimator.flags import Flag
from margtrack.live.buffers import BatchBuffers
from margtrack.live.engine import Engine
from margtrack.live.faults import FaultyStream, default_faults
from margtrack.live.lines import LineDecoder
from margtrack.live.protocol import SourceInfo, SourceStats

RATE_HZ = 100.0


def _signals(n_sensors, n, seed=3):
    """Seeded (S, N, 3) rates, specific forces and fields of sensors turning slowly, with a
    non-finite rate, a zero accelerometer and a magnetic spike to be flagged and skipped."""
    rng = np.random.default_rng(seed)
    gyr = rng.normal(0.0, 0.3, (n_sensors, n, 3))
    acc = rng.normal(0.0, 0.2, (n_sensors, n, 3)) + [0.0, 0.0, 9.81]
    mag = rng.normal(0.0, 0.5, (n_sensors, n, 3)) + [20.0, 2.0, -40.0]
    gyr[1, 7] = np.nan
    acc[2, 12] = 0.0
    mag[0, 20] *= 5.0
    return gyr, acc, mag


@pytest.mark.parametrize("method", ["robust", "bachmann", "gradient"])
def test_run_into_equals_run_to_the_bit_batch_after_batch(method):
    n_sensors, n, batch = 3, 40, 8
    gyr, acc, mag = _signals(n_sensors, n)
    t = np.arange(n) / RATE_HZ
    t[24:] += 0.5  # a gap: both restart after it
    ref, hot = methods.create(method, rate_hz=RATE_HZ), methods.create(method, rate_hz=RATE_HZ)
    q = np.empty((n_sensors, batch, 4))
    x = np.empty((n_sensors, batch, hot.run_width))
    flags = np.empty((n_sensors, batch), dtype=np.uint16)
    clock = np.empty(1)
    seen = 0
    for a in range(0, n, batch):
        part = slice(a, a + batch)
        g, ac, m = (np.ascontiguousarray(v[:, part]) for v in (gyr, acc, mag))
        inputs = [v.copy() for v in (g, ac, m)]
        est = ref.run(gyr=g, acc=ac, mag=m, t=t[part], check_units=False)
        hot.run_into(t[part].copy(), g, ac, m, q, x, flags, clock)
        np.testing.assert_array_equal(q, est.quat)
        np.testing.assert_array_equal(flags, est.flags)
        full = x
        if hasattr(hot.kernel, "expand"):  # a kernel that keeps N_LEAN values: expand them
            full = np.empty((n_sensors, batch, sum(w for _, w in hot.outputs_layout)))
            hot.kernel.expand(hot._coefs, q, x, full)
        start = 0
        for name, w in hot.outputs_layout:  # run's outputs, some squeezed and typed
            values = est.outputs[name]
            mine = full[..., start : start + w].reshape(values.shape).astype(values.dtype)
            np.testing.assert_array_equal(mine, values, err_msg=name)
            start += w
        np.testing.assert_array_equal(hot.state.rows, ref.state.rows)
        np.testing.assert_array_equal(hot.state.clock, ref.state.clock)
        np.testing.assert_array_equal(hot.flags, ref.flags)
        assert clock[0] == t[a - 1] if a else np.isnan(clock[0])  # the clock before the batch
        for before, after in zip(inputs, (g, ac, m), strict=True):
            np.testing.assert_array_equal(before, after)  # inputs never modified
        seen |= int(np.bitwise_or.reduce(flags, axis=None))
    assert seen & Flag.GAP and seen & Flag.ACC_IGNORED  # flagged as by run


@pytest.mark.parametrize(("method", "n_sensors"), [("robust", 3), ("robust", 40),
                                                   ("bachmann", 40), ("gradient", 40),
                                                   ("ekf", 3)])
def test_run_into_without_the_extra_outputs_equals_run(method, n_sensors):
    # x_out (S, N, 0): the lockstep blocks (S >= 16) write none, the per-sensor kernels a
    # scratch array; orientations, flags and state as run's, batch after batch
    n, batch = 40, 8
    gyr, acc, mag = _signals(n_sensors, n, seed=5)
    t = np.arange(n) / RATE_HZ
    t[24:] += 0.5
    ref, hot = methods.create(method, rate_hz=RATE_HZ), methods.create(method, rate_hz=RATE_HZ)
    assert hot._in_lanes(n_sensors) == (n_sensors >= 16 and method != "ekf")
    q, flags = np.empty((n_sensors, batch, 4)), np.empty((n_sensors, batch), dtype=np.uint16)
    none = np.empty((n_sensors, batch, 0))
    for a in range(0, n, batch):
        g, ac, m = (np.ascontiguousarray(v[:, a:a + batch]) for v in (gyr, acc, mag))
        est = ref.run(gyr=g, acc=ac, mag=m, t=t[a:a + batch], check_units=False)
        hot.run_into(t[a:a + batch].copy(), g, ac, m, q, none, flags)
        np.testing.assert_array_equal(q, est.quat)
        np.testing.assert_array_equal(flags, est.flags)
        rows = hot.state.rows.copy()
        if hasattr(hot.kernel, "E_GEN"):  # the generation of each estimator's coefficients
            rows[:, hot.kernel.E_GEN] = ref.state.rows[:, hot.kernel.E_GEN]
        np.testing.assert_array_equal(rows, ref.state.rows)
    with pytest.raises(ValueError, match=r"x_out must be C-contiguous float64 of shape "
                                         rf"\({n_sensors}, 8, {hot.run_width}\)"):
        hot.run_into(t[:batch] + 1.0, g, ac, m, q, np.empty((n_sensors, batch, 1)), flags)


@pytest.mark.parametrize("method", ["robust", "bachmann", "gradient", "ekf"])
@pytest.mark.parametrize("parallel", [False, True])
def test_run_into_on_frame_major_inputs_equals_the_per_sensor_layout(method, parallel):
    # (N, S, 3) inputs as the live sources deliver them: the lockstep blocks read them where
    # they are (75 sensors: two full blocks and a partial one, split over threads at a block
    # edge); ekf has no blocks and gets a copy. Bit for bit the per-sensor call's results,
    # batch after batch, across a gap; the wrong layout named.
    n_sensors, n, batch = 75, 40, 8
    gyr, acc, mag = _signals(n_sensors, n, seed=9)
    gyr[7, 13] = np.nan  # a screened sample in one sensor
    t = np.arange(n) / RATE_HZ
    t[24:] += 0.5
    ref = methods.create(method, rate_hz=RATE_HZ)
    hot = methods.create(method, rate_hz=RATE_HZ)
    assert hot.takes_frames(n_sensors) == (method != "ekf")
    q_ref, q = np.empty((n_sensors, batch, 4)), np.empty((n_sensors, batch, 4))
    f_ref, f = (np.empty((n_sensors, batch), dtype=np.uint16) for _ in range(2))
    none = np.empty((n_sensors, batch, 0))
    for a in range(0, n, batch):
        per_sensor = [np.ascontiguousarray(v[:, a:a + batch]) for v in (gyr, acc, mag)]
        frames = [np.ascontiguousarray(np.swapaxes(v, 0, 1)) for v in per_sensor]
        ref.run_into(t[a:a + batch].copy(), *per_sensor, q_ref, none, f_ref, parallel=parallel)
        hot.run_into(t[a:a + batch].copy(), *frames, q, none, f, parallel=parallel,
                     frame_major=True)
        np.testing.assert_array_equal(q, q_ref)
        np.testing.assert_array_equal(f, f_ref)
        rows = hot.state.rows.copy()
        if hasattr(hot.kernel, "E_GEN"):  # the generation of each estimator's coefficients
            rows[:, hot.kernel.E_GEN] = ref.state.rows[:, hot.kernel.E_GEN]
        np.testing.assert_array_equal(rows, ref.state.rows)
        if a == 8:  # the NaN rate was flagged, at its sensor and sample only
            assert f[7, 13 - a] & Flag.INVALID and not f[6, 13 - a] & Flag.INVALID
    with pytest.raises(ValueError, match=rf"acc must be C-contiguous float64 of shape "
                                         rf"\({batch}, {n_sensors}, 3\) \(frame-major\)"):
        hot.run_into(t[:batch] + 9.0, *frames[:1], per_sensor[1], frames[2], q, none, f,
                     frame_major=True)


def test_run_into_refuses_buffers_of_the_wrong_shape_or_layout_naming_them():
    est = methods.create("robust", rate_hz=RATE_HZ)
    gyr, acc, mag = (v[:, :4].copy() for v in _signals(3, 24))
    t = np.arange(4) / RATE_HZ
    # robust's extra outputs: 6-D quaternion, bias, its deviation, hard-iron offset
    q, x = np.empty((3, 4, 4)), np.empty((3, 4, 13))
    flags = np.empty((3, 4), dtype=np.uint16)
    with pytest.raises(ValueError, match=r"q_out must be C-contiguous float64 of shape \(3, 4"):
        est.run_into(t, gyr, acc, mag, np.empty((3, 8, 4))[:, :4], x, flags)
    with pytest.raises(ValueError, match="flags_out must be C-contiguous uint16"):
        est.run_into(t, gyr, acc, mag, q, x, flags.astype(np.int64))
    with pytest.raises(ValueError, match=r"gyr must be C-contiguous float64 of shape \(3, 4, 3\)"):
        est.run_into(t, gyr[:, :2], acc, mag, q, x, flags)
    with pytest.raises(ValueError, match="needs gyroscope data"):
        est.run_into(t, None, acc, mag, q, x, flags)
    assert est.state is None  # nothing ran
    est.run_into(t, gyr, acc, mag, q, x, flags)
    with pytest.raises(ValueError, match="the state holds 3 sensor"):
        est.run_into(t + 0.04, gyr[:2].copy(), acc[:2].copy(), mag[:2].copy(), q[:2].copy(),
                     x[:2].copy(), flags[:2].copy())


def test_batch_buffers_reuse_their_memory_and_copy_only_strided_inputs():
    buf = BatchBuffers(5, {"acc": (3, np.float64), "flags": (0, np.uint16)})
    a4 = buf.get("acc", 4)
    assert a4.shape == (5, 4, 3) and a4.flags.c_contiguous
    a2 = buf.get("acc", 2)  # fewer frames: the same block
    assert a2.shape == (5, 2, 3) and np.shares_memory(a2, a4)
    a9 = buf.get("acc", 9)  # more frames than held: a new block
    assert a9.shape == (5, 9, 3) and not np.shares_memory(a9, a4)
    assert buf.get("flags", 3).shape == (5, 3) and buf.get("flags", 3).dtype == np.uint16
    whole = np.arange(5 * 10 * 3, dtype=float).reshape(5, 10, 3)
    assert buf.contiguous("acc", whole) is whole  # contiguous: used as it is
    strided = whole[:, 3:7]
    copied = buf.contiguous("acc", strided)
    assert copied.flags.c_contiguous and np.shares_memory(copied, buf.get("acc", 4))
    np.testing.assert_array_equal(copied, strided)


@pytest.mark.kernel
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_batch_buffers_copy_frame_major_batches_value_for_value(dtype):
    # a source's batch: frames of all sensors together, (N, S, 3) in memory, seen as (S, N, 3)
    buf = BatchBuffers(7, {"gyr": (3, np.float64)})
    memory = np.random.default_rng(1).normal(size=(10, 7, 3)).astype(dtype)
    memory[2, 4, 1], memory[5, 0, 2], memory[6, 6, 0] = np.nan, np.inf, -0.0  # kept as they are
    whole = np.swapaxes(memory, 0, 1)
    for a, b in ((3, 7), (0, 10), (9, 10)):
        batch = whole[:, a:b]
        copied = buf.contiguous("gyr", batch)
        assert copied.flags.c_contiguous and copied.dtype == np.float64
        np.testing.assert_array_equal(copied, batch.astype(np.float64))
        assert np.array_equal(np.signbit(copied), np.signbit(batch))


@pytest.mark.kernel
def test_batch_buffers_copy_a_large_batch_on_threads_value_for_value(monkeypatch):
    # the three inputs of a batch in one call, the sensors split among three threads (at
    # uneven bounds: 10 sensors), a missing field left None
    import threading

    from margtrack.live import buffers

    monkeypatch.setattr(buffers, "THREADED_COPY_MIN_SAMPLES", 40)
    started = []
    thread_init = threading.Thread.__init__

    def counted(self, *args, **kwargs):
        if str(kwargs.get("name")).startswith("margtrack-copy"):  # (not other tests' threads)
            started.append(kwargs.get("name"))
        thread_init(self, *args, **kwargs)

    monkeypatch.setattr(threading.Thread, "__init__", counted)
    buf = BatchBuffers(10, {k: (3, np.float64) for k in ("gyr", "acc", "mag")})
    memory = np.random.default_rng(2).normal(size=(2, 4, 10, 3))
    memory[0, 3, 9, 2], memory[1, 0, 0, 0] = np.nan, -np.inf
    gyr, acc = (np.swapaxes(m, 0, 1) for m in memory)  # (10, 4, 3) views, frame-major
    out = buf.contiguous_all([("gyr", gyr), ("acc", acc), ("mag", None)], n_threads=3)
    assert started == ["margtrack-copy-1", "margtrack-copy-2"]
    assert out[2] is None and all(o.flags.c_contiguous for o in out[:2])
    np.testing.assert_array_equal(out[0], gyr)
    np.testing.assert_array_equal(out[1], acc)
    started.clear()  # below the threshold: one thread, the same values
    small = buf.contiguous_all([("gyr", gyr[:, :1])], n_threads=3)[0]
    assert started == [] and np.array_equal(small, gyr[:, :1])


def _engine_run(hot, strict):
    duration = 4.0
    names = tuple(f"s{i}" for i in range(10))
    engine = Engine(SourceInfo(names, RATE_HZ, True), "default", {"strict": strict},
                    avatars=None)
    engine._filters._hot = hot  # the copying path: Estimator.run, as before run_into
    stream = FaultyStream(10, RATE_HZ, duration, default_faults(duration))
    decoder = LineDecoder(names, True, SourceStats())
    q = []
    for t, lines in stream.ticks():
        pose = engine.push(decoder.feed("".join(lines).encode(), arrival_s=t, final=True),
                           now_s=t)
        if pose is not None:
            q.append(pose.q_sensor)
    return np.array(q), engine.stats().health.counts


@pytest.mark.parametrize("strict", [False, True])
def test_the_engine_on_the_hot_path_equals_it_on_run_under_every_fault(strict):
    # reboots, a stale sensor, zero acc, a 1e300 gyro, drops, duplicates; with strict=True
    # a flagged sample makes its sensor's filter raise (re-initialised alone)
    q_hot, counts_hot = _engine_run(True, strict)
    q_run, counts_run = _engine_run(False, strict)
    assert q_hot.shape == q_run.shape and len(q_hot) >= 90
    np.testing.assert_array_equal(q_hot, q_run)
    for name, values in counts_run.items():
        np.testing.assert_array_equal(counts_hot[name], values, err_msg=name)
    assert counts_hot["gaps"].sum() > 0
    if strict:
        assert counts_hot["reinitialised"].sum() > 0 and counts_hot["faults"].sum() == 0
    else:
        assert counts_hot["faults"].sum() > 0 and counts_hot["reinitialised"].sum() == 0


def test_unrun_marks_no_real_flags():
    # UNRUN must differ from every combination of real flags, so it can mark unrun samples
    every = 0
    for f in Flag:
        every |= int(f)
    assert every & int(UNRUN) != int(UNRUN)
