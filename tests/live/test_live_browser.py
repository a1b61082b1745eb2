"""The live view in a real browser: headless Debian chromium driven by Playwright.

Needs /usr/bin/chromium (``apt-get install chromium``), the ``playwright`` Python package (no
browser download: the system chromium is launched) and ``viser``; skipped with the reason
when one is missing. Software WebGL (SwiftShader) renders the scene headless.
"""

from __future__ import annotations

import math
import re
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from margtrack.estimator.params import specs
from margtrack.live.simulator import PeopleSimulation, SimulatorSource
from margtrack.live.viewer_controls import control_label
from margtrack.methods.bachmann import BachmannParams

pytestmark = pytest.mark.browser

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    "--disable-gpu-sandbox", "--no-first-run", "--disable-background-networking",
    "--disable-component-update", "--disable-sync",
]


def _wait(predicate, timeout_s: float, what: str) -> None:
    end = time.perf_counter() + timeout_s
    while not predicate():
        if time.perf_counter() > end:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.05)


def _avatar_box(pixels: np.ndarray) -> tuple[int, int, int, int, int] | None:
    """(left, top, right, bottom, count) of the avatar's coloured pixels in the 3-D view.

    The scene is what lies left of the control panel (x < 760) and above the axes gizmo
    (y < 690), without the WebGL notice (top left); the floor grid and the background are
    grey or white, the avatar's solids are coloured (channel spread > 0.12).
    """
    scene = pixels[:690, :760]
    spread = scene.max(axis=-1) - scene.min(axis=-1)
    mask = spread > 0.12
    mask[:170, :330] = False  # the "Software WebGL rendering" notice
    rows, cols = np.nonzero(mask)
    if rows.size < 500:
        return None
    return int(cols.min()), int(rows.min()), int(cols.max()), int(rows.max()), int(rows.size)


def test_live_view_connects_renders_the_avatar_and_retunes_the_filter(tmp_path):
    if not CHROMIUM.is_file():
        pytest.skip("Debian's chromium is not installed (apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api",
                                   reason="the playwright package is not installed")
    pytest.importorskip("viser", reason="the live view needs viser (pip install viser)")
    import matplotlib.image

    from margtrack.live.viewer_session import run_live

    source = SimulatorSource(PeopleSimulation(seed=1), speed=1.0)
    # token=True: the page needs its token even on loopback, so the real client's page load
    # (?token=...) and websocket (the cookie, the page's own Origin) pass the access check
    session = run_live(source, "bachmann", port=0, block=False, calibrate_at_start=True,
                       out_dir=tmp_path, token=True)
    assert session.token and session.url.endswith(f"?token={session.token}")
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1100, "height": 750})
            refused = page.goto(session.url.split("?")[0])
            assert refused.status == 403 and "needs its token" in refused.text()
            page.goto(session.url)
            page.get_by_text("Connected").wait_for(timeout=15000)
            counter = page.get_by_text(re.compile(r"poses shown: \d+"))
            counter.wait_for(timeout=15000)

            def shown() -> int:
                return int(re.search(r"poses shown: (\d+)", counter.inner_text()).group(1))

            _wait(lambda: shown() >= 25, 15.0, "25 poses shown on the page")  # 1 s at 25 Hz
            assert len(session.server.get_clients()) == 1
            assert session.engine.stats().poses_published >= 25

            # the first screenshot: the avatar is drawn (left side blue, right side red; lit
            # and anti-aliased, so colours are told apart by the dominant channel) and framed:
            # its bounding box is centred in the view and covers a good part of its height.
            # A frame caught while viser swaps geometry can be pale: up to five tries.
            shot = tmp_path / "live.png"
            for _ in range(5):
                page.screenshot(path=str(shot))
                pixels = matplotlib.image.imread(shot)[..., :3]  # floats in [0, 1]
                r, g, b = (pixels[160:690, :760, k] for k in range(3))
                blue = int(np.sum(b - np.maximum(r, g) > 0.12))
                red = int(np.sum(r - np.maximum(g, b) > 0.12))
                box = _avatar_box(pixels)
                if blue > 500 and red > 500 and box is not None:
                    break
                time.sleep(0.3)
            Path("/tmp/margtrack_live_browser.png").write_bytes(shot.read_bytes())
            assert pixels.std() > 0.05, "blank page"
            assert blue > 500 and red > 500, f"avatar not drawn: {blue} blue, {red} red pixels"
            assert box is not None, "no avatar pixels in the 3-D view"
            left, top, right, bottom, _ = box
            width, height = pixels.shape[1], pixels.shape[0]
            # the camera looks at the avatar: the canvas spans the window, panel over it
            assert abs(0.5 * (left + right) - 0.5 * width) < 0.1 * width, box
            assert abs(0.5 * (top + bottom) - 0.5 * height) < 0.15 * height, box
            assert (bottom - top) > 0.4 * height, f"avatar too small: {box}"
            assert (right - left) < 0.6 * width, f"avatar too wide (not framed): {box}"

            # session time from 0, joint angles, sensors in body order (pelvis before trunk,
            # trunk before head; the source's order is not alphabetical either way)
            status = page.locator("p", has_text="poses shown").inner_text()
            session_s = float(re.search(r"session time (\d+\.\d+) s", status).group(1))
            assert 0.5 < session_s < 600.0
            page.get_by_role("cell", name="right knee").wait_for(timeout=5000)
            cells = [c.inner_text() for c in page.get_by_role("cell").all()]
            assert cells.index("pelvis") < cells.index("trunk") < cells.index("head")
            assert cells.index("head") < cells.index("left_upper_arm") < cells.index("left_thigh")

            # the control is labelled by the parameter's declaration: name and unit
            spec = next(p for p in specs(BachmannParams) if p.name == "gain")
            label = control_label(spec.name, spec.unit)
            assert label == "gain [1/s]"
            gain = page.get_by_label(label, exact=True)
            assert float(gain.input_value()) == pytest.approx(BachmannParams().gain)
            gain.fill("0.5")
            gain.press("Enter")
            _wait(lambda: session.engine.active_params.gain == 0.5, 5.0,
                  "the engine's filter to run with gain 0.5")
            frames = session.engine.stats().frames
            _wait(lambda: session.engine.stats().frames > frames, 2.0, "more frames")

            # record 1 s, export: BVH, CSV and .sto, their full paths shown in the panel
            page.get_by_role("button", name="Start recording").click()
            _wait(lambda: session.engine.recording, 5.0, "the recording to start")
            time.sleep(1.0)
            page.get_by_role("button", name="Stop recording and export").click()
            def exported() -> list[Path]:  # (the raw stream's live_raw*.hdf5 may come too)
                return sorted((f for f in tmp_path.glob("live_*") if f.suffix != ".hdf5"),
                              key=lambda f: f.suffix)

            _wait(lambda: len(exported()) == 3, 10.0, "three exported files")
            files = exported()
            assert [f.suffix for f in files] == [".bvh", ".csv", ".sto"]
            for f in files:
                page.get_by_text(str(f.resolve())).wait_for(timeout=5000)
            assert files[2].read_text().splitlines()[1] == "DataType=Quaternion"
            browser.close()
    finally:
        session.stop()
    assert session.engine.active_params.gain == 0.5
    assert math.isfinite(session.engine.stats().latency_p50_s)
    assert not [t for t in threading.enumerate() if t.name.startswith("margtrack-live")]
    assert np.isfinite(session.engine.latest.joints_m).all()


def test_replay_end_notice_then_replay_again_restarts_session_time(tmp_path):
    if not CHROMIUM.is_file():
        pytest.skip("Debian's chromium is not installed (apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api",
                                   reason="the playwright package is not installed")
    pytest.importorskip("viser", reason="the live view needs viser (pip install viser)")
    from margtrack.body.skeleton import SEGMENT_NAMES
    from margtrack.live.replay import ReplaySource
    from margtrack.live.viewer_session import run_live

    n, s = 400, len(SEGMENT_NAMES)  # 4 s at 100 Hz of 15 still sensors
    t = 1000.0 + 0.01 * np.arange(n)  # a device clock far from 0
    gyr = np.zeros((s, n, 3))
    acc = np.tile([0.0, 0.0, 9.81], (s, n, 1))
    mag = np.tile([0.0, 20.0, -40.0], (s, n, 1))
    source = ReplaySource(t, gyr, acc, mag, SEGMENT_NAMES, speed=1.0, description="still")
    session = run_live(source, "bachmann", port=0, block=False, out_dir=tmp_path)
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1100, "height": 750})
            page.goto(session.url)
            notice = page.get_by_text(re.compile(r"Replay ended at session time"))
            notice.wait_for(timeout=20000)
            ended_s = float(re.search(r"session time (\d+\.\d+) s", notice.inner_text())[1])
            assert 3.5 <= ended_s <= 4.0  # session time: 0 at the first frame, not 1000 s
            first = session.engine
            assert first.stats().frames == n
            # tick "Loop replay", then "Replay again": a new engine on a rewound copy of the
            # replay, which now runs on past its end (a second lap)
            page.get_by_label("Loop replay").check()
            page.get_by_role("button", name="Replay again").click()
            _wait(lambda: session.engine is not first, 10.0, "a new engine")
            page.get_by_text("replaying again (the previous run had 400 frames)").wait_for(
                timeout=10000)
            _wait(lambda: session.engine.stats().frames > n + 20, 15.0, "a second lap")
            assert session.engine.running
            browser.close()
    finally:
        session.stop()
    assert not [t for t in threading.enumerate() if t.name.startswith("margtrack-live")]


def test_no_mag_page_lists_the_joints_and_the_avatar_walks_until_reset(tmp_path):
    if not CHROMIUM.is_file():
        pytest.skip("Debian's chromium is not installed (apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api",
                                   reason="the playwright package is not installed")
    pytest.importorskip("viser", reason="the live view needs viser (pip install viser)")
    from margtrack.live.viewer_session import run_live

    people = PeopleSimulation(preset="lower", seed=3)
    source = SimulatorSource(people, speed=3.0)
    session = run_live(source, "default", port=0, block=False, calibrate_at_start=True,
                       out_dir=tmp_path, heading="pelvis",
                       forward_axis=people.pelvis_forward_axis(), no_mag=True,
                       walking_root=True)
    engine = session.engine
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1100, "height": 750})
            page.goto(session.url)
            page.get_by_text("Connected").wait_for(timeout=15000)
            page.get_by_text(re.compile("no magnetometer \\(joints constrained\\)")).wait_for(
                timeout=10000)
            page.get_by_text(re.compile("6 joints constrained")).wait_for(timeout=10000)
            # still 2 s, then 3 s of walking for the lever arms (1/3 of that in real time)
            page.get_by_text(re.compile(r"left_knee: parent \[.*\(estimated\); settled")
                             ).wait_for(timeout=20000)
            _wait(lambda: engine.calibration_status.startswith("calibrated on 0.0"), 10.0,
                  "the calibration on the still start")
            start = engine.avatars.root_positions_m[0]

            # every published pose's distance from the start: the avatar walks on right
            # after a reset, so polling only the latest pose could miss its return
            moved: list[float] = []
            engine.subscribe(lambda pose: moved.append(
                math.inf if pose.root_m is None
                else float(np.hypot(*(pose.root_m[0] - start)[:2]))))
            _wait(lambda: bool(moved) and math.isfinite(moved[-1]) and moved[-1] > 0.5, 15.0,
                  "the avatar to walk half a metre")
            clicked = len(moved)
            page.get_by_role("button", name="Reset position").click()
            _wait(lambda: min(moved[clicked:], default=math.inf) < 0.3, 5.0,
                  "the avatar back where it started")
            browser.close()
    finally:
        session.stop()
    assert not [t for t in threading.enumerate() if t.name.startswith("margtrack-live")]
