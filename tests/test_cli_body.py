"""``margtrack body``: the x-IMU3 walk, per-sensor files with a map, a live recording, bad input."""

from __future__ import annotations

import re
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from margtrack import io
from margtrack.body.outputs import OUTPUT_FILES
from margtrack.cli import app
from margtrack.live.simulator import PeopleSimulation
from margtrack.recording import Recording

runner = CliRunner()


def _invoke(*args: str | Path):
    return runner.invoke(app, ["body", *map(str, args)])


@pytest.fixture(scope="module")
def walk() -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """A simulated 7-sensor walk (lower body, 100 Hz, 6 s, 2 s standing first)."""
    sim = PeopleSimulation(preset="lower", motion="walk", rate_hz=100.0, still_s=2.0, seed=5)
    t, gyr, acc, mag = sim.signals(0, 600)
    return t, {n: (gyr[s], acc[s], mag[s]) for s, n in enumerate(sim.skeleton.names)}


def _files(folder: Path, walk, names: dict[str, str], suffix: str) -> Path:
    folder.mkdir()
    t, signals = walk
    for segment, sensor in names.items():
        g, a, m = signals[segment]
        io.write(Recording(t=t, gyr=g, acc=a, mag=m, name=sensor), folder / f"{sensor}{suffix}")
    return folder


def _knee_peaks(output: str, side: str) -> list[float]:
    line = next(x for x in output.splitlines()
                if x.strip().startswith(f"{side}_knee ") and " s;" in x)
    return [float(v) for v in re.findall(r"(\d+) at [\d.]+ s", line)]


def test_xio_walk_end_to_end(xio_folder: Path, tmp_path: Path) -> None:
    out = tmp_path / "xio"
    result = _invoke(xio_folder, "-o", out)
    assert result.exit_code == 0, result.output
    assert "calibration on 0.00-0.98 s" in result.output
    assert re.search(r"left_knee\s+flexion\s+-?\d+\.\d\s+1[23]\d\.\d", result.output)
    # the benchmark's device-quaternion peaks: left 63, 55, ..., 134 (the high-knee raise)
    left = _knee_peaks(result.output, "left")
    assert abs(max(left) - 134.0) < 4.0 and abs(left[0] - 63.0) < 4.0
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES.values())
    # gait cycles per side and the pelvis path, with the BVH's unit and Blender's scale
    for side in ("left", "right"):
        line = re.search(rf"^  {side}\s+(\d+) cycles \({side}_shank\): stride .* cadence "
                         r"([\d.]+) ± [\d.]+ steps/min, stance ([\d.]+) ± [\d.]+ %$",
                         result.output, re.M)
        assert line, result.output
        assert int(line[1]) >= 2 and 80 < float(line[2]) < 140 and 50 < float(line[3]) < 75
    assert re.search(r"pelvis path from the foot contacts \(east, north; m\): start "
                     r"\(0\.00, 0\.00\), end .* m walked", result.output)
    assert ("motion.bvh lengths in cm (--bvh-unit cm, the default): import it into Blender "
            "with scale 0.01") in result.output
    cycles = (out / "gait_cycles.csv").read_text().splitlines()
    assert cycles[0] == ("side,cycle,start (s),toe_off (s),end (s),duration (s),stance (%),"
                         "cadence (steps/min)") and len(cycles) >= 5
    again = _invoke(xio_folder, "-o", out)
    assert again.exit_code == 2
    assert "already holds" in again.output and "--force" in again.output
    forced = _invoke(xio_folder, "-o", out, "--force", "--heading", "north")
    assert forced.exit_code == 0, forced.output
    assert "faced magnetic north" in forced.output


def test_per_sensor_files_with_a_map(walk, tmp_path: Path) -> None:
    names = {seg: f"imu_{i}" for i, seg in enumerate(walk[1])}
    folder = _files(tmp_path / "rec", walk, names, ".csv")
    (folder / "README.txt").write_text("per-sensor CSV files of a lab recording\n")
    result = _invoke(folder, "-o", tmp_path / "out")
    assert result.exit_code == 2
    assert "not segment names" in result.output and "--map" in result.output
    body_map = tmp_path / "body.toml"
    body_map.write_text("[sensors]\n" + "".join(f'{s} = "{seg}"\n' for seg, s in names.items()))
    pose = ["--heading", "north", "--pose-window", "0.5,1.5"]
    result = _invoke(folder, "-o", tmp_path / "out", "--map", body_map, *pose)
    assert result.exit_code == 0, result.output
    assert "note: README.txt: not in the map, not read" in result.output
    # the simulated knee swings 32 +- 27 deg: peaks near 59 deg
    assert all(abs(p - 59.0) < 3.0 for p in _knee_peaks(result.output, "left")[1:])
    sto = (tmp_path / "out" / "orientations.sto").read_text().splitlines()
    assert sto[5].split("\t") == ["time", "pelvis_imu", "femur_l_imu", "tibia_l_imu",
                                  "calcn_l_imu", "femur_r_imu", "tibia_r_imu", "calcn_r_imu"]
    wrong = tmp_path / "wrong.toml"
    wrong.write_text('[sensors]\nimu_0 = "pelvis"\nimu_1 = "kneecap"\n')
    result = _invoke(folder, "-o", tmp_path / "out2", "--map", wrong)
    assert result.exit_code == 2 and "'kneecap', which is not a segment" in result.output
    assert "valid segments: pelvis" in result.output
    inside = _invoke(folder, "-o", folder / "out", "--map", body_map)
    assert inside.exit_code == 2 and "inside the input" in inside.output


def test_bvh_unit_and_fewer_than_two_gait_cycles(walk, tmp_path: Path) -> None:
    # the simulated walk in place swings its legs sinusoidally: no heel strike and toe off
    # pattern of a real gait, so no cycle; that is a message, and the rest is written
    bvhio = pytest.importorskip("bvhio", reason="bvhio (dev extra) reads the BVH back")
    folder = _files(tmp_path / "rec", walk, {seg: seg for seg in walk[1]}, ".h5")
    roots = {}
    for unit in ("cm", "m"):
        out = tmp_path / unit
        result = _invoke(folder, "-o", out, "--heading", "north", "--bvh-unit", unit)
        assert result.exit_code == 0, result.output
        assert "fewer than two, so no cycle average for this side" in result.output
        scale = "0.01" if unit == "cm" else "1"
        assert f"motion.bvh lengths in {unit} (--bvh-unit {unit}" in result.output
        assert f"import it into Blender with scale {scale}" in result.output
        assert not (out / "gait_cycles.png").exists()
        assert (out / "gait_cycles.csv").read_text().count("\n") == 1  # the header
        hierarchy = bvhio.readAsHierarchy(str(out / "motion.bvh"))
        pelvis = next(j for j, _, _ in hierarchy.layout() if j.Name == "pelvis")
        got = []
        for f in (0, 300, 599):
            hierarchy.loadPose(f, recursive=True)
            got.append(np.array(pelvis.PositionWorld, dtype=np.float64))
        roots[unit] = np.array(got)
        table = np.loadtxt(out / "pelvis_position.csv", delimiter=",", skiprows=1)
        assert table.shape == (600, 6)
    np.testing.assert_allclose(roots["cm"], 100.0 * roots["m"], rtol=1e-6, atol=1e-4)
    assert 0.8 < roots["m"][0, 1] < 1.0  # hip height, Y up, in m


def test_live_recording_input(walk, tmp_path: Path) -> None:
    live = pytest.importorskip("margtrack.io.live_hdf5",
                               reason="the live recording format (helper B3) is not present")
    t, signals = walk
    names = tuple(signals)
    raw = live.RawLiveRecording(
        sensor_names=names, t_s=t, batch_frames=np.array([t.size]),
        gyr=np.stack([signals[n][0] for n in names]),
        acc=np.stack([signals[n][1] for n in names]),
        mag=np.stack([signals[n][2] for n in names]),
        held=np.zeros((len(names), t.size), bool), events=(), frame="ENU",
        method="robust", params={})
    path = tmp_path / "session.h5"
    live.write_live_recording(raw, path)
    result = _invoke(path, "-o", tmp_path / "out", "--heading", "north")
    assert result.exit_code == 0, result.output
    assert f"body: 7 sensors, {t.size} frames at 100 Hz" in result.output


def test_bad_input_is_refused_with_the_fix(walk, tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    result = _invoke(empty, "-o", tmp_path / "out")
    assert result.exit_code == 2 and "holds no sensor recordings" in result.output
    result = _invoke(empty, "-o", tmp_path / "out", "--heading", "south")
    assert result.exit_code == 2 and "--heading must be 'pelvis' or 'north'" in result.output
    result = _invoke(empty, "-o", tmp_path / "out", "--pose-window", "1;2")
    assert result.exit_code == 2 and "--pose-window takes START,END" in result.output
    result = _invoke(empty, "-o", tmp_path / "out", "--bvh-unit", "mm")
    assert result.exit_code == 2 and "--bvh-unit must be cm or m, got 'mm'" in result.output
    result = _invoke(empty, "-o", tmp_path / "missing" / "out")
    assert result.exit_code == 2 and "does not exist" in result.output
    assert not (tmp_path / "out").exists()  # nothing written on refusal
    folder = _files(tmp_path / "bad", walk, {"pelvis": "pelvis", "left_thigh": "left_thigh"},
                    ".h5")
    with h5py.File(folder / "left_thigh.h5", "r+") as f:
        f["t"][10] = f["t"][9]  # a repeated timestamp (a reset clock)
    result = _invoke(folder, "-o", tmp_path / "out")
    assert result.exit_code == 2
    assert "left_thigh.h5" in result.output and "duplicate timestamp at sample 10" in result.output
    (folder / "left_thigh.h5").unlink()
    data = (folder / "pelvis.h5").read_bytes()
    (folder / "pelvis.h5").write_bytes(data[: len(data) // 2])  # truncated
    result = _invoke(folder, "-o", tmp_path / "out")
    assert result.exit_code == 2 and "pelvis.h5 is not a readable HDF5 file" in result.output


def test_units_are_checked_per_sensor(walk, tmp_path: Path) -> None:
    t, signals = walk
    folder = tmp_path / "deg"
    folder.mkdir()
    for seg, (g, a, m) in signals.items():
        io.write(Recording(t=t, gyr=np.degrees(g), acc=a, mag=m, name=seg), folder / f"{seg}.h5")
    result = _invoke(folder, "-o", tmp_path / "out")
    assert result.exit_code == 2 and "--gyr-unit deg/s" in result.output
    ok = _invoke(folder, "-o", tmp_path / "out", "--gyr-unit", "deg/s", "--heading", "north")
    assert ok.exit_code == 0, ok.output


def _table(folder: Path) -> tuple[list[str], np.ndarray]:
    path = folder / "joint_angles.csv"
    return (path.read_text().splitlines()[0].split(","),
            np.loadtxt(path, delimiter=",", skiprows=1))


def test_xio_walk_without_magnetometers(xio_folder: Path, tmp_path: Path) -> None:
    ref = _invoke(xio_folder, "-o", tmp_path / "mag")
    assert ref.exit_code == 0, ref.output
    names, with_mag = _table(tmp_path / "mag")
    chain = [("left_hip", "pelvis", "left_upper_leg"),
             ("left_knee", "left_upper_leg", "left_lower_leg"),
             ("left_ankle", "left_lower_leg", "left_foot"),
             ("right_hip", "pelvis", "right_upper_leg"),
             ("right_knee", "right_upper_leg", "right_lower_leg"),
             ("right_ankle", "right_lower_leg", "right_foot")]
    arm = r"\((-?\d+ ± \d+, ){2}-?\d+ ± \d+\)"
    for extra in ((), ("--offline",)):
        out = tmp_path / f"no_mag{'_offline' if extra else ''}"
        result = _invoke(xio_folder, "-o", out, "--no-mag", *extra)
        assert result.exit_code == 0, result.output
        kind = "offline" if extra else "online"
        assert f"constrained joints ({kind}; no magnetometer): lever arms" in result.output
        lines = result.output.splitlines()
        for joint, parent, child in chain:  # parents first, each with both lever arms
            k = next(i for i, x in enumerate(lines) if x.startswith(f"  {joint} "))
            assert re.fullmatch(rf"  {joint}\s+{parent}\s+{arm}", lines[k]), lines[k]
            assert re.fullmatch(rf"\s+{child}\s+{arm}", lines[k + 1]), lines[k + 1]
            assert re.fullmatch(r"\s+fit residual [\d.]+ m/s² over \d+ samples", lines[k + 2])
        assert sum(bool(re.search(r"\d\s+not used  ", x)) for x in lines) == 7  # sensor rows
        assert "magnetometers not used (--no-mag)" in result.output
        got_names, angles = _table(out)
        assert got_names == names and angles.shape == with_mag.shape
        for side in ("left", "right"):
            col = names.index(f"{side}_knee_flexion (deg)")
            r = np.corrcoef(angles[:, col], with_mag[:, col])[0, 1]
            assert r > 0.9, (extra, side, r)  # measured 0.985-0.998
        if extra:  # the still start calibrates, as with magnetometers; flexion within a few deg
            assert "calibration on 0.00-0.98 s" in result.output
            col = names.index("left_knee_flexion (deg)")
            assert np.sqrt(np.mean((angles[:, col] - with_mag[:, col]) ** 2)) < 3.0  # 1.4


def test_no_mag_bad_input_is_refused_with_the_fix(walk, tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    result = _invoke(empty, "-o", tmp_path / "out", "--no-mag", "--heading", "north")
    assert result.exit_code == 2
    assert "--heading north needs the magnetometers, which --no-mag leaves out" in result.output
    result = _invoke(empty, "-o", tmp_path / "out", "--offline")
    assert result.exit_code == 2 and "give it with --no-mag" in result.output
    # the left thigh's sensor is missing: the shank has no joint to its parent to be tied by
    folder = _files(tmp_path / "no_thigh", walk, {"pelvis": "pelvis", "left_shank": "left_shank"},
                    ".h5")
    result = _invoke(folder, "-o", tmp_path / "out", "--no-mag")
    assert result.exit_code == 2
    assert "left_shank needs left_thigh" in result.output, result.output
    assert not (tmp_path / "out").exists()
