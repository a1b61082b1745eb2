"""The page's parts without a browser: the avatar's solids, camera framing, panel text."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from margtrack import body
from margtrack import quaternion as quat
from margtrack.body.skeleton import SEGMENT_NAMES
from margtrack.live.avatar_solids import SolidLayout, cylinder_mesh, sphere_mesh
from margtrack.live.avatars import Avatars
from margtrack.live.viewer_controls import control_label
from margtrack.live.viewer_panels import (
    JointTrace,
    joint_table,
    sensor_order,
    sensor_table,
    unique_stem,
)
from margtrack.live.viewer_scene import camera_view, display


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_solids_join_the_skeletons_points_with_a_shoulder_girdle_and_a_head(frame):
    av = Avatars.from_names(SEGMENT_NAMES, 1.8, frame)
    layout = SolidLayout.from_avatars(av)
    rng = np.random.default_rng(3)
    q = quat.normalize(rng.normal(size=(1, len(SEGMENT_NAMES), 4)))
    joints, ends = body.positions(av.skeleton, q, av.root_positions_m)
    s = layout.solids(q, joints, ends)
    names = av.skeleton.names
    k = names.index
    # the upper arm's capsule runs from the shoulder joint to the elbow (its end)
    i = layout.capsules.index(("joint", k("left_upper_arm"), "end", k("left_upper_arm")))
    np.testing.assert_allclose(s.capsule_a[i], joints[0, k("left_upper_arm")])
    np.testing.assert_allclose(s.capsule_b[i], ends[0, k("left_upper_arm")])
    # the shoulder girdle: the trunk's distal end (neck) to each shoulder joint
    for side in ("left", "right"):
        g = layout.capsules.index(("end", k("trunk"), "joint", k(f"{side}_upper_arm")))
        np.testing.assert_allclose(s.capsule_a[g], ends[0, k("trunk")])
        np.testing.assert_allclose(s.capsule_b[g], joints[0, k(f"{side}_upper_arm")])
    # cylinders: unit z mapped onto each capsule's axis, length and radius as scales
    pos, qc, scale = s.cylinders()
    axis = quat.rotate(qc, np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(pos + 0.5 * scale[:, 2:] * axis, s.capsule_b, atol=1e-12)
    np.testing.assert_allclose(pos - 0.5 * scale[:, 2:] * axis, s.capsule_a, atol=1e-12)
    np.testing.assert_allclose(scale[:, 0], s.capsule_radius)
    # upper arm 0.030 H, thigh 0.045 H
    assert layout.capsule_radius_m[i] == pytest.approx(0.030 * 1.8)
    # one head ball on the head segment, about 20 cm across for 1.8 m; trunk box turns
    assert s.head_positions.shape == (1, 3) and 0.09 < s.head_radius[0] < 0.11
    np.testing.assert_allclose(s.box_wxyzs[0], q[0, k("trunk")])


def test_camera_frames_the_reference_pose_in_front_of_the_avatar():
    av = Avatars.from_names(SEGMENT_NAMES, 1.75, "NED")
    ref = SolidLayout.from_avatars(av).reference()
    points, _ = display("NED", ref.points())
    # z up: the toes' capsule reaches its radius (4.6 cm) below the floor; the head's top
    assert points[:, 2].min() == pytest.approx(-0.026 * 1.75, abs=1e-9)
    assert points[:, 2].max() == pytest.approx(1.75, abs=0.05)
    position, look_at = camera_view(points, fov_rad=math.radians(50), fill=0.75)
    np.testing.assert_allclose(look_at[2], 0.5 * (points[:, 2].min() + points[:, 2].max()))
    assert position[1] > look_at[1] + 1.0  # in front (north, the reference pose's forward)
    # the box's half height fills 75 % of the half field of view from that distance
    half = 0.5 * (points[:, 2].max() - points[:, 2].min())
    distance = np.linalg.norm(position - look_at)
    assert half / distance < math.tan(math.radians(25)) * 0.8


def test_meshes_are_closed_and_face_outwards():
    for vertices, faces in (cylinder_mesh(12), sphere_mesh(8, 12)):
        normals = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                           vertices[faces[:, 2]] - vertices[faces[:, 0]])
        assert np.all(np.sum(normals * vertices[faces].mean(axis=1), axis=1) > 0)
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]),
                        axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        assert np.all(counts == 2)  # every edge shared by two faces: watertight


def test_sensor_table_is_in_body_order_and_shows_stale_sensors_and_counters():
    names = ("right_foot", "pelvis", "left_thigh", "left_shank", "left_foot", "right_thigh",
             "right_shank")  # the source's order: neither body nor alphabetical
    av = Avatars.from_names(names)
    order = sensor_order(names, av)
    assert [names[i] for i in order] == ["pelvis", "left_thigh", "left_shank", "left_foot",
                                         "right_thigh", "right_shank", "right_foot"]
    assert sensor_order(("b", "a"), None) == [0, 1]
    n = len(names)
    health = SimpleNamespace(
        names=names, rate_hz=np.full(n, 100.0), dropped=np.arange(n),
        mag_norm_ratio=np.r_[np.nan, 1.0, np.full(n - 2, np.nan)],
        mag_ok=np.r_[False, True, [False] * (n - 2)],
        stale=np.r_[True, [False] * (n - 1)], counts={"resyncs": np.r_[2, [0] * (n - 1)]},
        errors=("clock reset at 12.0 s", *[""] * (n - 1)))
    rows = sensor_table(health, order).splitlines()
    assert rows[0] == "| sensor | Hz | drops | \\|m\\|/\\|m₀\\| | state |"
    assert rows[2] == "| pelvis | 100 | 1 | 1.00 ✓ | ok |"
    assert rows[-4] == "| right_foot | 100 | 0 | nan – | **stale** · resyncs 2 |"
    assert rows[-2:] == ["last errors:", "- right_foot: clock reset at 12.0 s"]
    # an engine without those fields: every sensor ok
    basic = SimpleNamespace(**{k: getattr(health, k) for k in
                               ("names", "rate_hz", "dropped", "mag_norm_ratio", "mag_ok")})
    assert sensor_table(basic, order).splitlines()[-1] == "| right_foot | 100 | 0 | nan – | ok |"


def test_joint_readout_and_trace():
    sk = body.Skeleton.from_height(1.75, "lower", "ENU")
    q = np.tile(quat.identity(), (len(sk), 1))
    q[sk.index("right_shank")] = quat.from_axis_angle([1.0, 0, 0], math.radians(-30))
    angles = body.joint_angles(sk, q)
    table = joint_table(angles)
    assert "| right knee | flexion +30 · abduction +0 · internal rotation +0 |" in table
    trace = JointTrace(window_s=1.0)
    for t in 0.25 * np.arange(8):  # exact binary fractions: 0 ... 1.75 s
        trace.add(t, angles)
    t, knee, missing = trace.data(["right_knee", "no_joint"])
    assert t.tolist() == [0.75, 1.0, 1.25, 1.5, 1.75]  # the last second
    np.testing.assert_allclose(knee, 30.0)
    assert np.isnan(missing).all()
    trace.add(0.0, angles)  # time going back (replay again): starts over
    assert trace.data(["right_knee"])[0].tolist() == [0.0]
    with pytest.raises(ValueError, match="window_s"):
        JointTrace(window_s=math.nan)


def test_unique_stem_never_reuses_an_existing_export(tmp_path):
    assert unique_stem(tmp_path, "live", (".bvh", ".sto")) == "live"
    (tmp_path / "live.sto").write_text("x")
    assert unique_stem(tmp_path, "live", (".bvh", ".sto")) == "live_2"
    (tmp_path / "live_2.bvh").write_text("x")
    assert unique_stem(tmp_path, "live", (".bvh", ".sto")) == "live_3"


def test_control_labels_are_words_with_the_declared_unit():
    from margtrack import methods
    from margtrack.estimator.params import specs

    assert control_label("bias_walk_deg_s_sqrt_s", "deg/s/√s") == "bias walk [deg/s/√s]"
    assert control_label("rest_acc_m_s2", "m/s²") == "rest acc [m/s²]"
    assert control_label("gain", "1/s") == "gain [1/s]"
    assert control_label("tau_s", "s") == "tau [s]"
    assert control_label("mag_weight", "") == "mag weight"
    assert control_label("s", "s") == "s [s]"  # never an empty name
    # every declared parameter of every method: no unit word left, no raw identifier
    for name in ("bias-kf", "ekf", "robust", "bachmann", "gradient"):
        for spec in specs(methods.create(name, rate_hz=100.0).params):
            label = control_label(spec.name, spec.unit)
            assert "_" not in label
            if spec.unit:
                assert label.endswith(f" [{spec.unit}]")
                assert label.split(" [")[0].split()[-1] not in {"deg", "s", "rad", "sqrt"}


def test_the_page_says_when_the_engine_stops_on_an_error():
    """A real viser server and engine; the source fails after its first chunk."""
    pytest.importorskip("viser", reason="the live page needs viser (pip install viser)")
    import time

    from margtrack.live.protocol import BaseSource, Chunk, SourceInfo
    from margtrack.live.viewer_session import run_live

    class FailingSource(BaseSource):
        def __init__(self) -> None:
            super().__init__(SourceInfo(("a", "b"), 100.0, True, "failing"))
            self.polls = 0

        def poll(self, timeout_s: float) -> list[Chunk]:
            self.polls += 1
            if self.polls > 1:
                raise RuntimeError("sensor cable pulled")
            n = 10
            return [Chunk(0.01 * np.arange(n), np.arange(2), np.zeros((2, n, 3)),
                          np.tile([0.0, 0.0, 9.81], (2, n, 1)),
                          np.tile([20.0, 0.0, -40.0], (2, n, 1)), np.full(n, time.perf_counter()))]

    session = run_live(FailingSource(), "bachmann", port=0, block=False)
    try:
        viewer = session.viewer
        end = time.perf_counter() + 10.0
        while not viewer._notice.visible and time.perf_counter() < end:
            time.sleep(0.05)
        assert viewer._notice.visible
        assert "RuntimeError('sensor cable pulled')" in viewer._notice.content
        assert "restart `margtrack live`" in viewer._notice.content
        assert "sensor cable pulled" in viewer._status.content
    finally:
        session.stop()
