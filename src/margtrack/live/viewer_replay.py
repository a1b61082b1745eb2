"""The page's replay options: *Loop replay* and *Replay again* (a new engine, same session).

*Replay again* runs a new engine (built like the first, with the filter parameters in force)
on a rewound copy of the replay, and carries over what the session had attached to the old
one, so that nothing is silently dropped:

- the sensor calibrations: a replay read through a
  :class:`~margtrack.live.calibration_panel.CalibratedSource` is rewound inside a new
  wrapper with the same calibrations (``--sensor-calibration`` and those the guided panel
  applied); the guided-calibration panel serves the new engine and wrapper (a procedure
  still running is cancelled);
- the raw recording of ``--record FILE`` (``viewer.raw_recorder``): the finished run is
  written at once to ``FILE_run1.hdf5`` (``_run2``... for later ones; atomically, never over
  an existing file) and a new recorder starts with the new engine, so ``FILE`` holds the
  last run when the session ends. Each file is one engine's run from its start, so each
  replays that run's poses exactly (a run cannot continue another's file: the new engine's
  filters start afresh, which a replay could not reproduce);
- a recording started from the page is stopped and exported first (its files are listed).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from margtrack.live.calibration_panel import CalibratedSource, free_path
from margtrack.live.protocol import Source
from margtrack.live.replay import ReplaySource

__all__ = ["replay_again", "replay_of", "rewound"]


def replay_of(source: Source | None) -> ReplaySource | None:
    """The :class:`ReplaySource` that ``source`` plays (itself or inside a calibration
    wrapper), else None."""
    inner = source.inner if isinstance(source, CalibratedSource) else source
    return inner if type(inner) is ReplaySource else None


def rewound(source: Source | None) -> Source | None:
    """A fresh copy of a replay (same data, speed, loop flag, and calibration wrapper with
    the same calibrations) to play again from its start, else None."""
    replay = replay_of(source)
    if replay is None:
        return None
    fresh = ReplaySource(replay.t_s, replay.gyr, replay.acc, replay.mag,
                         replay.info.sensor_names, speed=replay.speed,
                         chunk_frames=replay.chunk_frames, loop=replay.loop,
                         description=replay.info.description)
    if isinstance(source, CalibratedSource):
        return CalibratedSource(fresh, source.calibrations())
    return fresh


def replay_again(viewer: Any) -> str | None:
    """Run a new engine on a rewound copy of ``viewer.source`` (module docstring).

    ``viewer`` is a :class:`~margtrack.live.viewer.LiveViewer` whose engine has stopped;
    returns the message for the page, or None when there is nothing to replay.
    """
    old = viewer.engine
    if viewer.new_engine is None or old.running or replay_of(viewer.source) is None:
        return None
    exported = ""
    if old.recording:  # a page recording still open: export it before the engine goes
        viewer.toggle_recording()
        exported = f"; {viewer.message}"
    panel = getattr(viewer, "calibration_panel", None)
    if panel is not None:
        panel.cancel_run()  # restores the calibration a procedure had lifted
    fresh = rewound(viewer.source)
    assert fresh is not None
    new = viewer.new_engine()
    new.set_params(**{f.name: getattr(old.params, f.name)
                      for f in dataclasses.fields(old.params) if f.name != "frame"})
    if panel is not None and isinstance(fresh, CalibratedSource):
        panel.rebind(new, fresh)
    kept = _next_raw_recorder(viewer, new)
    viewer.switch_engine(new, fresh)
    new.start(fresh)
    return (f"replaying again (the previous run had {old.stats().frames} frames)"
            f"{exported}{kept}")


def _next_raw_recorder(viewer: Any, engine: Any) -> str:
    """Write the finished run of ``--record`` beside its file, start recording ``engine``."""
    from margtrack.io.live_hdf5 import write_live_recording
    from margtrack.live.recording import RawRecorder

    recorder = getattr(viewer, "raw_recorder", None)
    if recorder is None:
        return ""
    recorder.detach()
    target = Path(getattr(viewer, "record_path", None) or "live_raw.hdf5")
    viewer.raw_runs = runs = [*getattr(viewer, "raw_runs", [])]
    text = ""
    if recorder.recording:
        try:
            run = recorder.stop()
        except ValueError:  # nothing arrived: nothing to keep
            pass
        else:
            name = f"{target.stem}_run{len(runs) + 1}{target.suffix or '.hdf5'}"
            try:
                runs.append(write_live_recording(run, free_path(target.with_name(name))))
            except (OSError, ValueError) as exc:  # kept in memory: viewer.raw_unsaved
                viewer.raw_unsaved = [*getattr(viewer, "raw_unsaved", []), run]
                text = f"; the raw recording of that run could not be written ({exc})"
            else:
                text = f"; raw recording of that run: {runs[-1]}"
    viewer.raw_recorder = RawRecorder(engine)
    viewer.raw_recorder.start()
    return text
