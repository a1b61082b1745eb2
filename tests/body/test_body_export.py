"""Exports: BVH read back by bvhio, OpenSim .sto and CSV round trips, stick-figure bones."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.body import (
    Skeleton,
    body_axes,
    bvh_axes,
    joint_angles,
    positions,
    read_joint_angles_csv,
    read_sto,
    write_bvh,
    write_joint_angles_csv,
    write_sto,
)
from margtrack.body.plot import bones, plot_stick_figures

H = 1.75


def motion(sk: Skeleton, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = rng.normal(scale=0.3, size=(n, len(sk), 3))
    return quat.from_rotvec(np.cumsum(steps, axis=0))


@pytest.mark.parametrize(("frame", "unit"), [("ENU", "cm"), ("NED", "m")])
def test_bvh_read_back_by_bvhio_reproduces_the_joint_positions(
    tmp_path: Path, frame: str, unit: str
) -> None:
    bvhio = pytest.importorskip("bvhio", reason="bvhio (dev extra) reads the BVH back")
    sk = Skeleton.from_height(H, "full", frame)
    n = 12
    q = motion(sk, n, 30)
    root = sk.root_position_m + np.linspace(0.0, 1.0, n)[:, None] * np.array([0.3, -0.2, 0.05])
    path = tmp_path / "motion.bvh"
    write_bvh(path, sk, q, 0.01, root, unit=unit)
    joints, _ = positions(sk, q, root)
    m = bvh_axes(frame)
    scale = {"cm": 100.0, "m": 1.0}[unit]
    hierarchy = bvhio.readAsHierarchy(str(path))
    nodes = {j.Name: j for j, _, _ in hierarchy.layout()}
    assert set(nodes) == set(sk.names)
    worst = 0.0
    for f in range(n):
        hierarchy.loadPose(f, recursive=True)
        for i, name in enumerate(sk.names):
            p_bvh = np.array(nodes[name].PositionWorld, dtype=np.float64) / scale
            worst = max(worst, float(np.abs(m.T @ p_bvh - joints[f, i]).max()))
    # bvhio computes in float32 (pyglm): ~1e-7 relative on ~2 m chains of 5 rotations
    assert worst < 1e-6


def test_bvh_layout(tmp_path: Path) -> None:
    sk = Skeleton.from_height(H, "lower", "ENU")
    q = quat.identity((3, len(sk)))
    q[:, sk.index("left_shank")] = quat.from_axis_angle(body_axes("ENU")[0], np.radians(-30.0))
    path = tmp_path / "lower.bvh"
    write_bvh(path, sk, q, 0.02)
    text = path.read_text().splitlines()
    assert text[0] == "HIERARCHY" and text[1] == "ROOT pelvis"
    assert text[3].split() == ["OFFSET", "0.00000000", "0.00000000", "0.00000000"]
    assert "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" in text[4]
    assert sum("CHANNELS 3 Zrotation Xrotation Yrotation" in line for line in text) == 6
    assert sum(line.strip() == "End Site" for line in text) == 2
    # right hip: 0.191 H / 2 to the right = towards -X (BVH X is west), in cm
    i = text.index("  JOINT right_thigh")
    offset = [float(v) for v in text[i + 2].split()[1:]]
    np.testing.assert_allclose(offset, [-0.0955 * H * 100, 0.0, 0.0], atol=1e-6)
    k = text.index("MOTION")
    assert text[k + 1:k + 3] == ["Frames: 3", "Frame Time: 0.02000000"]
    values = np.array([float(v) for v in text[k + 3].split()])
    assert values.size == 6 + 6 * 3
    np.testing.assert_allclose(values[:3], [0.0, 0.530 * H * 100, 0.0], atol=1e-6)  # Y up
    # depth-first order: pelvis, left_thigh, left_shank: -30 deg about east is +30 deg about
    # BVH X (west): Zrot Xrot Yrot = 0 30 0
    np.testing.assert_allclose(values[9:12], [0.0, 30.0, 0.0], atol=1e-9)


def test_bvh_rejects_bad_arguments(tmp_path: Path) -> None:
    sk = Skeleton.from_height(H, "right_arm")
    q = quat.identity((2, 3))
    with pytest.raises(ValueError, match="frame_time_s must be a finite number of seconds > 0"):
        write_bvh(tmp_path / "a.bvh", sk, q, 0.0)
    with pytest.raises(ValueError, match="unit must be one of cm, m"):
        write_bvh(tmp_path / "a.bvh", sk, q, 0.01, unit="mm")
    with pytest.raises(ValueError, match=r"shape \(N, S, 4\) for a motion"):
        write_bvh(tmp_path / "a.bvh", sk, q[0], 0.01)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_sto_round_trip_and_opensim_axes(tmp_path: Path, frame: str) -> None:
    sk = Skeleton.from_height(H, "lower", frame)
    q = motion(sk, 8, 31)
    t = 0.5 + np.arange(8) / 100.0
    write_sto(tmp_path / "earth.sto", sk, t, q, axes="earth", names="segment")
    header, labels, t_back, q_back = read_sto(tmp_path / "earth.sto")
    assert header == {"DataRate": "100.000000", "DataType": "Quaternion", "version": "3",
                      "OpenSimVersion": "4.5"}
    assert labels == list(sk.names)
    np.testing.assert_allclose(t_back, t, atol=1e-8)
    np.testing.assert_allclose(q_back, q, atol=1e-10)
    # OpenSim axes: facing east in the reference pose is a -90 deg turn about Y (up), and the
    # segment's X (forward) points along OpenSim's Z (east = the subject's right of north)
    up = body_axes(frame)[2]
    east = quat.identity((1, len(sk))) * 0 + quat.from_axis_angle(up, -np.pi / 2)
    write_sto(tmp_path / "os.sto", sk, [0.0], east)
    _, labels, _, q_os = read_sto(tmp_path / "os.sto")
    assert labels == ["pelvis_imu", "femur_l_imu", "tibia_l_imu", "calcn_l_imu",
                      "femur_r_imu", "tibia_r_imu", "calcn_r_imu"]
    np.testing.assert_allclose(quat.rotate(q_os[0], [1.0, 0.0, 0.0]),
                               np.tile([0.0, 0.0, 1.0], (len(sk), 1)), atol=1e-10)
    np.testing.assert_allclose(quat.rotate(q_os[0], [0.0, 1.0, 0.0]),
                               np.tile([0.0, 1.0, 0.0], (len(sk), 1)), atol=1e-10)
    with pytest.raises(ValueError, match="axes must be 'opensim' or 'earth'"):
        write_sto(tmp_path / "x.sto", sk, [0.0], east, axes="ned")


def test_joint_angle_csv_round_trip(tmp_path: Path) -> None:
    sk = Skeleton.from_height(H, "lower")
    q = motion(sk, 6, 32)
    angles = joint_angles(sk, q)
    t = np.arange(6) / 50.0
    write_joint_angles_csv(tmp_path / "angles.csv", t, angles)
    header = (tmp_path / "angles.csv").read_text().splitlines()[0].split(",")
    assert header[:3] == ["t (s)", "right_hip_flexion (deg)", "right_hip_abduction (deg)"]
    assert len(header) == 1 + 6 * 3
    t_back, names, deg = read_joint_angles_csv(tmp_path / "angles.csv")
    assert names == angles.columns()
    np.testing.assert_allclose(t_back, t, atol=1e-12)
    np.testing.assert_allclose(deg, np.degrees(angles.angles_rad.reshape(6, -1)), atol=1e-7)
    with pytest.raises(ValueError, match=r"t_s must have shape \(6,\)"):
        write_joint_angles_csv(tmp_path / "bad.csv", t[:5], angles)


def test_stick_figure_bones_and_png(tmp_path: Path) -> None:
    sk = Skeleton.from_height(H, "full")
    joints, ends = positions(sk, quat.identity((2, len(sk))))
    lines = bones(sk, joints, ends)
    assert lines.shape == (2, 2 * len(sk) - 1, 2, 3)
    # the right shoulder girdle: from the trunk's end (neck) to the right shoulder joint
    link = lines[0, len(sk) + sk.index("right_upper_arm") - 1]
    np.testing.assert_allclose(link[0], [0.0, 0.0, 0.818 * H], atol=1e-12)
    np.testing.assert_allclose(link[1], [0.1295 * H, 0.0, 0.818 * H], atol=1e-12)
    png = tmp_path / "sticks.png"
    plot_stick_figures(png, sk, joints, ends, [0, 1], labels=["a", "b"])
    import matplotlib.image

    image = matplotlib.image.imread(png)
    assert (image[..., :3].mean(axis=-1) < 0.9).mean() > 0.005  # something was drawn
    with pytest.raises(ValueError, match="frames must be indices in"):
        plot_stick_figures(png, sk, joints, ends, [5])
