"""Live guided calibration (000 Appendix B) on the page, and calibrations applied to sensors.

- :class:`CalibratedSource` wraps any source and corrects the samples of the sensors that
  have a :class:`margtrack.calibration.Calibration` (``x̂ = K⁻¹ (y - b)`` per triad) before
  the engine sees them; calibrations can be set or removed while it runs. Chunks are copied,
  never corrected in place (a replay's arrays stay raw).
- :class:`GuidedRun` runs :class:`~margtrack.calibration.live_procedure.LiveProcedure` on
  one sensor of a running engine: it reads the engine's frames (a ``before_batch`` hook, so
  the source has one reader), skips held samples, and when step 18 is done saves the
  calibration JSON (atomically, never over an existing file: ``_2``, ``_3``... are added)
  and applies it to that sensor through the :class:`CalibratedSource`. While it runs, the
  sensor's previous calibration is lifted, so the procedure sees raw data.
- :class:`CalibrationPanel` is the page's folder "Guided calibration": the sensor, a
  start/cancel button, the step and instruction, a progress bar for each hold and what is
  wrong ("+z should point down", "hold still"), refreshed at 5 Hz.
- :func:`attach` is the one call the viewer makes: it wraps the source and adds the panel
  (and starts the raw recording of ``--record``); :func:`page_recording` is the page's
  "Start recording" for the raw stream (:mod:`margtrack.live.recording`).
- :func:`feed_chunks` feeds a source's chunks of one sensor to a procedure (the terminal
  command ``margtrack calibrate guided --udp PORT``).
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from margtrack.calibration.calibration_file import Calibration
from margtrack.calibration.guided import Event, GuidedSettings
from margtrack.calibration.live_procedure import LiveProcedure, ProcedureStatus, save_result
from margtrack.live.assembler import Frames
from margtrack.live.protocol import Chunk, Source, SourceInfo, SourceStats

if TYPE_CHECKING:
    from margtrack.live.engine import Engine

__all__ = ["CalibratedSource", "CalibrationPanel", "GuidedRun", "attach", "feed_chunks",
           "free_path", "page_recording"]


class CalibratedSource:
    """A source whose listed sensors are corrected by their calibration (module docstring).

    Every other attribute is the wrapped source's (``address``, ``recording``...).
    """

    def __init__(self, source: Source, calibrations: dict[int, Calibration] | None = None
                 ) -> None:
        self.inner = source
        self._lock = threading.Lock()
        self._calibrations: dict[int, Calibration] = {}
        for sensor, cal in (calibrations or {}).items():
            self.set_calibration(sensor, cal)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    @property
    def info(self) -> SourceInfo:
        """The wrapped source's sensors."""
        return self.inner.info

    @property
    def stats(self) -> SourceStats:
        """The wrapped source's counters."""
        return self.inner.stats

    @property
    def finished(self) -> bool:
        """Whether the wrapped source is exhausted."""
        return self.inner.finished

    def open(self) -> None:
        """Open the wrapped source."""
        self.inner.open()

    def close(self) -> None:
        """Close the wrapped source."""
        self.inner.close()

    def set_calibration(self, sensor: int, calibration: Calibration | None) -> None:
        """Correct ``sensor``'s samples with ``calibration`` from the next poll (None: raw)."""
        if not 0 <= int(sensor) < self.info.n_sensors:
            raise ValueError(f"sensor must be in 0..{self.info.n_sensors - 1}, got {sensor}")
        if calibration is not None and calibration.mag is not None and not self.info.has_mag:
            calibration = Calibration(calibration.gyr, calibration.acc, None,
                                      source=calibration.source)
        with self._lock:
            if calibration is None:
                self._calibrations.pop(int(sensor), None)
            else:
                self._calibrations[int(sensor)] = calibration

    def calibration(self, sensor: int) -> Calibration | None:
        """The calibration applied to ``sensor`` (None: raw)."""
        with self._lock:
            return self._calibrations.get(int(sensor))

    def calibrations(self) -> dict[int, Calibration]:
        """Every calibration applied now, by sensor index (a copy)."""
        with self._lock:
            return dict(self._calibrations)

    def poll(self, timeout_s: float) -> list[Chunk]:
        """The wrapped source's chunks, calibrated sensors corrected (copies)."""
        chunks = self.inner.poll(timeout_s)
        with self._lock:
            cals = dict(self._calibrations)
        if not cals or not chunks:
            return chunks
        return [self._correct(c, cals) for c in chunks]

    @staticmethod
    def _correct(chunk: Chunk, cals: dict[int, Calibration]) -> Chunk:
        rows = [(k, cals[int(s)]) for k, s in enumerate(chunk.sensors) if int(s) in cals]
        if not rows:
            return chunk
        gyr, acc = chunk.gyr.copy(), chunk.acc.copy()
        mag = None if chunk.mag is None else chunk.mag.copy()
        for k, cal in rows:
            gyr[k] = cal.gyr.correct(gyr[k])
            acc[k] = cal.acc.correct(acc[k])
            if mag is not None and cal.mag is not None:
                mag[k] = cal.mag.correct(mag[k])
        return dataclasses.replace(chunk, gyr=gyr, acc=acc, mag=mag)


def feed_chunks(procedure: LiveProcedure, chunks: Iterable[Chunk], sensor: int) -> list[Event]:
    """Feed the samples of ``sensor`` in ``chunks`` to ``procedure``; returns its events."""
    events: list[Event] = []
    for chunk in chunks:
        if chunk.mag is None:
            raise ValueError("the guided procedure needs a magnetometer; the source has none")
        for k in np.flatnonzero(chunk.sensors == sensor):
            events += procedure.add_samples(chunk.t_s, chunk.gyr[k], chunk.acc[k],
                                            chunk.mag[k])
    return events


def free_path(path: Path) -> Path:
    """``path``, or ``stem_2.suffix``, ``stem_3.suffix``... the first that does not exist."""
    candidate, n = path, 1
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.stem}_{n}{path.suffix}")
    return candidate


class GuidedRun:
    """The live procedure on one sensor of a running engine (module docstring).

    Parameters
    ----------
    engine : the engine whose frames are read (hook registered here, once).
    sensor : index of the sensor to calibrate.
    source : the :class:`CalibratedSource` the engine reads, to apply the result (or None).
    out_dir : folder of the calibration file ``calibration_<sensor name>.json``.
    settings : tolerances of the procedure.
    """

    def __init__(self, engine: Engine, sensor: int, source: CalibratedSource | None,
                 out_dir: str | Path, settings: GuidedSettings | None = None) -> None:
        if not engine.info.has_mag:
            raise ValueError("the guided procedure needs a magnetometer; the source has none")
        if not 0 <= sensor < engine.info.n_sensors:
            raise ValueError(f"sensor must be in 0..{engine.info.n_sensors - 1}, got {sensor}")
        self.engine, self.sensor, self.source = engine, int(sensor), source
        self.name = engine.info.sensor_names[self.sensor]
        self.out_dir = Path(out_dir)
        self.procedure = LiveProcedure(settings)
        self.saved: Path | None = None
        self.error = ""
        self.active = True
        self._previous = source.calibration(self.sensor) if source is not None else None
        if source is not None:
            source.set_calibration(self.sensor, None)  # the procedure needs raw samples
        engine.before_batch.append(self._on_frames)

    @property
    def status(self) -> ProcedureStatus:
        """The procedure's status after the last sample."""
        return self.procedure.status

    def cancel(self) -> None:
        """Stop feeding the procedure and restore the sensor's previous calibration."""
        if self.active:
            self.active = False
            if self.source is not None:
                self.source.set_calibration(self.sensor, self._previous)

    def _on_frames(self, frames: Frames) -> None:
        if not self.active or frames.mag is None:
            return
        s = self.sensor
        fresh = ~frames.held[s]
        self.procedure.add_samples(frames.t_s[fresh], frames.gyr[s][fresh],
                                   frames.acc[s][fresh], frames.mag[s][fresh])
        if self.procedure.finished:
            self.active = False
            self._finish()

    def _finish(self) -> None:
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            path = free_path(self.out_dir / f"calibration_{self.name.replace('/', '_')}.json")
            self.saved = save_result(self.procedure.result(), path,
                                     source=f"live guided procedure on sensor {self.name}")
        except (OSError, ValueError) as exc:
            self.error = f"calibration not saved: {exc}"
        if self.source is not None:
            self.source.set_calibration(self.sensor, self.procedure.result().calibration)


class CalibrationPanel:
    """The page's "Guided calibration" folder (module docstring); needs a viser server."""

    def __init__(self, viewer: Any, source: CalibratedSource) -> None:
        self.viewer, self.source = viewer, source
        self.engine: Engine = viewer.engine
        self.run: GuidedRun | None = None
        gui = viewer.server.gui
        names = list(self.engine.info.sensor_names)
        with gui.add_folder("Guided calibration (000 App. B)", expand_by_default=False):
            self._sensor = gui.add_dropdown("sensor", names, initial_value=names[0])
            self._button = gui.add_button("Start guided calibration",
                                          disabled=not self.engine.info.has_mag)
            self._button.on_click(lambda _: self.toggle())
            self._progress = gui.add_progress_bar(0.0, animated=False)
            self._text = gui.add_markdown("" if self.engine.info.has_mag else
                                          "needs a magnetometer: this source has none")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="margtrack-calibration-panel",
                                        daemon=True)
        self._thread.start()

    def cancel_run(self) -> None:
        """Cancel a running procedure (its sensor's previous calibration is restored)."""
        if self.run is not None and self.run.active:
            self.run.cancel()

    def rebind(self, engine: Engine, source: CalibratedSource) -> None:
        """Serve ``engine`` reading ``source`` from now on (the page's *Replay again*; call
        :meth:`cancel_run` before building ``source`` from the old one)."""
        self.cancel_run()
        self.engine, self.source = engine, source

    def toggle(self) -> None:
        """Start a procedure on the chosen sensor, or cancel the running one."""
        if self.run is not None and self.run.active:
            self.run.cancel()
            self._button.label = "Start guided calibration"
            return
        sensor = list(self.engine.info.sensor_names).index(self._sensor.value)
        out = getattr(self.viewer, "out_dir", Path.cwd() / "margtrack_live")
        self.run = GuidedRun(self.engine, sensor, self.source, out)
        self._button.label = "Cancel guided calibration"

    def text(self) -> str:
        """The panel's markdown for the current state."""
        run = self.run
        if run is None:
            return "choose a sensor and press start; follow the steps shown here"
        st = run.status
        if st.finished:
            where = f"saved `{run.saved}`" if run.saved else run.error
            return f"**done**: {where}; applied to **{run.name}**"
        lines = [f"**step {st.step} of 18**: {st.instruction}",
                 f"hold {st.hold_needed_s:g} s: {100 * st.hold_progress:.0f} %",
                 f"down now: {st.down or '?'} (wanted {st.expected_down})"]
        if st.problem:
            lines.append(f"**{st.problem}**")
        if st.message and st.message != st.instruction:
            lines.append(f"_{st.message}_")
        if not run.active:
            lines.append("cancelled")
        return "  \n".join(lines)

    def _loop(self) -> None:
        while not self._stop.wait(0.2):
            run = self.run
            self._progress.value = 100.0 * (run.status.hold_progress if run else 0.0)
            self._text.content = self.text()
            if run is not None and not run.active:
                self._button.label = "Start guided calibration"

    def close(self) -> None:
        """Stop refreshing the panel (waits for the refresh thread)."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(1.0)


def attach(viewer: Any, source: Source, record: str | Path | None = None
           ) -> CalibratedSource:
    """The viewer's one call, before the engine starts: adds the guided-calibration panel and
    returns the source to run the engine on (``source`` wrapped in a
    :class:`CalibratedSource`). With ``record`` (``margtrack live --record FILE``) a
    :class:`~margtrack.live.recording.RawRecorder` starts with the engine, as
    ``viewer.raw_recorder``, so that the session replays exactly; the caller saves it
    (``viewer.raw_recorder.save(FILE)``) when the session ends."""
    from margtrack.live.recording import RawRecorder

    wrapped = source if isinstance(source, CalibratedSource) else CalibratedSource(source)
    viewer.calibration_panel = CalibrationPanel(viewer, wrapped)
    viewer.raw_recorder = None
    if record is not None:
        viewer.raw_recorder = RawRecorder(viewer.engine)
        viewer.raw_recorder.start()
    return wrapped


def page_recording(viewer: Any, start: bool) -> Path | None:
    """The page's "Start recording" / "Stop recording" for the raw stream: starts a
    :class:`~margtrack.live.recording.RawRecorder` on the viewer's engine, or stops it and
    writes ``<out_dir>/live_raw.hdf5`` (``_2``, ``_3``... if taken); returns the file."""
    from margtrack.live.recording import RawRecorder

    if start:
        recorder = RawRecorder(viewer.engine)
        recorder.detach_on_stop = True
        recorder.start()
        viewer.page_raw_recorder = recorder
        return None
    recorder = getattr(viewer, "page_raw_recorder", None)
    if recorder is None or not recorder.recording:
        return None
    viewer.page_raw_recorder = None
    out = Path(getattr(viewer, "out_dir", Path.cwd() / "margtrack_live"))
    out.mkdir(parents=True, exist_ok=True)
    return recorder.save(free_path(out / "live_raw.hdf5"))
