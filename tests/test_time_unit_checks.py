"""Issue 40, item 1: timestamps in ms (µs, ns) read as s are refused on every path, with the
fix of that path, as deg/s gyroscopes and g accelerometers are."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest

import margtrack as mt
from margtrack import methods
from margtrack.io.csv import read_csv
from margtrack.live.engine import Engine
from margtrack.live.lines import LineDecoder, format_line
from margtrack.live.protocol import SourceStats
from margtrack.live.udp import UdpSource, send_lines
from margtrack.units import UnitError, check_unit_magnitudes


@pytest.fixture(scope="module")
def rec():
    """10 s of simulated random motion at 100 Hz, SI units (t in s)."""
    return mt.sim.simulate_motion("random", duration_s=10, rate_hz=100, seed=5)


def _arrays(r):
    return {"gyr": r.gyr, "acc": r.acc, "mag": r.mag}


def test_the_suspected_unit_is_the_one_giving_a_sensor_rate():
    from margtrack.units import suspected_time_unit

    assert suspected_time_unit(10.0) == ("ms", pytest.approx(100.0))  # 100 Hz in ms
    assert suspected_time_unit(20_000.0) == ("us", pytest.approx(50.0))  # x-IMU3's µs
    assert suspected_time_unit(2.5e6)[0] == "ns"  # 400 Hz in ns
    assert suspected_time_unit(1000.0)[0] == "us"  # 1 kHz in µs rather than 1 Hz in ms


def test_arrays_with_t_in_ms_are_refused_naming_the_sample_and_time_unit(rec):
    est = methods.create("robust")
    with pytest.raises(UnitError, match=r"t advances by a median of 10 s per sample \(0\.1 Hz; "
                       r"t\[1\] - t\[0\] = 10\) while the gyroscope turns .* at sample \d+\): "
                       r".*probably in ms \(100 Hz then\): pass time_unit='ms' to run\(\)"
                       ) as info:
        est.run(t=rec.t * 1000.0, **_arrays(rec))
    assert (info.value.signal, info.value.suspected) == ("time", "ms")
    assert est.state is None  # nothing ran
    with pytest.raises(UnitError, match=r"probably in us .*time_unit='us'"):
        est.run(t=rec.t * 1e6, **_arrays(rec))
    # declared: the same run as in s, to the last bit of the timestamps' conversion
    in_ms = methods.create("robust").run(t=rec.t * 1000.0, time_unit="ms", **_arrays(rec))
    in_s = methods.create("robust").run(t=rec.t, **_arrays(rec))
    np.testing.assert_allclose(in_ms.quat, in_s.quat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(in_ms.t, rec.t, rtol=1e-15)
    # check_units=False runs it as told (every interval a gap)
    raw = methods.create("robust").run(t=rec.t * 1000.0, check_units=False, **_arrays(rec))
    assert np.count_nonzero(raw.flags & mt.estimator.Flag.GAP) == rec.n_samples - 1


def test_a_slow_log_of_a_still_sensor_or_a_declared_rate_is_not_refused(rec):
    still = np.zeros_like(rec.gyr) + 0.01  # a gyroscope at rest: no evidence of ms
    est = methods.create("gyro").run(gyr=still, acc=rec.acc, t=np.arange(rec.n_samples) * 2.0)
    assert est.quat.shape == (rec.n_samples, 4)
    # a rate is a declaration, not timestamps to judge
    check_unit_magnitudes(rec.gyr, rec.acc, t_s=rec.t * 0.5)  # 200 Hz: fine
    rec2 = mt.Recording.from_arrays(rec.gyr, rec.acc, rate_hz=0.5)
    assert rec2.rate_hz == pytest.approx(0.5)


def test_a_recording_in_ms_is_refused_by_run_and_from_arrays(rec):
    in_ms = dataclasses.replace(rec, t=rec.t * 1000.0)
    with pytest.raises(UnitError, match=r"rec\.with_units\(time='ms'\)"):
        methods.create("default").run(in_ms)
    converted = in_ms.with_units(time="ms")
    np.testing.assert_allclose(converted.t, rec.t, rtol=1e-15)
    methods.create("default").run(converted)  # accepted
    with pytest.raises(UnitError, match=r"pass time_unit='ms' to from_arrays"):
        mt.Recording.from_arrays(rec.gyr, rec.acc, t=rec.t * 1000.0)
    ok = mt.Recording.from_arrays(rec.gyr, rec.acc, t=rec.t * 1000.0, time_unit="ms")
    np.testing.assert_allclose(ok.t, rec.t, rtol=1e-15)


def test_a_mapped_csv_in_ms_is_refused_by_read_csv(rec, tmp_path):
    path = tmp_path / "log.csv"
    table = np.column_stack([rec.t * 1000.0, rec.gyr, rec.acc])
    np.savetxt(path, table, delimiter=",", header="stamp,gx,gy,gz,ax,ay,az", comments="")
    columns = {"t": "stamp", "gyr": "gx,gy,gz", "acc": "ax,ay,az"}
    with pytest.raises(UnitError, match=r"log\.csv: t advances .* pass time_unit='ms' to "
                       r"read_csv"):
        read_csv(path, columns, check_units=True)
    assert read_csv(path, columns, time_unit="ms", check_units=True).rate_hz == pytest.approx(100)


@pytest.mark.parametrize("method", ["robust", "ekf"])
def test_update_with_dt_in_ms_is_refused_within_the_first_updates(rec, method):
    est = methods.create(method)
    dt_ms = np.diff(rec.t) * 1000.0
    with pytest.raises(UnitError, match=r"dt has a median of 10 s over the first 10 "
                       r"intervals .* at update \d+\): .*give update\(\) dt in s \(divide dt "
                       r"in ms by 1000\)") as info:
        for i in range(1, 200):
            est.update(rec.gyr[i], rec.acc[i], rec.mag[i], dt=dt_ms[i - 1])
    assert i <= 15, i  # refused at once, not after the 500-sample gyro window
    assert info.value.suspected == "ms"
    # in s: no refusal, and the check ends (the lean path takes over after its window)
    est = methods.create(method)
    for i in range(1, 600):
        est.update(rec.gyr[i % rec.n_samples], rec.acc[i % rec.n_samples],
                   rec.mag[i % rec.n_samples], dt=0.01)
    assert est._probe.done


def _ms_lines(n=30, sensor=0, rate_rad_s=1.0):
    """n lines of one sensor turning about z, stamped in ms at 100 Hz."""
    return [format_line(10.0 * k, sensor, [0.0, 0.0, rate_rad_s], [0.0, 0.0, 9.81],
                        [0.0, 20.0, -40.0]) for k in range(n)]


def test_live_lines_in_ms_are_refused_naming_the_sensor_and_the_option():
    decoder = LineDecoder(["pelvis", "head"], True, SourceStats())
    with pytest.raises(UnitError, match=r"^sensor pelvis: t advances by a median of 10 s per "
                       r"line over the first 11 .* at line 0\): .*probably in ms \(100 Hz "
                       r"then\): declare the senders' unit \(margtrack live --time-unit ms"):
        decoder.feed("".join(_ms_lines()).encode(), final=True)
    # declared: accepted, the times in s
    decoder = LineDecoder(["pelvis", "head"], True, SourceStats(), time_unit="ms")
    chunks = decoder.feed("".join(_ms_lines()).encode(), final=True)
    assert len(chunks) == 30 and chunks[-1].t_s[0] == pytest.approx(0.29)
    # a still sensor on a slow clock is no evidence
    still = LineDecoder(["a"], True, SourceStats())
    assert len(still.feed("".join(_ms_lines(rate_rad_s=0.0)).encode(), final=True)) == 30


def test_a_udp_stream_in_ms_stops_the_engine_with_the_fix():
    source = UdpSource(["s0"], port=0, rate_hz=100.0)
    source.open()
    engine = Engine(source.info, "default", avatars=None).start(source)
    try:
        send_lines(_ms_lines(40), source.address, per_datagram=4)
        end = time.perf_counter() + 20.0
        while engine.running and time.perf_counter() < end:
            time.sleep(0.02)
        assert not engine.running
        assert "--time-unit ms" in engine.error and "sensor s0" in engine.error
    finally:
        engine.stop()
    declared = UdpSource(["s0"], port=0, rate_hz=100.0, time_unit="ms")
    declared.open()
    try:
        send_lines(_ms_lines(40), declared.address, per_datagram=4)
        got = []
        end = time.perf_counter() + 10.0
        while len(got) < 40 and time.perf_counter() < end:
            got += declared.poll(0.05)
        assert len(got) == 40 and math.isclose(got[1].t_s[0], 0.01)
    finally:
        declared.close()


def test_the_live_command_passes_its_time_unit_to_line_sources():
    from margtrack.cli.live import _source

    source = _source(False, None, 0, None, "2", 1.0, 1, "walk", "full", 0, False,
                     time_unit="ms")
    assert isinstance(source, UdpSource) and source._decoder.time_factor == 1e-3
