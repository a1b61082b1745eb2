"""The live 3-D view in a browser page, served on this machine by ``viser``.

What the page shows (000's display, in a browser):

- the scene (:mod:`margtrack.live.viewer_scene`): every person as solids (capsule limbs, a
  shoulder girdle, trunk and pelvis boxes, a head; left side blue, right red), the camera
  framed on them at start; without a body model one frame per sensor;
- *Status*: poses shown, session time (from 0 at the first frame), latency, processing
  time, drops, calibration, the engine's error; when a replay ends, a notice, a *Loop
  replay* option and a *Replay again* button (:mod:`margtrack.live.viewer_replay`: the
  sensor calibrations and the raw recording carry over to the new engine);
- *Joint angles*: the first person's joint angles now, and a scrolling plot of the joints
  ticked under it (first component, deg, over the last 10 s);
- *Calibration and recording*: "Calibrate in reference pose" with a countdown;
  "Start recording" / "Stop recording and export" writing BVH, joint-angle CSV and OpenSim
  ``.sto`` (:func:`~margtrack.live.viewer_panels.export_recording`), the files' full paths
  listed in the panel;
- *Filter*: one control per numeric parameter, labelled from its declaration (label with
  unit, help and bounds as hint); changes go to :meth:`Engine.set_params` and take effect
  at the next sample; a rejected value is reported and the control reset;
- *Sensors*: health in body order (the skeleton's segment order), with the stale state and
  the loss / gap / resync / flag counters when the engine reports them.

Threads: the engine's worker publishes poses; the viewer's own thread
("margtrack-live-viewer") sends the latest one to the browser at the display rate and the
panels at about 4 Hz; viser's server thread runs the GUI callbacks.
:class:`~margtrack.live.viewer_session.LiveSession` owns all three and stops them
(:func:`~margtrack.live.viewer_session.run_live` starts one). Who may connect:
:mod:`margtrack.live.security`.

``viser`` is imported only here and in the modules above (an extra of margtrack).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack import body
from margtrack.live import calibration_panel
from margtrack.live.engine import Engine, Pose
from margtrack.live.protocol import Source
from margtrack.live.viewer_controls import JointPlot, ParamControls
from margtrack.live.viewer_panels import (
    JointTrace,
    end_notice,
    export_recording,
    joints_lines,
    sensor_order,
    sensor_table,
    status_text,
)
from margtrack.live.viewer_replay import replay_again, replay_of
from margtrack.live.viewer_scene import AvatarScene

Array = NDArray[np.float64]

__all__ = ["LiveViewer"]

_PANEL_PERIOD_S = 0.25


class LiveViewer:
    """Scene and GUI of one engine on one viser server (module docstring).

    source : the engine's source, for the replay options (loop, replay again), or None.
    new_engine : builds an engine like ``engine`` (not started); with a replay ``source``
        (plain or in a calibration wrapper), *Replay again* runs one on a rewound copy of
        the replay, with the parameters in force (:func:`~.viewer_replay.replay_again`).
    """

    def __init__(self, engine: Engine, server: Any, out_dir: str | Path | None = None,
                 countdown_s: float = 3.0, source: Source | None = None,
                 new_engine: Callable[[], Engine] | None = None) -> None:
        self.engine = engine
        self.server = server
        self.source = source
        self.out_dir = Path(out_dir) if out_dir is not None else Path.cwd() / "margtrack_live"
        self.countdown_s = float(countdown_s)
        self.poses_shown = 0
        self.exported: list[Path] = []
        self.new_engine = new_engine if replay_of(source) is not None else None
        self._lock = threading.Lock()
        self._pose: Pose | None = None
        self._new = threading.Event()
        self._stop = threading.Event()
        self._message = ""
        self._t0: float | None = None
        self._session_s = math.nan
        self._angles: body.JointAngles | None = None
        self._trace = JointTrace()
        self._order = sensor_order(engine.info.sensor_names, engine.avatars)
        self.scene = AvatarScene(server, engine.avatars, engine.info.n_sensors, engine.frame)
        self._joint_names = self._joints()
        self._build_gui()
        self._unsubscribe = engine.subscribe(self._on_pose)
        self._thread = threading.Thread(target=self._loop, name="margtrack-live-viewer",
                                        daemon=True)
        self._thread.start()

    def _joints(self) -> tuple[str, ...]:
        av = self.engine.avatars
        if av is None:
            return ()
        q = np.tile([1.0, 0.0, 0.0, 0.0], (len(av.skeleton), 1))
        return tuple(body.joint_angles(av.skeleton, q).names)

    # -- GUI ---------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.server.gui
        info = self.engine.info
        gui.add_markdown(f"**margtrack live** · {info.description} · method "
                         f"`{self.engine.method}`"
                         + (" · no magnetometer (joints constrained)" if self.engine.no_mag
                            else ""))
        with gui.add_folder("Status"):
            self._status = gui.add_markdown("poses shown: 0")
            self._notice = gui.add_markdown("", visible=False)
            if self.source is not None and hasattr(self.source, "loop"):
                self._loop_box = gui.add_checkbox(
                    "Loop replay", initial_value=bool(getattr(self.source, "loop", False)),
                    hint="Start the replay again after its last frame (timestamps continue).")
                self._loop_box.on_update(lambda _: self._set_loop(self._loop_box.value))
            if self.new_engine is not None:
                self._again = gui.add_button("Replay again", visible=False)
                self._again.on_click(lambda _: self._replay_again())
        self._joint_plot: JointPlot | None = None
        if self._joint_names:
            with gui.add_folder("Joint angles"):
                self._joint_plot = JointPlot(self.server, self._joint_names, self._trace)
        with gui.add_folder("Calibration and recording"):
            self._calibrate = gui.add_button("Calibrate in reference pose",
                                             disabled=self.engine.avatars is None)
            self._calibrate.on_click(lambda _: self._start_countdown())
            self._record = gui.add_button("Start recording", disabled=self.engine.avatars is None)
            self._record.on_click(lambda _: self.toggle_recording())
            self._exports = gui.add_markdown(f"exports go to `{self.out_dir.resolve()}`")
            if self.engine.walking_root:
                self._reset_root = gui.add_button(
                    "Reset position", hint="Put the avatar back where it started (its root "
                    "walks with the feet's contacts once calibrated).")
                self._reset_root.on_click(lambda _: self.engine.reset_root())
        with gui.add_folder(f"Filter: {self.engine.method}"):
            self._axes_box = gui.add_checkbox("show segment axes", initial_value=False)
            self._axes_box.on_update(lambda _: self.scene.set_axes_visible(self._axes_box.value))
            self._params = ParamControls(gui, lambda: self.engine, self._say)
        with gui.add_folder("Sensors"):
            self._sensors = gui.add_markdown("")
        if self.engine.no_mag:
            with gui.add_folder("Joints (no magnetometer)"):
                self._joints_md = gui.add_markdown("  \n".join(
                    joints_lines(self.engine.joints)))

    @property
    def message(self) -> str:
        """The last message shown in the status panel."""
        return self._message

    def _set_loop(self, value: bool) -> None:
        target = replay_of(self.source) or self.source
        if target is not None:
            target.loop = bool(value)  # type: ignore[attr-defined]
            self._message = "the replay loops" if value else "the replay stops at its end"

    def _replay_again(self) -> None:
        """The *Replay again* button (:func:`~.viewer_replay.replay_again`)."""
        message = replay_again(self)
        if message is not None:
            self._again.visible = False
            self._notice.visible = False
            self._message = message

    def switch_engine(self, engine: Engine, source: Source) -> None:
        """Show ``engine`` (reading ``source``) instead of the stopped one."""
        self._unsubscribe()
        self.engine.stop()
        self._t0 = None
        self._trace.clear()
        self.engine, self.source = engine, source
        self._unsubscribe = engine.subscribe(self._on_pose)

    def _say(self, message: str) -> None:
        self._message = message

    def _start_countdown(self) -> None:
        def countdown() -> None:
            self._calibrate.disabled = True
            end = time.perf_counter() + self.countdown_s
            while not self._stop.is_set() and (left := end - time.perf_counter()) > 0:
                self._calibrate.label = f"Hold the reference pose: {math.ceil(left)} s"
                time.sleep(min(0.2, left))
            self._calibrate.label = "Calibrate in reference pose"
            self._calibrate.disabled = False
            if not self._stop.is_set():
                self.engine.request_calibration()

        threading.Thread(target=countdown, name="margtrack-live-countdown", daemon=True).start()

    def toggle_recording(self) -> None:
        """The page's "Start recording" / "Stop recording and export" button."""
        if not self.engine.recording:
            self.engine.start_recording()
            calibration_panel.page_recording(self, True)  # the raw stream too
            self._record.label = "Stop recording and export"
            self._message = "recording"
            return
        self._record.label = "Start recording"
        rec = self.engine.stop_recording()
        try:
            raw = calibration_panel.page_recording(self, False)  # raw stream, .hdf5
            unit = getattr(self, "bvh_unit", "cm")
            self.exported = [*export_recording(rec, self.out_dir, bvh_unit=unit),
                             *([raw] if raw else [])]
        except (ValueError, OSError) as exc:
            self._message = f"export failed: {exc}"
            self._exports.content = f"**export failed:** {exc}"
        else:
            self._message = f"exported {len(self.exported)} files (BVH in {unit})"
            self._exports.content = f"exported (BVH lengths in {unit}):\n\n" + "\n".join(
                f"- `{path}`" for path in self.exported)

    def _session_time(self, pose: Pose) -> float:
        """Seconds since the session's first frame (the engine's, when it provides it)."""
        if hasattr(self.engine, "session_origin_s"):  # the engine's times are session times
            return pose.t_s
        if self._t0 is None:  # an engine on device time: from the first pose shown
            self._t0 = pose.t_s
        return pose.t_s - self._t0

    def _panels(self) -> None:
        engine = self.engine
        # whether it ended, before its stats: read after, they hold why it ended (read
        # before, a stop in between showed a failed engine as a source that ended)
        ended = engine.wait(0)  # the source is exhausted or the engine stopped
        st = engine.stats()
        self._status.content = status_text(st, self.poses_shown, self._session_s,
                                           self._message)
        # the engine's own failure (B1's engine_error), else an error text naming a stop
        fatal = getattr(st, "engine_error", None) or (
            st.error if st.error.startswith("engine stopped") else None)
        if ended and not self._notice.visible:
            self._notice.content = end_notice(st, self._session_s, fatal,
                                              replay=hasattr(self.source, "loop"),
                                              again=self.new_engine is not None)
            self._notice.visible = True
            if self.new_engine is not None and not fatal:
                self._again.visible = True
        self._sensors.content = sensor_table(st.health, self._order)
        if self.engine.no_mag:
            self._joints_md.content = "  \n".join(joints_lines(self.engine.joints))
        if self._joint_plot is not None and self._angles is not None:
            self._joint_plot.update(self._angles)

    # -- threads -----------------------------------------------------------------------------
    def _on_pose(self, pose: Pose) -> None:
        with self._lock:
            self._pose = pose
        self._new.set()

    def _loop(self) -> None:
        next_panel = 0.0
        while not self._stop.is_set():
            self._new.wait(0.1)
            self._new.clear()
            with self._lock:
                pose, self._pose = self._pose, None
            try:
                if pose is not None:
                    self._session_s = self._session_time(pose)
                    self.scene.show(pose)
                    self.poses_shown += 1
                    if self._joint_names and pose.q_segment is not None:
                        self._angles = body.joint_angles(self.engine.avatars.skeleton,
                                                         pose.q_segment[0])
                        self._trace.add(self._session_s, self._angles)
                now = time.perf_counter()
                if now >= next_panel:
                    next_panel = now + _PANEL_PERIOD_S
                    self._panels()
            except Exception as exc:  # a display failure must not end the page's updates
                self._message = f"display error: {exc!r}"

    def close(self) -> None:
        """Stop updating the page, attached panels included (the server is closed by its
        owner)."""
        self._unsubscribe()
        self._stop.set()
        self._thread.join(2.0)
        panel = getattr(self, "calibration_panel", None)  # calibration_panel.attach's
        if panel is not None:
            panel.close()
