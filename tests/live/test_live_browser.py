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
from margtrack.filters.complementary import BachmannParams
from margtrack.live.simulator import PeopleSimulation, SimulatorSource

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


def test_live_view_connects_renders_the_avatar_and_retunes_the_filter(tmp_path):
    if not CHROMIUM.is_file():
        pytest.skip("Debian's chromium is not installed (apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api",
                                   reason="the playwright package is not installed")
    pytest.importorskip("viser", reason="the live view needs viser (pip install viser)")
    from margtrack.live.viewer import run_live

    source = SimulatorSource(PeopleSimulation(seed=1), speed=1.0)
    session = run_live(source, "bachmann", port=0, block=False, calibrate_at_start=True,
                       out_dir=tmp_path)
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1100, "height": 750})
            page.goto(session.url)
            page.get_by_text("Connected").wait_for(timeout=15000)
            counter = page.get_by_text(re.compile(r"poses shown: \d+"))
            counter.wait_for(timeout=15000)

            def shown() -> int:
                return int(re.search(r"poses shown: (\d+)", counter.inner_text()).group(1))

            _wait(lambda: shown() >= 25, 15.0, "25 poses shown on the page")  # 1 s at 25 Hz
            assert len(session.server.get_clients()) == 1
            assert session.engine.stats().poses_published >= 25

            # the avatar is drawn: pixels of the left (blue) and right (red) bones in the scene
            # (left of the panel, below the WebGL notice); lines are lit and anti-aliased, so
            # colours are told apart by which channel dominates. A frame caught while viser
            # swaps geometry can be pale: up to five screenshots are taken.
            import matplotlib.image

            shot = tmp_path / "live.png"
            for _ in range(5):
                page.screenshot(path=str(shot))
                pixels = matplotlib.image.imread(shot)[..., :3]  # floats in [0, 1]
                r, g, b = (pixels[160:, :700, k] for k in range(3))
                blue = int(np.sum(b - np.maximum(r, g) > 0.12))
                red = int(np.sum(r - np.maximum(g, b) > 0.12))
                if blue > 200 and red > 200:
                    break
                time.sleep(0.3)
            Path("/tmp/margtrack_live_browser.png").write_bytes(shot.read_bytes())
            assert pixels.std() > 0.05, "blank page"
            assert blue > 200 and red > 200, f"avatar not drawn: {blue} blue, {red} red pixels"

            # the control is labelled by the parameter's declaration: name and unit
            label = next(p.label for p in specs(BachmannParams) if p.name == "gain")
            assert label.startswith("gain [")
            gain = page.get_by_label(label, exact=True)
            assert float(gain.input_value()) == pytest.approx(BachmannParams().gain)
            gain.fill("0.5")
            gain.press("Enter")
            _wait(lambda: session.engine.active_params.gain == 0.5, 5.0,
                  "the engine's filter to run with gain 0.5")
            frames = session.engine.stats().frames
            _wait(lambda: session.engine.stats().frames > frames, 2.0, "more frames")
            browser.close()
    finally:
        session.stop()
    assert session.engine.active_params.gain == 0.5
    assert math.isfinite(session.engine.stats().latency_p50_s)
    assert not [t for t in threading.enumerate() if t.name.startswith("margtrack-live")]
    assert np.isfinite(session.engine.latest.joints_m).all()
