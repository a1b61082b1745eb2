"""The live page's BVH export carries the walking root (live/recording.py, viewer_panels.py):
read back with bvhio, its root walks where the live view's did, in the stated unit."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest

from margtrack.body.export_bvh import bvh_axes
from margtrack.live.avatars import identity_calibration
from margtrack.live.engine import Engine
from margtrack.live.protocol import iter_chunks
from margtrack.live.replay import ReplaySource
from margtrack.live.simulator import PeopleSimulation, SimulatorSource
from margtrack.live.viewer_panels import export_recording

bvhio = pytest.importorskip("bvhio", reason="bvhio (test extra) reads the BVH back")

SIM = PeopleSimulation(preset="lower", seed=3, still_s=2.0)


def _bvh_root_m(path, unit: str, frames) -> np.ndarray:
    """The BVH root joint's position at ``frames``, m in the earth frame (bvhio's reading
    undone by the stated unit and the BVH axes)."""
    hierarchy = bvhio.readAsHierarchy(str(path))
    root = next(j for j, _, _ in hierarchy.layout())
    assert root.Name == "pelvis"
    scale = {"cm": 100.0, "m": 1.0}[unit]
    out = []
    for f in frames:
        hierarchy.loadPose(int(f), recursive=True)
        out.append(bvh_axes(SIM.skeleton.frame).T @ np.array(root.PositionWorld) / scale)
    return np.array(out)


@pytest.fixture(scope="module")
def walk():
    """12 s of the simulated walk through an engine with the walking root, recorded."""
    source = SimulatorSource(SIM, speed=math.inf, duration_s=12.0)
    engine = Engine(source.info, "default", walking_root=True)
    engine.set_calibrations([dataclasses.replace(identity_calibration(SIM.skeleton),
                                                 offsets=SIM.mounting[0])])
    poses = []
    engine.subscribe(poses.append)
    engine.start_recording()
    for chunk in iter_chunks(source):
        engine.push([chunk])
    return engine, poses, engine.stop_recording()


@pytest.mark.parametrize("unit", ["cm", "m"])
def test_the_exported_root_walks_as_the_live_root_did(walk, tmp_path, unit) -> None:
    engine, poses, rec = walk
    bvh = export_recording(rec, tmp_path, "walk", bvh_unit=unit)[0]
    frames = np.arange(0, rec.n_frames, 40)
    bvh_root = _bvh_root_m(bvh, unit, frames)
    # every frame's root is the live root at that frame (bvhio reads in float32: 1e-5 m)
    np.testing.assert_allclose(bvh_root, rec.root_m[frames, 0], atol=1e-4, rtol=0)
    # the published poses carried the same roots
    at = {float(t): k for k, t in enumerate(rec.t_s)}
    for p in poses[::25]:
        np.testing.assert_array_equal(p.root_m, rec.root_m[at[p.t_s]])
    up = np.abs(bvh_axes(SIM.skeleton.frame)[1])
    start = engine.avatars.root_positions_m[0]
    live = poses[-1].root_m[0] - start
    live_m = float(np.linalg.norm(live - (live @ up) * up))
    exported = _bvh_root_m(bvh, unit, [at[poses[-1].t_s]])[0] - start
    exported_m = float(np.linalg.norm(exported - (exported @ up) * up))
    assert live_m > 1.0  # the avatar walked (the simulation walks on the spot)
    assert exported_m == pytest.approx(live_m, abs=1e-4)


def test_cm_and_m_files_differ_by_the_unit_and_a_fixed_root_stays(walk, tmp_path) -> None:
    _, _, rec = walk
    cm = export_recording(rec, tmp_path, "a", bvh_unit="cm")[0]
    m = export_recording(rec, tmp_path, "b", bvh_unit="m")[0]
    first = [float(v) for v in cm.read_text().split("MOTION")[1].splitlines()[3].split()[:3]]
    again = [float(v) for v in m.read_text().split("MOTION")[1].splitlines()[3].split()[:3]]
    np.testing.assert_allclose(first, 100.0 * np.array(again), rtol=1e-6)
    fixed = dataclasses.replace(rec, root_m=None)
    still = _bvh_root_m(export_recording(fixed, tmp_path, "c")[0], "cm", [0, rec.n_frames - 1])
    np.testing.assert_allclose(still, np.tile(rec.avatars.root_positions_m[0], (2, 1)),
                               atol=1e-5)
    with pytest.raises(ValueError, match="cm, m"):
        export_recording(rec, tmp_path, "d", bvh_unit="mm")


def test_the_page_exports_the_walking_root_in_the_chosen_unit(tmp_path) -> None:
    pytest.importorskip("viser", reason="the live page needs viser (pip install viser)")
    from margtrack.live.viewer_session import run_live

    chunks = list(iter_chunks(SimulatorSource(SIM, speed=math.inf, duration_s=12.0)))
    t = np.concatenate([c.t_s for c in chunks])
    cat = [np.concatenate([getattr(c, k) for c in chunks], axis=1) for k in ("gyr", "acc", "mag")]
    source = ReplaySource(t, *cat, SIM.sensor_names, speed=4.0)
    session = run_live(source, "default", port=0, block=False, out_dir=tmp_path,
                       calibrate_at_start=True, walking_root=True, bvh_unit="m")
    try:
        viewer, engine = session.viewer, session.engine
        viewer.toggle_recording()  # "Start recording"
        end = time.perf_counter() + 30.0
        while not engine.wait(0.1):
            assert time.perf_counter() < end, "the replay did not end"
        viewer.toggle_recording()  # "Stop recording and export"
        assert viewer.message == "exported 4 files (BVH in m)", viewer.message
        bvh = next(p for p in viewer.exported if p.suffix == ".bvh")
        lines = bvh.read_text().split("MOTION")[1].splitlines()
        n = int(lines[1].split()[1])
        root = _bvh_root_m(bvh, "m", [n - 1])[0]
        live = engine.latest.root_m[0]
        # the last pose is at most 3 frames (0.03 s) before the last recorded frame
        assert np.linalg.norm(root - live) < 0.05
        assert np.linalg.norm((root - engine.avatars.root_positions_m[0])[:2]) > 1.0
    finally:
        session.stop()


def test_cli_states_the_bvh_unit_and_refuses_another(tmp_path) -> None:
    pytest.importorskip("viser", reason="the live page needs viser (pip install viser)")
    from typer.testing import CliRunner

    from margtrack.cli import app

    args = ["live", "--demo", "--preset", "lower", "--port", "0", "--speed", "10",
            "--duration", "1", "--out", str(tmp_path)]
    for unit, text in (("m", "lengths in m (--bvh-unit m): import into Blender with scale 1"),
                       (None, "lengths in cm (--bvh-unit cm, the default): import into "
                              "Blender with scale 0.01")):
        result = CliRunner().invoke(app, args + ([] if unit is None else ["--bvh-unit", unit]))
        assert result.exit_code == 0, result.output
        assert text in " ".join(result.output.split())
    wrong = CliRunner().invoke(app, [*args, "--bvh-unit", "mm"])
    assert wrong.exit_code == 2 and "--bvh-unit must be cm or m, got 'mm'" in wrong.output
