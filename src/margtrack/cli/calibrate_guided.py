"""``margtrack calibrate guided``: 000 Appendix B's 18-step procedure, offline or live.

Offline (``--source FILE``) the recording of the procedure is replayed through
:class:`~margtrack.calibration.guided.GuidedCalibration`; live (``--udp PORT`` /
``--serial DEVICE``) one sensor of a line stream drives
:class:`~margtrack.calibration.live_procedure.LiveProcedure`, with the current step, a
progress bar for each hold and what is wrong printed as the samples come. The command is
registered on the ``calibrate`` app by :mod:`margtrack.cli.calibrate`.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape

from margtrack.calibration.cli_common import fmt, make_table, read, triad_rows

__all__ = ["guided"]


def guided(
    source: Annotated[Path | None, typer.Option(
        "--source", "-s", help="Recording of the procedure (offline).")] = None,
    output: Annotated[Path, typer.Option("--output", "-o", help="Calibration JSON.")] = Path(
        "calibration.json"
    ),
    quiet: Annotated[bool, typer.Option(help="Print only the result.")] = False,
    udp: Annotated[int | None, typer.Option(
        "--udp", help="Live: lines t,sensor,gx,...,mz on this UDP port (127.0.0.1).")] = None,
    serial: Annotated[str | None, typer.Option(
        "--serial", help="Live: lines from this serial port.")] = None,
    sensors: Annotated[str, typer.Option(
        help="Live: the stream's sensors, a count or comma-separated names.")] = "1",
    sensor: Annotated[str | None, typer.Option(
        help="Live: the sensor to calibrate (name or index; default the first).")] = None,
    timeout: Annotated[float, typer.Option(
        help="Live: give up after this many seconds (wall clock).")] = 600.0,
    force: Annotated[bool, typer.Option(
        "--force", help="Live: replace an existing --output file.")] = False,
) -> None:
    """Walk through 000's 18 steps on a recording, or live on a sensor (--udp/--serial),
    printing each instruction, a progress bar for each hold and what is wrong."""
    from margtrack.calibration.calibration_file import save_calibration
    from margtrack.calibration.guided import GuidedCalibration

    console = Console()
    if (udp is not None or serial is not None) == (source is not None) or (
            udp is not None and serial is not None):
        raise ValueError("give exactly one of --source FILE, --udp PORT or --serial DEVICE")
    if source is None:
        _guided_live(udp, serial, sensors, sensor, timeout, output, force, quiet, console)
        return
    rec = read(source)
    if rec.mag is None:
        raise ValueError(f"{source} has no magnetometer; the procedure needs one (steps 15-18)")
    machine = GuidedCalibration()
    style = {"instruction": "bold cyan", "done": "green", "warning": "yellow", "finished": "bold"}
    if not quiet:
        console.print(f"[{style['instruction']}]{machine.instruction}[/]")
    block = max(1, round(rec.rate_hz))
    for start in range(0, rec.n_samples, block):
        s = slice(start, start + block)
        for e in machine.add_samples(rec.t[s], rec.gyr[s], rec.acc[s], rec.mag[s]):
            if not quiet:
                console.print(f"{e.t_s:8.2f} s  [{style[e.kind]}]{escape(e.message)}[/]")
        if machine.finished:
            break
    result = machine.result()
    cal = result.calibration
    _guided_table(result, console)
    save_calibration(dataclasses.replace(cal, source=f"guided procedure on {source.name}"),
                     output)
    console.print(f"wrote {output}")


def _guided_table(result: Any, console: Console) -> None:
    cal = result.calibration
    table = make_table("guided calibration (000 Appendix B)", ["figure", "x", "y", "z"])
    table.add_row("gyro scale factor, eq. 5", *fmt(result.gyro_scale.scale_factor, 6))
    triad_rows(table, "gyr", cal.gyr, "deg/s", 180.0 / math.pi)
    table.add_row("acc null, eq. 1 (m/s²)", *fmt(result.six_position.null_m_s2))
    table.add_row("acc scale, eq. 2", *fmt(result.six_position.scale, 6))
    triad_rows(table, "acc", cal.acc, "m/s²")
    table.add_row("mag null, eq. 3 (µT)", *fmt(result.min_max.null_ut))
    table.add_row("mag scale, eq. 4", *fmt(result.min_max.scale, 6))
    if cal.mag is None or cal.reference is None:
        raise ValueError("the procedure produced no magnetometer calibration")
    triad_rows(table, "mag", cal.mag, "µT")
    ref = cal.reference
    table.add_row("reference acc (m/s²)", *fmt(ref.acc_m_s2))
    table.add_row("reference mag (µT)", *fmt(ref.mag_ut))
    console.print(table)
    console.print(f"gravity {ref.gravity_m_s2:.4f} m/s², field {ref.field_ut:.2f} µT, "
                  f"dip {ref.dip_deg:.2f} deg, x from north {ref.heading_offset_deg:+.2f} deg")
    for note in cal.notes:
        console.print(f"- {note}")


def _guided_live(udp: int | None, serial: str | None, sensors: str, sensor: str | None,
                 timeout: float, output: Path, force: bool, quiet: bool,
                 console: Console) -> None:
    """The procedure live on one sensor of a UDP or serial line stream (terminal display:
    events as they come and, every 0.5 s of data, the step, a hold progress bar and what is
    wrong; a terminal shows the status line in place)."""
    import time

    from margtrack.calibration.live_procedure import LiveProcedure, save_result
    from margtrack.io.safe_output import check_output
    from margtrack.live.calibration_panel import feed_chunks

    check_output(output, force=force)  # before the person spends minutes on the procedure
    names = ([f"sensor{i}" for i in range(int(sensors))] if sensors.strip().isdigit()
             else [n.strip() for n in sensors.split(",") if n.strip()])
    if not names:
        raise ValueError("--sensors must be a count or comma-separated names")
    key = names[0] if sensor is None else sensor
    index = int(key) if key.isdigit() else (names.index(key) if key in names else -1)
    if not 0 <= index < len(names):
        raise ValueError(f"--sensor {key!r} is not one of {', '.join(names)}")
    if udp is not None:
        from margtrack.live.udp import UdpSource

        src: Any = UdpSource(names, port=udp)
    else:
        from margtrack.live.serial_port import SerialSource

        src = SerialSource(str(serial), names)
    procedure = LiveProcedure()
    style = {"instruction": "bold cyan", "done": "green", "warning": "yellow", "finished": "bold"}
    console.print(f"guided calibration of {names[index]} on {src.info.description}")
    console.print(f"[{style['instruction']}]{procedure.status.instruction}[/]")
    end = time.perf_counter() + timeout
    next_line = 0.0
    src.open()
    try:
        while not procedure.finished and time.perf_counter() < end:
            for e in feed_chunks(procedure, src.poll(0.1), index):
                if not quiet:
                    console.print(f"{e.t_s:8.2f} s  [{style[e.kind]}]{escape(e.message)}[/]",
                                  soft_wrap=True)
            st = procedure.status
            if not quiet and st.samples and st.t_s >= next_line and not st.finished:
                next_line = st.t_s + 0.5
                console.print(escape(st.line()), end="\r" if console.is_terminal else "\n",
                              soft_wrap=True)
    finally:
        src.close()
    if procedure.rejected or src.stats.malformed:
        console.print(f"rejected: {src.stats.malformed} malformed lines, {procedure.rejected} "
                      f"samples ({procedure.last_rejection or src.stats.last_error})")
    if not procedure.finished:
        raise ValueError(f"no finished procedure after {timeout:g} s; still waiting for "
                         f"{procedure.status.instruction}")
    result = procedure.result()
    _guided_table(result, console)
    path = save_result(result, output, source=f"live guided procedure on {names[index]}",
                       force=force)
    console.print(f"wrote {path} (apply it: margtrack live ... --sensor-calibration "
                  f"{names[index]}={path})", soft_wrap=True)
