"""The line format, and the UDP and serial sources reading it (real socket, loop://, pty)."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from margtrack.live.assembler import FrameAssembler
from margtrack.live.lines import LineDecoder, format_line, parse_line
from margtrack.live.protocol import Chunk, SourceStats
from margtrack.live.udp import UdpSource, send_lines

NAMES = ("pelvis", "left_thigh", "left_shank")


def _line(t, s, k=0.0):
    return format_line(t, s, [0.1 + k, -0.2, 0.3], [0.0, 0.5, 9.81], [20.0, 1.0 / 3.0, -40.0])


def test_a_formatted_line_parses_back_exactly():
    t, s, gyr, acc, mag = parse_line(_line(12.345678901234567, 2), NAMES)
    assert (t, s) == (12.345678901234567, 2)
    np.testing.assert_array_equal(gyr, [0.1, -0.2, 0.3])
    np.testing.assert_array_equal(acc, [0.0, 0.5, 9.81])
    assert mag[1] == 1.0 / 3.0
    assert parse_line("1.5,left_thigh,0,0,0,0,0,9.8,1,2,3\r\n", NAMES)[1] == 1
    t, s, _, _, mag = parse_line("2,0,0,0,0,0,0,9.8", NAMES, with_mag=False)
    assert (t, s, mag) == (2.0, 0, None)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("1,0,0,0,0,0,0,9.8", "expected 11 comma-separated fields"),
        ("1,0,0,0,0,0,0,9.8,a,2,3", "a field is not a number"),
        ("1,0,0,0,nan,0,0,9.8,1,2,3", "not finite"),
        ("1,3,0,0,0,0,0,9.8,1,2,3", "sensor index 3 out of range 0..2"),
        ("1,head,0,0,0,0,0,9.8,1,2,3", "unknown sensor 'head'"),
    ],
)
def test_malformed_lines_raise_with_the_reason(line, message):
    with pytest.raises(ValueError, match=message):
        parse_line(line, NAMES)


def test_decoder_counts_malformed_lines_and_joins_partial_ones():
    stats = SourceStats()
    decoder = LineDecoder(NAMES, True, stats)
    line = _line(1.0, 1)
    out = decoder.feed(line[:10].encode())
    out += decoder.feed((line[10:] + "# comment\n\ngarbage\n" + _line(1.0, 2)[:-1]).encode())
    assert len(out) == 1 and out[0].sensors.tolist() == [1]
    assert stats.malformed == 1 and "expected 11" in stats.last_error
    out = decoder.feed(b"\n")
    assert len(out) == 1 and out[0].sensors.tolist() == [2] and stats.samples == 2


def test_udp_source_receives_lines_over_a_real_socket():
    source = UdpSource(NAMES, port=0)
    source.open()
    try:
        lines = [_line(0.01 * i, i % 3, k=i) for i in range(30)]
        lines.insert(7, "0.5,9,1,2")  # malformed: reported, not raised
        lines.insert(12, "not a sample at all")
        send_lines(lines, source.address, per_datagram=4)
        chunks, end = [], time.perf_counter() + 5.0
        while len(chunks) < 30 and time.perf_counter() < end:
            chunks.extend(source.poll(0.05))
    finally:
        source.close()
    assert len(chunks) == 30
    assert [int(c.sensors[0]) for c in chunks] == [i % 3 for i in range(30)]
    np.testing.assert_allclose([c.gyr[0, 0, 0] for c in chunks], 0.1 + np.arange(30))
    assert source.stats.malformed == 2 and source.stats.samples == 30
    assert source.finished and source.poll(0.0) == []


def _serial():
    return pytest.importorskip("serial", reason="pyserial is not installed")


def test_serial_source_reads_lines_from_a_loopback_port():
    _serial()
    from margtrack.live.serial_port import SerialSource

    source = SerialSource("loop://", NAMES)
    source.open()
    text = "".join(_line(0.01 * i, i % 3) for i in range(6)) + "1,2,3\n"
    source.port.write(text[:50].encode())
    chunks = source.poll(0.2)
    source.port.write(text[50:].encode())
    end = time.perf_counter() + 2.0
    while len(chunks) < 6 and time.perf_counter() < end:
        chunks.extend(source.poll(0.05))
    source.close()
    assert [float(c.t_s[0]) for c in chunks] == pytest.approx([0.01 * i for i in range(6)])
    assert source.stats.malformed == 1


def test_serial_source_reads_a_pseudo_terminal():
    _serial()
    from margtrack.live.serial_port import SerialSource

    master, slave = os.openpty()
    try:
        source = SerialSource(os.ttyname(slave), NAMES, baudrate=115200)
        source.open()
        os.write(master, "".join(_line(0.5 + 0.01 * i, 0) for i in range(4)).encode())
        chunks, end = [], time.perf_counter() + 2.0
        while len(chunks) < 4 and time.perf_counter() < end:
            chunks.extend(source.poll(0.05))
        source.close()
    finally:
        os.close(master)
        os.close(slave)
    assert len(chunks) == 4 and float(chunks[3].t_s[0]) == pytest.approx(0.53)


def _sample(t, s, value, arrival=0.0):
    v = np.full((1, 1, 3), float(value))
    return Chunk(np.array([t]), np.array([s]), v, v + 9.0, v + 20.0, np.array([arrival]))


def test_assembler_builds_frames_holds_missing_samples_and_counts_late_ones():
    asm = FrameAssembler(3, with_mag=True, max_wait_s=10.0)
    frames = asm.push([_sample(0.0, s, s) for s in range(3)], now_s=0.0)
    assert len(frames) == 1 and frames[0].gyr[:, 0, 0].tolist() == [0.0, 1.0, 2.0]
    # frame 0.01 lacks sensor 1; frame 0.02 completes first, so 0.01 goes out with a hold
    chunks = [_sample(0.01, 0, 10), _sample(0.01, 2, 12)]
    chunks += [_sample(0.02, s, 20 + s, arrival=0.5) for s in range(3)]
    chunks += [_sample(0.01, 1, 11), _sample(0.02, 0, 99)]  # too late; repeated: dropped
    frames = asm.push(chunks, now_s=0.0)
    assert [float(f.t_s[0]) for f in frames] == [0.01, 0.02]
    assert frames[0].gyr[:, 0, 0].tolist() == [10.0, 1.0, 12.0]  # sensor 1 held from t = 0
    assert frames[0].held[:, 0].tolist() == [False, True, False]
    assert frames[1].acc[:, 0, 0].tolist() == [29.0, 30.0, 31.0] and frames[1].arrival_s[0] == 0.5
    assert asm.dropped.tolist() == [0, 1, 0] and asm.late == 2


def test_assembler_emits_a_waiting_frame_after_max_wait_and_rounds_onto_ticks():
    asm = FrameAssembler(2, with_mag=True, max_wait_s=0.05, tick_hz=100.0)
    assert asm.push([_sample(0.0, 0, 1), _sample(0.0004, 1, 2)], now_s=0.0)[0].t_s[0] == 0.0
    assert asm.push([_sample(0.0102, 0, 3, arrival=1.0)], now_s=1.0) == []
    frames = asm.push([], now_s=1.06)
    assert len(frames) == 1 and frames[0].t_s[0] == pytest.approx(0.01)
    assert frames[0].gyr[:, 0, 0].tolist() == [3.0, 2.0] and asm.dropped.tolist() == [0, 1]
    # a frame whose missing sensor was never seen cannot be held: discarded whole
    fresh = FrameAssembler(2, with_mag=True, max_wait_s=0.0)
    assert fresh.push([_sample(0.0, 0, 1)], now_s=0.0) == []
    assert fresh.discarded_frames == 1 and fresh.dropped.tolist() == [1, 0]
