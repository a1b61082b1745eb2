"""``margtrack live``'s session without the page (``--headless``) and the replay of a
raw live recording (the session's magnetometer choice and lever arms), for
:mod:`margtrack.cli.live`."""

from __future__ import annotations

import contextlib
import math
from pathlib import Path
from typing import Any, cast

from rich.console import Console

from margtrack.body.offsets import Heading
from margtrack.live.protocol import Source

__all__ = ["headless", "replayed_session"]


def replayed_session(source: Any, no_mag: bool, no_mag_given: bool, arms: Any,
                      console: Console) -> Any:
    """The lever arms for replaying a raw live recording (the session's unless
    --lever-arms gives some); prints which magnetometer choice and lever arms are used."""
    session = source
    ran = {None: "an unrecorded magnetometer choice (--mag assumed)", True: "--no-mag",
           False: "--mag"}[session.no_mag]
    used = "--no-mag" if no_mag else "--mag"
    console.print(f"the session ran with {ran}; replaying with {used} "
                  + ("(from the command line)" if no_mag_given else
                     "(the default)" if session.no_mag is None else "(the session's)"))
    if not no_mag:
        return arms
    if arms is not None:
        console.print(f"lever arms: --lever-arms ({len(arms)} joint(s)), the others estimated")
        return arms
    if session.lever_arms:
        console.print("lever arms: the session's for " + ", ".join(session.lever_arms)
                      + "; the others estimated from the replayed motion as in the session")
    else:
        console.print("lever arms: estimated from the replayed motion, as in the session")
    return dict(session.lever_arms)


def headless(source: Source, method: str, params: list[str] | dict[str, Any],
              calibrate: bool, heading: str,
              axis: Any, duration: float | None, console: Console,
              record: Path | None = None, force: bool = False, *,
              summary: Path | None = None, stale_after_s: float | None = None,
              no_mag: bool = False, lever_arms: Any = None,
              walking_root: bool = False) -> None:
    import time

    from margtrack.live.engine import Engine
    from margtrack.live.recording import RawRecorder

    engine = Engine(source.info, method, params, heading=cast(Heading, heading),
                    forward_axis=axis, stale_after_s=stale_after_s,
                    summary_path=None if summary is None else str(summary),
                    no_mag=no_mag, lever_arms=lever_arms, walking_root=walking_root)
    recorder = RawRecorder(engine) if record is not None else None
    if recorder is not None:
        recorder.start()
    if calibrate and engine.avatars is not None:
        engine.request_calibration()
    end = math.inf if duration is None else time.perf_counter() + duration
    with engine.start(source):
        with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C ends the run cleanly
            while engine.running and time.perf_counter() < end:
                engine.wait(min(0.2, max(end - time.perf_counter(), 0.0)))
    if recorder is not None and record is not None:
        console.print(f"raw recording: {recorder.n_frames} frames written to "
                      f"{recorder.save(record, force=force)}")
    stats = engine.stats()
    console.print(f"{source.info.description}: {source.info.n_sensors} sensors, method "
                  f"{engine.method}")
    console.print(stats.summary())
    console.print(f"calibration: {stats.calibration}")
    root = engine.latest.root_m if engine.latest is not None else None
    if root is not None and engine.avatars is not None:
        import numpy as np

        moved = root - engine.avatars.root_positions_m  # x, y horizontal in ENU and NED
        console.print("root (pelvis) moved by the feet, horizontally from its start: "
                      + "; ".join(f"{p or 'the person'} {np.hypot(m[0], m[1]):.2f} m"
                                  for p, m in zip(engine.avatars.people, moved, strict=True)))
    if no_mag:
        from margtrack.live.viewer_panels import joints_lines

        for line in joints_lines(engine.joints):
            console.print(line, soft_wrap=True)
    if summary is not None:
        console.print(f"summary written to {summary}")
    if stats.error:
        raise ValueError(stats.error)
