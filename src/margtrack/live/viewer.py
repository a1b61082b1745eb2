"""The live 3-D view in a browser page, served on localhost by ``viser``.

What the page shows (000's display, in a browser): every person's segments as bones
(joint to distal end, and the parent's distal end to the joint, e.g. neck to shoulder;
left side blue, right red) with a small frame
per segment, or, without a body model, one frame per sensor; a status panel ("poses shown:
N", data time, latency, processing time, drops, calibration); the sensor list with health
(rate, drops, magnetic-norm check); one control per numeric filter parameter (changes go to
:meth:`Engine.set_params` and take effect at the next sample; a rejected value is reported
and the control reset); a "Calibrate in reference pose" button with a countdown; and
"Start recording" / "Stop recording and export" writing a BVH and a joint-angle CSV.

Threads: the engine's worker publishes poses; the viewer's own thread
("margtrack-live-viewer") sends the latest one to the browser at the display rate and the
panels at about 4 Hz; viser's server thread runs the GUI callbacks. :class:`LiveSession`
owns all three and stops them in :meth:`LiveSession.stop`.

``viser`` is imported only here (``pip install viser``; an extra of margtrack).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import frames as frames_mod
from margtrack.body.offsets import Heading
from margtrack.estimator.params import specs
from margtrack.live.engine import Engine, Pose
from margtrack.live.protocol import Source

Array = NDArray[np.float64]

__all__ = ["LiveSession", "LiveViewer", "run_live"]

_PANEL_PERIOD_S = 0.25
_MAX_SENSOR_ROWS = 24
_COLORS = {"left": (40, 110, 220), "right": (220, 60, 50), "": (90, 90, 90)}


def _viser() -> Any:
    try:
        import viser
    except ImportError:
        raise ImportError("the live view needs viser: pip install viser (or margtrack[live])"
                          ) from None
    return viser


def _display(frame: str, p: Array | None = None, q: Array | None = None
             ) -> tuple[Array | None, Array | None]:
    """Positions and orientations in the page's z-up world (ENU)."""
    if frame == "ENU":
        return p, q
    p2 = None if p is None else np.stack([p[..., 1], p[..., 0], -p[..., 2]], axis=-1)
    return p2, None if q is None else frames_mod.convert(q, frame, "ENU")


def _step(value: float) -> float:
    return 10.0 ** (math.floor(math.log10(abs(value))) - 1) if value else 0.01


class LiveViewer:
    """Scene and GUI of one engine on one viser server (module docstring)."""

    def __init__(self, engine: Engine, server: Any, out_dir: str | Path | None = None,
                 countdown_s: float = 3.0) -> None:
        self.engine = engine
        self.server = server
        self.out_dir = Path(out_dir) if out_dir is not None else Path.cwd() / "margtrack_live"
        self.countdown_s = float(countdown_s)
        self.poses_shown = 0
        self.exported: list[Path] = []
        self._lock = threading.Lock()
        self._pose: Pose | None = None
        self._new = threading.Event()
        self._stop = threading.Event()
        self._message = ""
        self._controls: dict[str, Any] = {}
        self._reverting = False
        self._build_scene()
        self._build_gui()
        self._unsubscribe = engine.subscribe(self._on_pose)
        self._thread = threading.Thread(target=self._loop, name="margtrack-live-viewer",
                                        daemon=True)
        self._thread.start()

    # -- scene -------------------------------------------------------------------------------
    def _build_scene(self) -> None:
        scene = self.server.scene
        scene.add_grid("/floor", width=8.0, height=8.0, cell_size=0.5)
        self.server.initial_camera.position = (2.0, -2.6, 1.6)
        self.server.initial_camera.look_at = (0.0, 0.0, 0.9)
        av = self.engine.avatars
        if av is not None:
            sk = av.skeleton
            sides = [n.split("_")[0] if n.split("_")[0] in _COLORS else "" for n in sk.names]
            seg_colors = np.array([_COLORS[s] for s in sides], dtype=np.uint8)
            colors = np.concatenate([seg_colors[1:], seg_colors])  # links, then bones
            self._colors = np.tile(colors[:, None, :], (av.n_people, 2, 1))
            n_lines = av.n_people * (2 * len(sk) - 1)
            self._bones = scene.add_line_segments(
                "/avatars/bones", np.zeros((n_lines, 2, 3)), self._colors, thickness=0.035)
            n_seg = av.n_people * len(sk)
            self._frames = scene.add_batched_axes(
                "/avatars/frames", np.tile([1.0, 0, 0, 0], (n_seg, 1)), np.zeros((n_seg, 3)),
                axes_length=0.08, axes_radius=0.008)
        else:
            n = self.engine.info.n_sensors
            cols = math.ceil(math.sqrt(n))
            self._sensor_positions = np.array(
                [(0.6 * (i % cols), 0.6 * (i // cols), 1.0) for i in range(n)], dtype=float)
            self._frames = scene.add_batched_axes(
                "/sensors", np.tile([1.0, 0, 0, 0], (n, 1)), self._sensor_positions,
                axes_length=0.25, axes_radius=0.02)

    def _show(self, pose: Pose) -> None:
        av = self.engine.avatars
        with self.server.atomic():
            if av is not None and pose.joints_m is not None:
                parents = av.skeleton.parents[1:]
                joints, ends = pose.joints_m, pose.ends_m
                links = np.stack([ends[:, parents], joints[:, 1:]], axis=2)
                bones = np.stack([joints, ends], axis=2)
                lines = np.concatenate([links, bones], axis=1).reshape(-1, 2, 3)
                lines, q = _display(self.engine.frame, lines, pose.q_segment.reshape(-1, 4))
                self._bones.points = lines.astype(np.float32)
                mid, _ = _display(self.engine.frame, (0.5 * (joints + ends)).reshape(-1, 3))
                self._frames.batched_positions = mid.astype(np.float32)
                self._frames.batched_wxyzs = q.astype(np.float32)
            else:
                _, q = _display(self.engine.frame, None, pose.q_sensor)
                self._frames.batched_wxyzs = q.astype(np.float32)

    # -- GUI ---------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.server.gui
        info = self.engine.info
        gui.add_markdown(f"**margtrack live** · {info.description} · method "
                         f"`{self.engine.method}`")
        with gui.add_folder("Status"):
            self._status = gui.add_markdown("poses shown: 0")
        with gui.add_folder("Calibration and recording"):
            self._calibrate = gui.add_button("Calibrate in reference pose",
                                             disabled=self.engine.avatars is None)
            self._calibrate.on_click(lambda _: self._start_countdown())
            self._record = gui.add_button("Start recording", disabled=self.engine.avatars is None)
            self._record.on_click(lambda _: self._toggle_recording())
        with gui.add_folder(f"Filter: {self.engine.method}"):
            for spec in specs(self.engine.params):
                value = getattr(self.engine.params, spec.name)
                if spec.name == "frame" or value is None or isinstance(value, (tuple, str)):
                    continue
                if isinstance(value, bool):
                    handle = gui.add_checkbox(spec.label, initial_value=value, hint=spec.help)
                else:
                    low = spec.ge if spec.ge is not None else spec.gt
                    high = spec.le if spec.le is not None else spec.lt
                    handle = gui.add_number(
                        spec.label,
                        initial_value=value,
                        min=low,
                        max=high,
                        step=1 if isinstance(value, int) else _step(value),
                        hint=f"{spec.help} ({spec.bounds_text()} {spec.unit})".strip(),
                    )
                handle.on_update(self._param_callback(spec.name, handle))
                self._controls[spec.name] = handle
        with gui.add_folder("Sensors"):
            self._sensors = gui.add_markdown("")

    def _param_callback(self, name: str, handle: Any) -> Any:
        def changed(event: Any) -> None:
            if self._reverting:
                return
            try:
                self.engine.set_params(**{name: handle.value})
            except (ValueError, TypeError) as exc:
                self._message = f"{name} rejected: {exc}"
                if getattr(event, "client", None) is not None:
                    event.client.add_notification(f"{name} rejected", str(exc),
                                                  auto_close_seconds=5.0, color="red")
                self._reverting = True
                try:
                    handle.value = getattr(self.engine.params, name)
                finally:
                    self._reverting = False
            else:
                self._message = f"{name} = {handle.value} from the next sample"

        return changed

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

    def _toggle_recording(self) -> None:
        if not self.engine.recording:
            self.engine.start_recording()
            self._record.label = "Stop recording and export"
            self._message = "recording"
            return
        self._record.label = "Start recording"
        rec = self.engine.stop_recording()
        try:
            stem = time.strftime("live_%Y%m%d_%H%M%S")
            self.exported = rec.export(self.out_dir, stem)
            self._message = "exported " + ", ".join(str(p) for p in self.exported)
        except ValueError as exc:
            self._message = f"export failed: {exc}"

    def _panels(self, pose: Pose | None) -> None:
        st = self.engine.stats()
        t = f"{pose.t_s:.2f} s" if pose is not None else "-"
        self._status.content = (
            f"poses shown: {self.poses_shown}  \n"
            f"data time {t} · {st.frames} frames  \n"
            f"latency p50 {st.latency_p50_s * 1e3:.1f} ms · p95 {st.latency_p95_s * 1e3:.1f} ms"
            f"  \nprocessing {st.processing_s_per_sample * 1e6:.2f} µs/sample · "
            f"dropped {st.dropped_samples} · late frames {st.late_frames}  \n"
            f"calibration: {st.calibration}  \n{self._message}"
            + (f"  \n**{st.error}**" if st.error else "")
        )
        h = st.health
        rows = ["| sensor | Hz | drops | \\|m\\|/\\|m₀\\| |", "|---|---|---|---|"]
        for i in range(min(len(h.names), _MAX_SENSOR_ROWS)):
            ratio = h.mag_norm_ratio[i]
            mark = "–" if not np.isfinite(ratio) else ("✓" if h.mag_ok[i] else "✗")
            rows.append(f"| {h.names[i]} | {h.rate_hz[i]:.0f} | {h.dropped[i]} | "
                        f"{ratio:.2f} {mark} |")
        if len(h.names) > _MAX_SENSOR_ROWS:
            rows.append(f"| … {len(h.names) - _MAX_SENSOR_ROWS} more | | "
                        f"{int(h.dropped.sum())} | {int(h.mag_ok.sum())} ✓ |")
        self._sensors.content = "\n".join(rows)

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
            if pose is not None:
                self._show(pose)
                self.poses_shown += 1
            now = time.perf_counter()
            if now >= next_panel:
                next_panel = now + _PANEL_PERIOD_S
                self._panels(pose if pose is not None else self.engine.latest)

    def close(self) -> None:
        """Stop updating the page (the server is closed by its owner)."""
        self._unsubscribe()
        self._stop.set()
        self._thread.join(2.0)


@dataclasses.dataclass
class LiveSession:
    """A running engine, its viewer and the viser server; :meth:`stop` ends them all."""

    engine: Engine
    viewer: LiveViewer
    server: Any
    url: str

    def stop(self) -> None:
        """Stop the viewer, the engine (closing the source) and the server."""
        self.viewer.close()
        self.engine.stop()
        self.server.stop()

    def __enter__(self) -> LiveSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def run_live(
    source: Source,
    method: str = "default",
    port: int = 8080,
    *,
    host: str = "127.0.0.1",
    params: Mapping[str, Any] | Iterable[str] = (),
    display_hz: float = 25.0,
    height_m: float = 1.75,
    calibrate_at_start: bool = False,
    heading: Heading = "north",
    forward_axis: ArrayLike | None = None,
    out_dir: str | Path | None = None,
    block: bool = True,
    duration_s: float | None = None,
) -> LiveSession:
    """Track ``source`` live and serve the 3-D view at ``http://host:port``.

    Parameters
    ----------
    source : any :class:`~margtrack.live.protocol.Source` (simulator, replay, UDP, serial).
    method, params : the filter (registered name) and its parameters.
    port : TCP port of the page (0: a free one, see ``session.url``); host : address bound
        (``127.0.0.1``: this machine only).
    display_hz, height_m, calibrate_at_start, heading, forward_axis : see :class:`Engine`.
    out_dir : where "Stop recording and export" writes (default ``./margtrack_live``).
    block : serve until Ctrl-C (or ``duration_s``), then stop everything and return the
        stopped session; ``False`` returns the running session at once (call ``stop()``).
    duration_s : with ``block``, stop after this many seconds.
    """
    viser = _viser()
    engine = Engine(source.info, method, params, height_m=height_m, display_hz=display_hz,
                    heading=heading, forward_axis=forward_axis,
                    calibrate_at_start=calibrate_at_start)
    server = viser.ViserServer(host=host, port=port, verbose=False)
    try:
        viewer = LiveViewer(engine, server, out_dir)
        engine.start(source)
    except BaseException:
        server.stop()
        raise
    session = LiveSession(engine, viewer, server, f"http://{host}:{server.get_port()}")
    if not block:
        return session
    end = math.inf if duration_s is None else time.perf_counter() + duration_s
    try:
        with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C ends the session cleanly
            while time.perf_counter() < end:
                time.sleep(min(0.2, max(end - time.perf_counter(), 0.0)))
    finally:
        session.stop()
    return session
