"""``margtrack live``: track a simulated, replayed, UDP or serial source and show it live.

Mounted in :mod:`margtrack.cli` as ``app.command(name="live")(live_command)``. Examples::

    margtrack live --demo                      # a simulated walking person, 15 sensors
    margtrack live --demo --people 4 --motion wave
    margtrack live --replay ../shared/data/xio_lower_body
    margtrack live --udp 9000 --sensors 3      # lines "t,sensor,gx,...,mz" on 127.0.0.1:9000
    margtrack live --serial /dev/ttyUSB0 --sensors pelvis,left_thigh
    margtrack live --replay trial.hdf5 --speed inf --headless   # engine only, prints stats

The page is served on http://127.0.0.1:PORT (8080 by default); stop with Ctrl-C.
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar, cast

import typer
from rich.console import Console
from rich.markup import escape

from margtrack.body.offsets import Heading
from margtrack.live.protocol import Source

__all__ = ["live_command"]

F = TypeVar("F", bound=Callable[..., Any])


def _friendly(func: F) -> F:
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (ValueError, FileNotFoundError, OSError, ImportError) as exc:
            Console(stderr=True).print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)
            raise typer.Exit(code=2) from None

    return wrapper  # type: ignore[return-value]


def _sensor_names(spec: str | None) -> list[str]:
    if not spec:
        raise ValueError("--udp and --serial need --sensors: a count (3) or names (a,b,c)")
    if spec.strip().isdigit():
        return [f"sensor{i}" for i in range(int(spec))]
    return [s.strip() for s in spec.split(",") if s.strip()]


def _source(demo: bool, replay: Path | None, udp: int | None, serial: str | None,
            sensors: str | None, speed: float, people: int, motion: str, preset: str,
            seed: int, no_mag: bool) -> Source:
    chosen = [name for name, on in (("--demo", demo), ("--replay", replay is not None),
                                    ("--udp", udp is not None), ("--serial", serial is not None))
              if on]
    if len(chosen) != 1:
        raise ValueError("choose exactly one source: --demo, --replay PATH, --udp PORT or "
                         f"--serial PORT (got {', '.join(chosen) or 'none'})")
    if demo:
        from margtrack.live.simulator import PeopleSimulation, SimulatorSource

        sim = PeopleSimulation(n_people=people, preset=preset, motion=motion, seed=seed)
        return SimulatorSource(sim, speed=speed)
    if replay is not None:
        from margtrack.live.replay import replay_path

        return replay_path(replay, speed=speed)
    if udp is not None:
        from margtrack.live.udp import UdpSource

        return UdpSource(_sensor_names(sensors), port=udp, with_mag=not no_mag)
    from margtrack.live.serial_port import SerialSource

    return SerialSource(str(serial), _sensor_names(sensors), with_mag=not no_mag)


@_friendly
def live_command(
    demo: Annotated[bool, typer.Option("--demo", help="Simulated people wearing sensors.")]
    = False,
    replay: Annotated[Path | None, typer.Option(
        "--replay", help="Replay a recording: BROAD/margtrack file or x-IMU3 (body) folder.")]
    = None,
    udp: Annotated[int | None, typer.Option("--udp", help="Listen for lines on this UDP port.")]
    = None,
    serial: Annotated[str | None, typer.Option("--serial", help="Read lines from this port.")]
    = None,
    sensors: Annotated[str | None, typer.Option(
        help="UDP/serial sensors: a count or comma-separated names.")] = None,
    no_mag: Annotated[bool, typer.Option("--no-mag", help="UDP/serial lines carry no mag.")]
    = False,
    method: Annotated[str, typer.Option("--method", "-m", help="Estimation method.")]
    = "default",
    param: Annotated[list[str] | None, typer.Option(
        "--param", "-p", help="Method parameter as name=value; repeatable.")] = None,
    speed: Annotated[float, typer.Option(help="Replay/demo speed factor; inf: unpaced.")] = 1.0,
    people: Annotated[int, typer.Option(help="Demo: number of people.")] = 1,
    motion: Annotated[str, typer.Option(help="Demo: walk or wave.")] = "walk",
    preset: Annotated[str, typer.Option(help="Demo: full, lower, left_arm, ...")] = "full",
    seed: Annotated[int, typer.Option(help="Demo: random seed.")] = 0,
    calibrate: Annotated[bool, typer.Option(
        help="Calibrate on the first still second (reference pose).")] = True,
    heading: Annotated[str, typer.Option(help="Calibration heading: north or pelvis.")]
    = "north",
    forward_axis: Annotated[str | None, typer.Option(
        help="heading=pelvis: the pelvis sensor's forward axis, e.g. 0,0,-1.")] = None,
    port: Annotated[int, typer.Option(help="Port of the page (0: any free one).")] = 8080,
    host: Annotated[str, typer.Option(help="Address to serve the page on.")] = "127.0.0.1",
    duration: Annotated[float | None, typer.Option(
        "--duration", help="Stop after this many seconds.")] = None,
    out: Annotated[Path | None, typer.Option(help="Folder for recordings' exports.")] = None,
    headless: Annotated[bool, typer.Option(
        "--headless", help="No page: run the engine and print its statistics.")] = False,
) -> None:
    """Track sensors live and show the avatar in a browser page (000's prototype system)."""
    console = Console()
    if heading not in ("north", "pelvis"):
        raise ValueError(f"--heading must be north or pelvis, got {heading!r}")
    axis = None if forward_axis is None else [float(v) for v in forward_axis.split(",")]
    source = _source(demo, replay, udp, serial, sensors, speed, people, motion, preset, seed,
                     no_mag)
    if headless:
        _headless(source, method, param or [], calibrate, heading, axis, duration, console)
        return
    from margtrack.live.avatars import Avatars
    from margtrack.live.viewer import run_live

    has_body = Avatars.from_names(source.info.sensor_names) is not None
    console.print(f"margtrack live: {source.info.description}; serving http://{host}:{port} "
                  "(Ctrl-C to stop)")
    session = run_live(source, method, port, host=host, params=param or [],
                       calibrate_at_start=calibrate and has_body, heading=cast(Heading, heading),
                       forward_axis=axis, out_dir=out, duration_s=duration)
    console.print(session.engine.stats().summary())


def _headless(source: Source, method: str, params: list[str], calibrate: bool, heading: str,
              axis: list[float] | None, duration: float | None, console: Console) -> None:
    import time

    from margtrack.live.engine import Engine

    engine = Engine(source.info, method, params, heading=cast(Heading, heading),
                    forward_axis=axis)
    if calibrate and engine.avatars is not None:
        engine.request_calibration()
    end = math.inf if duration is None else time.perf_counter() + duration
    with engine.start(source):
        with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C ends the run cleanly
            while engine.running and time.perf_counter() < end:
                engine.wait(min(0.2, max(end - time.perf_counter(), 0.0)))
    stats = engine.stats()
    console.print(f"{source.info.description}: {source.info.n_sensors} sensors, method "
                  f"{engine.method}")
    console.print(stats.summary())
    console.print(f"calibration: {stats.calibration}")
    if stats.error:
        raise ValueError(stats.error)
