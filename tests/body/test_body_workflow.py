"""process_body: simulated walks against their commanded angles, bad input, the files it writes.

The simulation (margtrack.live.simulator) commands clinical joint angles, so the workflow's
angles have a truth; OpenSim itself reads the .sto; the x-IMU3 walk is compared with the
devices' own orientation estimates (the benchmark's route).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from body_sim import (
    RATE_HZ,
    pelvis_forward_axis,
    recordings,
    simulation,
    truth_deg,
    without_samples,
)

from margtrack import body
from margtrack import quaternion as quat
from margtrack.body.outputs import OUTPUT_FILES
from margtrack.estimator.flags import Flag


@pytest.fixture(scope="module")
def sim():
    return simulation()


@pytest.fixture(scope="module")
def recs(sim):
    return recordings(sim)


@pytest.fixture(scope="module")
def north(recs):
    return body.process_body(recs, heading="north")


def _rms_against_truth(sim, result) -> dict[str, np.ndarray]:
    truth = truth_deg(sim, result.t_s)
    return {j: np.sqrt(np.mean((result.angles.degrees(j) - truth[j]) ** 2, axis=0))
            for j in result.angles.names}


def test_simulated_walk_gives_the_commanded_joint_angles(sim, north) -> None:
    # knee flexion swings 59 deg, hip flexion 50 deg: errors are the filter's, < 1.5 deg
    rms = _rms_against_truth(sim, north)
    assert set(rms) == {f"{s}_{j}" for s in ("left", "right") for j in ("hip", "knee", "ankle")}
    for joint, err in rms.items():
        assert err.max() < 1.5, (joint, err)
    assert north.calibration.spread_deg.max() < 1.0  # standing still in the pose
    assert north.rate_hz == pytest.approx(RATE_HZ)
    rom = {(j, c): hi - lo for j, c, lo, hi in north.range_of_motion()}
    assert rom[("left_knee", "flexion")] == pytest.approx(54.0, abs=6.0)  # 2 x 27 deg amplitude


def test_pelvis_heading_finds_the_facing_direction(sim, recs, north) -> None:
    result = body.process_body(recs, heading="pelvis", forward_axis=pelvis_forward_axis(sim))
    assert abs(result.calibration.facing_deg) < 3.0  # the simulated person faces north
    for err in _rms_against_truth(sim, result).values():
        assert err.max() < 2.5
    reversed_axis = body.process_body(recs, heading="pelvis",
                                      forward_axis=-pelvis_forward_axis(sim))
    assert abs(abs(reversed_axis.calibration.facing_deg) - 180.0) < 3.0
    assert any("bend backwards" in n for n in reversed_axis.notes)
    assert not any("bend backwards" in n for n in north.notes)


def test_a_map_renames_sensors_and_leaves_others_out(recs, north) -> None:
    renamed = {f"imu_{i}": replace(r, name=f"imu_{i}") for i, r in enumerate(recs.values())}
    mapping = {f"imu_{i}": seg for i, seg in enumerate(recs)}
    extra = {**renamed, "spare": next(iter(renamed.values()))}
    result = body.process_body(extra, mapping, heading="north")
    np.testing.assert_array_equal(result.angles.angles_rad, north.angles.angles_rad)
    assert "spare: not in the map, left out" in result.notes
    with pytest.raises(ValueError, match=r"'imu_0'.*not segment names.*--map.*pelvis, trunk"):
        body.process_body(renamed)
    with pytest.raises(ValueError, match=r"'knee_cap'.*not a segment; valid segments: pelvis"):
        body.process_body(renamed, {**mapping, "imu_0": "knee_cap"})
    with pytest.raises(ValueError, match=r"'imu_9'.*does not have; its sensors: imu_0"):
        body.process_body(renamed, {**mapping, "imu_9": "head"})


def test_read_body_map(tmp_path: Path) -> None:
    good = tmp_path / "body.toml"
    good.write_text('height_m = 1.8\n[sensors]\n"IMU 1" = "pelvis"\nb = "femur_r_imu"\n'
                    'c = "Right Lower Leg"\n[pelvis]\nforward_axis = [0, 0, -2]\n')
    m = body.read_body_map(good)
    assert dict(m.sensors) == {"IMU 1": "pelvis", "b": "right_thigh", "c": "right_shank"}
    np.testing.assert_array_equal(m.forward_axis, [0.0, 0.0, -1.0])
    assert m.height_m == 1.8
    cases = {
        'sensors = 3\n': "needs a \\[sensors\\] table",
        '[sensors]\na = "pelvis"\nb = "pelvis"\n': "'a' and 'b' are both mapped to pelvis",
        '[sensors]\na = "pelvis"\nwidth = 2\n': "needs a \\[sensors\\] table",
        '[sensors]\na = "pelvis"\n[extra]\n': "unknown key\\(s\\) extra",
        '[sensors]\na = "pelvis"\n[pelvis]\nforward_axis = "-w"\n': "a sensor axis is one of",
        '[sensors\n': "not valid TOML",
        '[sensors]\n': "lists no sensor",
        'height_m = 9\n[sensors]\na = "pelvis"\n': "height_m must be a body height",
    }
    for i, (text, message) in enumerate(cases.items()):
        bad = tmp_path / f"bad{i}.toml"
        bad.write_text(text)
        with pytest.raises(ValueError, match=message) as info:
            body.read_body_map(bad)
        assert str(bad) in str(info.value)
    with pytest.raises(FileNotFoundError, match="no such map file"):
        body.read_body_map(tmp_path / "missing.toml")


def test_different_rates_and_durations_are_merged_onto_the_overlap(recs, north) -> None:
    mixed = dict(recs)
    shank = recs["left_shank"]
    half = np.arange(0, shank.n_samples, 2)  # 50 Hz
    mixed["left_shank"] = replace(shank, t=shank.t[half], gyr=shank.gyr[half],
                                  acc=shank.acc[half], mag=shank.mag[half])
    mixed["right_foot"] = recs["right_foot"].slice(None, -150)  # 1.5 s shorter
    result = body.process_body(mixed, heading="north")
    assert result.rate_hz == pytest.approx(50.0)  # the slowest sensor's rate
    assert result.t_s[-1] <= mixed["right_foot"].t[-1] + 1e-12
    assert any("right_foot (end); left out: pelvis 1.50 s" in n for n in result.notes)
    assert any("merged onto 50 Hz" in n for n in result.notes)
    ref = north.angles.degrees("left_knee")[::2][: result.t_s.size, 0]
    diff = result.angles.degrees("left_knee")[:, 0] - ref
    assert np.sqrt(np.mean(diff**2)) < 1.0  # same motion, a coarser rate for one sensor


def test_unsynchronised_clocks_are_refused_with_the_fix(recs) -> None:
    shifted = dict(recs)
    pelvis = recs["pelvis"]
    shifted["pelvis"] = replace(pelvis, t=pelvis.t + 1000.0)
    with pytest.raises(ValueError, match=r"no common time span \(pelvis 1000.*--align-start"):
        body.process_body(shifted, heading="north")
    aligned = body.process_body(shifted, heading="north", align_start=True)
    assert aligned.t_s.size == pelvis.n_samples


def test_a_gap_flags_the_interpolated_frames(recs) -> None:
    gapped = dict(recs, right_thigh=without_samples(recs["right_thigh"], 5.0, 5.5))
    result = body.process_body(gapped, heading="north")
    col = result.skeleton.names.index("right_thigh")
    gap = (result.frame_flags[:, col] & int(Flag.GAP)) != 0
    assert gap.sum() == pytest.approx(0.5 * RATE_HZ, abs=2)
    assert np.all((result.t_s[gap] > 4.98) & (result.t_s[gap] < 5.51))
    others = np.delete(result.frame_flags, col, axis=1)
    assert not np.any(others & int(Flag.GAP))
    assert result.sensors[col].gap_frames == gap.sum()


def test_dead_magnetometer_is_flagged_and_pelvis_heading_still_works(sim, recs) -> None:
    dead = dict(recs, left_shank=replace(recs["left_shank"],
                                         mag=np.zeros_like(recs["left_shank"].mag)))
    with pytest.raises(ValueError, match=r"left_shank has none that works.*--heading pelvis"):
        body.process_body(dead, heading="north")
    axis = pelvis_forward_axis(sim)
    result = body.process_body(dead, heading="pelvis", forward_axis=axis, pose_window=(0.5, 1.5))
    normal = body.process_body(recs, heading="pelvis", forward_axis=axis, pose_window=(0.5, 1.5))
    report = {r.sensor: r for r in result.sensors}
    assert report["left_shank"].mag_dead and report["left_shank"].flag_counts["MAG_IGNORED"] > 700
    assert not report["right_shank"].mag_dead
    assert any("left_shank: magnetometer unusable" in n for n in result.notes)
    # the other sensors are untouched: the right side's angles are the same
    for joint in ("right_hip", "right_knee", "right_ankle", "left_hip"):
        np.testing.assert_allclose(result.angles.degrees(joint), normal.angles.degrees(joint),
                                   atol=1e-9)


def test_pose_window_errors_name_the_fix(recs) -> None:
    moving = body.process_body(recs, heading="north", pose_window=(0.2, 1.2))
    assert moving.window == slice(20, 121)  # 0.20 s to 1.20 s inclusive at 100 Hz
    with pytest.raises(ValueError, match=r"calibration on 3\.00-5\.00 s: sensor .* turned "
                       r".*--pose-window"):
        body.process_body(recs, heading="north", pose_window=(3.0, 5.0))
    with pytest.raises(ValueError, match=r"holds no frame; the recording spans 0-7\.99 s"):
        body.process_body(recs, heading="north", pose_window=(20.0, 21.0))
    with pytest.raises(ValueError, match=r"need 0 <= START < END"):
        body.process_body(recs, heading="north", pose_window=(2.0, 1.0))
    walking = recordings(simulation(still_s=0.0), n=300)
    with pytest.raises(ValueError, match=r"no still 1 s found.*--pose-window START,END"):
        body.process_body(walking, heading="north")


def test_units_method_and_heading_errors(recs) -> None:
    from margtrack.units import UnitError

    deg = dict(recs, left_foot=replace(recs["left_foot"], gyr=np.degrees(recs["left_foot"].gyr)))
    with pytest.raises(UnitError, match=r"sensor left_foot: .*deg/s"):
        body.process_body(deg, heading="north")
    with pytest.raises(ValueError, match=r"unknown method 'nope'"):
        body.process_body(recs, method="nope")
    with pytest.raises(ValueError, match=r"unknown parameter 'gian'"):
        body.process_body(recs, params=["gian=2"])
    with pytest.raises(ValueError, match=r"heading must be 'pelvis' or 'north'"):
        body.process_body(recs, heading="south")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"leave it out with heading 'north'"):
        body.process_body(recs, heading="north", forward_axis="-z")


def test_segments_that_form_no_chain_or_no_joint_are_refused(recs) -> None:
    with pytest.raises(ValueError, match=r"left_shank needs left_thigh"):
        body.process_body({k: recs[k] for k in ("pelvis", "left_shank", "left_foot")})
    with pytest.raises(ValueError, match=r"form no joint"):
        body.process_body({"pelvis": recs["pelvis"]})
    with pytest.raises(ValueError, match=r"no sensors"):
        body.process_body({})


@pytest.mark.parametrize("preset", ["lower", "full", "right_arm", "left_leg"])
def test_skeleton_from_segments_equals_the_presets(preset: str) -> None:
    ref = body.Skeleton.from_height(1.6, preset, "NED")
    aliases = {"right_shank": "right_lower_leg", "left_thigh": "Left Upper Leg"}
    shuffled = [aliases.get(n, n) for n in reversed(ref.names)]  # any order, aliases
    got = body.Skeleton.from_segments(shuffled, 1.6, "NED")
    assert got.names == ref.names
    np.testing.assert_array_equal(got.parents, ref.parents)
    np.testing.assert_allclose(got.offsets_m, ref.offsets_m, atol=1e-15)
    np.testing.assert_allclose(got.ends_m, ref.ends_m, atol=1e-15)
    np.testing.assert_allclose(got.root_position_m, ref.root_position_m, atol=1e-15)


def test_read_body_reads_segment_files_and_skips_the_rest(recs, tmp_path: Path) -> None:
    from margtrack import io

    for name in ("pelvis", "left_thigh"):
        io.write(recs[name], tmp_path / f"{name}.h5")
    (tmp_path / "notes.txt").write_text("recorded on Monday\n")  # not data: never read
    skipped: list[str] = []
    got = body.read_body(tmp_path, skipped=skipped)
    assert list(got) == ["left_thigh", "pelvis"]
    np.testing.assert_array_equal(got["pelvis"].gyr, recs["pelvis"].gyr)
    assert skipped == ["notes.txt: not a segment name (list it in a map, --map, to use it), "
                       "not read"]
    only = body.read_body(tmp_path, body.BodyMap({"pelvis": "pelvis"}), skipped := [])
    assert list(only) == ["pelvis"] and len(skipped) == 2
    with pytest.raises(ValueError, match=r"'imu_1'.*does not have; its sensors: left_thigh"):
        body.read_body(tmp_path, body.BodyMap({"imu_1": "pelvis"}))


def test_read_body_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"holds no sensor recordings.*--map body.toml"):
        body.read_body(tmp_path)
    (tmp_path / "notes.md").write_text("not a sensor")
    with pytest.raises(ValueError, match=r"holds no sensor recordings"):
        body.read_body(tmp_path)
    with pytest.raises(FileNotFoundError, match="no such file or folder"):
        body.read_body(tmp_path / "nope")


def test_write_refuses_existing_files_and_is_atomic(north, tmp_path: Path) -> None:
    out = tmp_path / "out"
    paths = north.write(out)
    # the simulated walk in place has no heel strikes: no gait cycle to draw
    expected = sorted(set(OUTPUT_FILES.values()) - {"gait_cycles.png"})
    assert not any(g.n_cycles for g in north.gait.values())
    assert sorted(p.name for p in paths.values()) == expected
    t, names, deg = body.read_joint_angles_csv(paths["angles"])
    np.testing.assert_allclose(deg[:, names.index("left_knee_flexion")],
                               north.angles.degrees("left_knee")[:, 0], atol=1e-7)
    assert t[0] == 0.0
    flags = np.loadtxt(paths["flags"], delimiter=",", skiprows=1)
    np.testing.assert_array_equal(flags[:, 1:], north.frame_flags)
    assert paths["plot"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    before = paths["angles"].stat().st_mtime_ns
    with pytest.raises(FileExistsError, match=r"joint_angles.csv.*kept; pass --force"):
        north.write(out)
    assert paths["angles"].stat().st_mtime_ns == before
    (out / "gait_cycles.png").write_bytes(b"a former run's figure")
    north.write(out, force=True)
    assert sorted(p.name for p in out.iterdir()) == expected  # no temp, no stale figure
    recording = tmp_path / "rec"
    recording.mkdir()
    with pytest.raises(ValueError, match="inside the input"):
        north.write(recording / "out", inputs=[recording])
    with pytest.raises(FileNotFoundError, match="does not exist"):
        north.write(tmp_path / "a" / "b")
    with pytest.raises(ValueError, match="the BVH unit must be one of cm, m, got 'mm'"):
        north.write(tmp_path / "c", bvh_unit="mm")
    assert not (tmp_path / "c").exists()  # refused before anything is written


def test_opensim_reads_the_sto(north, tmp_path: Path) -> None:
    opensim = pytest.importorskip("opensim", reason="OpenSim (pip install opensim) reads .sto")
    path = north.write(tmp_path / "out")["sto"]
    table = opensim.TimeSeriesTableQuaternion(str(path))
    labels = list(table.getColumnLabels())
    assert labels == ["pelvis_imu", "femur_l_imu", "tibia_l_imu", "calcn_l_imu",
                      "femur_r_imu", "tibia_r_imu", "calcn_r_imu"]
    assert table.getNumRows() == north.t_s.size
    np.testing.assert_allclose(list(table.getIndependentColumn()), north.t_rel_s, atol=1e-8)
    assert float(table.getTableMetaDataAsString("DataRate")) == pytest.approx(RATE_HZ)

    def row(i: int) -> np.ndarray:
        r = table.getRowAtIndex(i)
        return np.array([[r.getElt(0, j).get(k) for k in range(4)] for j in range(len(labels))])

    # OpenSim axes X forward (north), Y up, Z right (east): ENU (e, n, u) -> (n, u, e)
    c = quat.from_matrix(np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]]))
    for i in (0, north.t_s.size // 2, north.t_s.size - 1):
        expected = quat.multiply(quat.multiply(c, north.pose.q_segment[i]), quat.conjugate(c))
        np.testing.assert_allclose(row(i), expected, atol=2e-10)
    # in the reference pose facing north every segment is OpenSim's default pose (identity)
    mid = (north.window.start + north.window.stop) // 2
    angles = np.degrees(quat.angle_between(row(mid), quat.identity()))
    assert angles.max() < 1.0


def test_xio_walk_reproduces_the_device_quaternion_knee_peaks(xio_folder: Path) -> None:
    from margtrack.body.xio import read_xio_orientations

    result = body.process_body(body.read_body(xio_folder))  # robust, pelvis heading, -z
    t, names, q = read_xio_orientations(xio_folder, 50.0, device_frame="NWU", frame="ENU")
    sk = body.Skeleton.from_height(1.75, "lower", "ENU")
    q = q[:, sk.order(names)]
    window = body.still_window(t, q, 1.0, 2.0)
    cal = body.calibrate(sk, q[window], heading="pelvis", forward_axis=(0, 0, -1))
    device = body.joint_angles(sk, body.track(sk, cal, q).q_segment)
    for side in ("left", "right"):
        times, peaks = result.peaks(f"{side}_knee")
        flex = device.degrees(f"{side}_knee")[:, 0]
        assert times.size >= 8
        for s, value in zip(times, peaks, strict=True):
            near = np.abs((t - t[0]) - s) <= 0.1
            assert abs(flex[near].max() - value) < 4.0, (side, s, value)
    assert result.calibration.spread_deg.max() < 2.0


def test_xio_walk_no_mag_online_range_of_motion_spans_the_walk(xio_folder: Path) -> None:
    """Online --no-mag calibrates on the still end (every joint found only once it moved):
    the range of motion runs from when every joint was found, not from that end."""
    result = body.process_body(body.read_body(xio_folder), no_mag=True)
    settled = result.t_rel_s[result.valid_from]
    assert result.t_rel_s[result.window.start] > 10.0  # the pose at the end of the walk
    assert result.range_from_s == pytest.approx(settled) and settled < 5.0
    rom = {(j, c): hi - lo for j, c, lo, hi in result.range_of_motion()}
    _, peaks = result.peaks("left_knee")
    # the walk's knee flexion (swing peaks of 50-140 deg), not the still end's few degrees
    assert rom[("left_knee", "flexion")] >= peaks.max() > 50.0
    assert "range of motion from " + f"{settled:.2f} s" in "\n".join(result.summary())
