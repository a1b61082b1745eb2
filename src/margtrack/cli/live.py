"""``margtrack live``: track a simulated, replayed, UDP or serial source and show it live.

Mounted in :mod:`margtrack.cli` as ``app.command(name="live")(live_command)``. Examples::

    margtrack live --demo                      # a simulated walking person, 15 sensors
    margtrack live --demo --people 4 --motion wave
    margtrack live --replay ../shared/data/xio_lower_body
    margtrack live --udp 9000 --sensors 3      # lines "t,sensor,gx,...,mz" on 127.0.0.1:9000
    margtrack live --serial /dev/ttyUSB0 --sensors pelvis,left_thigh
    margtrack live --replay trial.hdf5 --speed inf --headless   # engine only, prints stats
    margtrack live --udp 9000 --sensors 3 --headless --record session.hdf5  # raw stream
    margtrack live --replay session.hdf5       # the session again, same poses
    margtrack live --osc 9001 --sensors 3      # OSC /margtrack/<sensor>/imu (live/osc.py)
    margtrack live --lsl MyImus                # an LSL stream named MyImus (live/lsl.py)

The page is served on http://127.0.0.1:PORT (8080 by default); stop with Ctrl-C.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar, cast

import typer
from rich.console import Console
from rich.markup import escape

from margtrack.body.offsets import Heading
from margtrack.cli.options import FORWARD_AXIS_HELP, HEADING_HELP
from margtrack.live.protocol import Source

__all__ = ["live_command"]

F = TypeVar("F", bound=Callable[..., Any])


def _friendly(func: F) -> F:
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (ValueError, FileNotFoundError, OSError, ImportError) as exc:
            from margtrack.cli.app import cli_message  # the command line's fix, not Python's

            Console(stderr=True).print(f"[bold red]error:[/] {escape(cli_message(exc))}",
                                       soft_wrap=True)
            raise typer.Exit(code=2) from None

    return wrapper  # type: ignore[return-value]


def _udp_host(host: str, used: bool) -> str:
    """``--udp-host`` checked (an address of this machine); warns off loopback."""
    import ipaddress

    from margtrack.live.security import udp_exposure_warning

    if host != "localhost":
        try:
            ipaddress.ip_address(host)
        except ValueError:
            raise ValueError(f"--udp-host must be an IP address of this machine (127.0.0.1, "
                             f"0.0.0.0 for every interface, or one interface's), got {host!r}"
                             ) from None
    if used and (message := udp_exposure_warning(host)) is not None:
        Console(stderr=True).print(f"[bold yellow]warning:[/] {escape(message)}",
                                   soft_wrap=True)
    return host


def _sensor_names(spec: str | None) -> list[str]:
    if not spec:
        raise ValueError("--udp, --serial and --osc need --sensors: a count (3) or names "
                         "(a,b,c)")
    if spec.strip().isdigit():
        return [f"sensor{i}" for i in range(int(spec))]
    return [s.strip() for s in spec.split(",") if s.strip()]


def _source(demo: bool, replay: Path | None, udp: int | None, serial: str | None,
            sensors: str | None, speed: float, people: int, motion: str, preset: str,
            seed: int, no_mag: bool, osc: int | None = None, lsl: str | None = None,
            udp_host: str = "127.0.0.1", time_unit: str = "s") -> Source:
    chosen = [name for name, on in (("--demo", demo), ("--replay", replay is not None),
                                    ("--udp", udp is not None), ("--serial", serial is not None),
                                    ("--osc", osc is not None), ("--lsl", lsl is not None))
              if on]
    if len(chosen) != 1:
        raise ValueError("choose exactly one source: --demo, --replay PATH, --udp PORT, "
                         "--serial PORT, --osc PORT or --lsl NAME "
                         f"(got {', '.join(chosen) or 'none'})")
    if osc is not None:
        from margtrack.live.osc import OscSource

        return OscSource(_sensor_names(sensors), port=osc, host=udp_host, with_mag=not no_mag)
    if lsl is not None:
        from margtrack.live.lsl import LslSource

        return LslSource(lsl)
    if demo:
        from margtrack.live.simulator import PeopleSimulation, SimulatorSource

        sim = PeopleSimulation(n_people=people, preset=preset, motion=motion, seed=seed)
        return SimulatorSource(sim, speed=speed)
    if replay is not None:
        from margtrack.live.replay import replay_path

        return replay_path(replay, speed=speed)
    if udp is not None:
        from margtrack.live.udp import UdpSource

        return UdpSource(_sensor_names(sensors), port=udp, host=udp_host, with_mag=not no_mag,
                         time_unit=time_unit)
    from margtrack.live.serial_port import SerialSource

    return SerialSource(str(serial), _sensor_names(sensors), with_mag=not no_mag,
                        time_unit=time_unit)


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
    no_mag: Annotated[bool | None, typer.Option(
        "--no-mag/--mag", show_default=False, help="No magnetometer: every filter runs "
        "without it and, with a body model, every segment but the pelvis is its parent's "
        "orientation times the relative orientation across the joint (gyroscopes and "
        "accelerometers of both; lever arms estimated after a few seconds of motion, or "
        "--lever-arms). UDP/serial/OSC lines then carry no mag. Default --mag, except when "
        "replaying a --record file: the session's choice and lever arms (either flag "
        "overrides it).")] = None,
    lever_arms: Annotated[Path | None, typer.Option(
        "--lever-arms", help="With --no-mag: known lever arms, a JSON object from joint "
        "name (left_knee, ...) to an object with parent_m and child_m, each \\[x, y, z] "
        "(m, joint centre to sensor, sensor frames; docs/live.md has an example); joints "
        "left out are estimated.")] = None,
    time_unit: Annotated[str, typer.Option(
        "--time-unit", help="Unit of the UDP/serial lines' timestamps: s, ms, us or ns.")]
    = "s",
    method: Annotated[str, typer.Option(
        "--method", "-m", show_default=False, help="Estimation method (default: the "
        "recommended one; `margtrack methods` lists them and marks it).")] = "default",
    param: Annotated[list[str] | None, typer.Option(
        "--param", "-p", help="Method parameter as name=value; repeatable.")] = None,
    speed: Annotated[float, typer.Option(help="Replay/demo speed factor; inf: unpaced.")] = 1.0,
    people: Annotated[int, typer.Option(help="Demo: number of people.")] = 1,
    motion: Annotated[str, typer.Option(help="Demo: walk or wave.")] = "walk",
    preset: Annotated[str, typer.Option(help="Demo: full, lower, left_arm, ...")] = "full",
    seed: Annotated[int, typer.Option(help="Demo: random seed.")] = 0,
    calibrate: Annotated[bool, typer.Option(
        help="Calibrate on the first still second (reference pose).")] = True,
    heading: Annotated[str | None, typer.Option(
        help=HEADING_HELP + " Default pelvis, as in margtrack body; north with --demo (its "
        "simulated sensors are mounted at random, so no axis of theirs points forward), "
        "except with --no-mag: pelvis, the simulation's pelvis sensor axis.")]
    = None,
    forward_axis: Annotated[str | None, typer.Option(help=FORWARD_AXIS_HELP)] = None,
    port: Annotated[int, typer.Option(help="Port of the page (0: any free one).")] = 8080,
    host: Annotated[str, typer.Option(
        help="Address to serve the page on. 127.0.0.1: this machine only. Any other address "
        "(0.0.0.0: every interface) lets the network reach the page, so it needs a token "
        "(printed in the URL) and a warning is printed.")] = "127.0.0.1",
    token: Annotated[str | None, typer.Option(
        help="The page's access token (12+ letters, digits, _ or -), then required on "
        "loopback too; default: a random one when --host is not loopback.")] = None,
    udp_host: Annotated[str, typer.Option(
        "--udp-host", help="Interface the --udp (and --osc) listener binds: 127.0.0.1 "
        "(default, this machine only) or e.g. 0.0.0.0 for sensors on other machines. "
        "Risk: UDP has no authentication, anyone who can reach the port can inject "
        "samples.")] = "127.0.0.1",
    duration: Annotated[float | None, typer.Option(
        "--duration", help="Stop after this many seconds.")] = None,
    out: Annotated[Path | None, typer.Option(help="Folder for recordings' exports.")] = None,
    bvh_unit: Annotated[str, typer.Option(
        "--bvh-unit", help="Length unit of the page's BVH exports: cm (the default; "
        "Blender's BVH import scale 0.01) or m (scale 1), as margtrack body --bvh-unit.")]
    = "cm",
    headless: Annotated[bool, typer.Option(
        "--headless", help="No page: run the engine and print its statistics.")] = False,
    record: Annotated[Path | None, typer.Option(
        "--record", help="Write the raw sensor stream and events to this HDF5 file when the "
        "session ends (replay it with --replay).")] = None,
    force: Annotated[bool, typer.Option(
        "--force", help="Replace an existing --record file.")] = False,
    summary: Annotated[Path | None, typer.Option(
        "--summary", help="When the engine stops, write its summary (error, frames, "
        "per-sensor received/processed/lost/gaps/resyncs/stale_s...) to this JSON file.")]
    = None,
    stale_after_s: Annotated[float | None, typer.Option(
        "--stale-after-s", help="A sensor silent this long stops integrating (stale) and "
        "restarts when it returns; default five sample periods.")] = None,
    osc: Annotated[int | None, typer.Option(
        "--osc", help="Listen for OSC messages /margtrack/<sensor>/imu on this UDP port.")]
    = None,
    lsl: Annotated[str | None, typer.Option(
        "--lsl", help="Read the Lab Streaming Layer stream of this name (type IMU/MARG).")]
    = None,
    walking_root: Annotated[bool, typer.Option(
        "--walking-root/--fixed-root", help="Once calibrated, the avatar's pelvis moves with "
        "the feet's contacts (the planted foot held still: the avatar walks across the "
        "floor; the page's Reset position puts it back), or stays in place.")] = True,
    sensor_calibration: Annotated[list[str] | None, typer.Option(
        "--sensor-calibration", help="NAME=FILE: correct sensor NAME's samples with this "
        "calibration JSON (margtrack calibrate guided ...); repeatable.")] = None,
) -> None:
    """Track sensors live and show the avatar in a browser page (000's prototype system)."""
    console = Console()
    no_mag_given = no_mag is not None
    no_mag = bool(no_mag)
    if heading is None:
        heading = "north" if demo and not no_mag else "pelvis"
    from margtrack.body.export_bvh import BVH_UNITS

    if bvh_unit not in BVH_UNITS:
        raise ValueError(f"--bvh-unit must be cm or m, got {bvh_unit!r}")
    if heading not in ("north", "pelvis"):
        raise ValueError(f"--heading must be north or pelvis, got {heading!r}")
    if heading == "north" and forward_axis is not None:
        raise ValueError("--forward-axis gives the heading from the pelvis sensor; leave it "
                         "out with --heading north, or use --heading pelvis")
    axis = None
    if heading == "pelvis":
        from margtrack.body.mapping import parse_axis
        from margtrack.body.workflow import DEFAULT_FORWARD_AXIS

        axis = parse_axis(forward_axis if forward_axis is not None else DEFAULT_FORWARD_AXIS)
    source = _source(demo, replay, udp, serial, sensors, speed, people, motion, preset, seed,
                     no_mag, osc, lsl,
                     udp_host=_udp_host(udp_host, udp is not None or osc is not None),
                     time_unit=time_unit)
    replayed = source if getattr(source, "recording", None) is not None else None
    if replayed is not None and not no_mag_given:  # a raw live recording: as it ran
        no_mag = bool(getattr(replayed, "no_mag", False))
    if demo and no_mag and forward_axis is None and heading == "pelvis":
        # the simulated sensors are mounted at random: the pelvis sensor's forward axis
        # comes from the simulation (person 0's mounting)
        axis = source.simulation.pelvis_forward_axis(0)  # type: ignore[attr-defined]
    if record is not None:
        from margtrack.io.safe_output import check_output

        check_output(record, [replay] if replay is not None else [], force=force)
    if summary is not None:
        from margtrack.io.safe_output import check_output

        check_output(summary, [replay] if replay is not None else [], force=force)
    if sensor_calibration:
        source = _calibrated(source, sensor_calibration)
    params: list[str] | dict[str, Any] = param or []
    arms = None
    if lever_arms is not None:
        if not no_mag:
            raise ValueError("--lever-arms serves the joint constraint of --no-mag; add "
                             "--no-mag")
        from margtrack.live.joint_chain import read_chain_lever_arms

        arms = read_chain_lever_arms(lever_arms)
    recorded = getattr(replayed, "recording", None)  # a raw live recording replayed
    if recorded is not None and method == "default" and not param:
        method, params, calibrate = recorded.method, dict(recorded.params), False
        console.print(f"replaying {recorded.n_frames} frames with the session's method "
                      f"{method} and its parameters and calibrations")
    if recorded is not None:
        from margtrack.cli.live_session import replayed_session

        arms = replayed_session(replayed, no_mag, no_mag_given, arms, console)
    if headless:
        from margtrack.cli.live_session import headless

        headless(source, method, params, calibrate, heading, axis, duration, console,
                  record, force, summary=summary, stale_after_s=stale_after_s,
                  no_mag=no_mag, lever_arms=arms, walking_root=walking_root)
        return
    from margtrack.live.avatars import Avatars
    from margtrack.live.viewer_session import run_live

    has_body = Avatars.from_names(source.info.sensor_names) is not None
    err = Console(stderr=True)

    def announce(running: Any) -> None:
        console.print(f"margtrack live: {source.info.description}; serving {running.url} "
                      "(Ctrl-C to stop)", soft_wrap=True)
        default = ", the default" if bvh_unit == "cm" else ""
        console.print(f"the page's BVH exports: lengths in {bvh_unit} (--bvh-unit "
                      f"{bvh_unit}{default}): import into Blender with scale "
                      f"{BVH_UNITS[bvh_unit]:g}", soft_wrap=True)

    session = run_live(source, method, port, host=host, token=token, params=params,
                       announce=announce,
                       warn=lambda m: err.print(f"[bold yellow]warning:[/] {escape(m)}",
                                                soft_wrap=True),
                       calibrate_at_start=calibrate and has_body, heading=cast(Heading, heading),
                       forward_axis=axis, out_dir=out, duration_s=duration, record=record,
                       no_mag=no_mag, lever_arms=arms, walking_root=walking_root,
                       bvh_unit=bvh_unit)
    recorder = getattr(session.viewer, "raw_recorder", None)
    if recorder is not None and record is not None:
        console.print(f"raw recording: {recorder.n_frames} frames written to "
                      f"{recorder.save(record, force=force)}")
    console.print(session.engine.stats().summary())
    if summary is not None:
        session.engine.write_summary(str(summary))


def _calibrated(source: Source, specs: list[str]) -> Source:
    """``source`` with the ``NAME=FILE`` calibrations applied to those sensors."""
    from margtrack.calibration.calibration_file import load_calibration
    from margtrack.live.calibration_panel import CalibratedSource

    wrapped = CalibratedSource(source)
    names = list(source.info.sensor_names)
    for spec in specs:
        name, sep, file = spec.partition("=")
        if not sep or name not in names:
            raise ValueError(f"--sensor-calibration {spec!r}: give NAME=FILE with NAME one of "
                             f"{', '.join(names)}")
        wrapped.set_calibration(names.index(name), load_calibration(file))
    return wrapped  # type: ignore[return-value]
