"""Skeleton: Winter proportions, presets, frames, names and validation."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.body import (
    PRESETS,
    Segment,
    Skeleton,
    body_axes,
    dimensions_from_height,
    positions,
)

H = 1.80
XIO_SENSORS = ["left_foot", "left_lower_leg", "left_upper_leg", "pelvis",
               "right_foot", "right_lower_leg", "right_upper_leg"]


def rest(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    return positions(skeleton, quat.identity((len(skeleton),)))


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_rest_pose_heights_are_winters_fractions(frame: str) -> None:
    sk = Skeleton.from_height(H, "full", frame)
    joints, ends = rest(sk)
    right, forward, up = body_axes(frame)
    height = {n: (joints[i] @ up, ends[i] @ up) for i, n in enumerate(sk.names)}
    # Winter (2009) Fig. 4.1: hip 0.530 H, knee 0.285 H, ankle 0.039 H, shoulder 0.818 H
    assert height["right_thigh"][0] == pytest.approx(0.530 * H, abs=1e-12)
    assert height["right_shank"][0] == pytest.approx(0.285 * H, abs=1e-12)
    assert height["right_foot"][0] == pytest.approx(0.039 * H, abs=1e-12)
    assert height["right_foot"][1] == pytest.approx(0.0, abs=1e-12)  # toes on the floor
    assert height["head"][0] == pytest.approx(0.818 * H, abs=1e-12)
    assert height["head"][1] == pytest.approx(H, abs=1e-12)
    # fingertips: 0.818 - 0.186 - 0.146 - 0.108 = 0.378 H (Winter: 0.377 H)
    assert height["left_hand"][1] == pytest.approx(0.378 * H, abs=1e-12)
    # widths and the foot: hips at ±0.191 H / 2 to the right, toes 0.152 H forward
    i_rt, i_lt = sk.index("right_thigh"), sk.index("left_thigh")
    assert joints[i_rt] @ right == pytest.approx(0.0955 * H, abs=1e-12)
    assert joints[i_lt] @ right == pytest.approx(-0.0955 * H, abs=1e-12)
    assert sk.index("left_upper_arm") == 3
    assert joints[3] @ right == pytest.approx(-0.1295 * H, abs=1e-12)
    assert (ends[sk.index("left_foot")] - joints[sk.index("left_foot")]) @ forward == (
        pytest.approx(0.152 * H, abs=1e-12)
    )


def test_body_axes_are_right_handed_and_frame_specific() -> None:
    r, f, u = body_axes("ENU")
    np.testing.assert_array_equal(np.stack([r, f, u]), np.eye(3))
    r, f, u = body_axes("NED")
    np.testing.assert_array_equal(r, [0, 1, 0])  # east
    np.testing.assert_array_equal(f, [1, 0, 0])  # north
    np.testing.assert_array_equal(u, [0, 0, -1])
    assert np.linalg.det(np.stack([r, f, u], axis=1)) == pytest.approx(1.0)


def test_presets() -> None:
    sizes = {"full": 15, "lower": 7, "left_arm": 3, "right_arm": 3, "left_leg": 3, "right_leg": 3}
    assert {p: len(Skeleton.from_height(H, p)) for p in PRESETS} == sizes
    arm = Skeleton.from_height(H, "right_arm")
    assert arm.root == "right_upper_arm" and list(arm.parents) == [-1, 0, 1]
    # the arm's root stands where the full body's right shoulder is
    full_joints, _ = rest(Skeleton.from_height(H, "full"))
    np.testing.assert_allclose(arm.root_position_m, full_joints[6], atol=1e-12)
    leg = Skeleton.from_height(H, "left_leg", "NED")
    np.testing.assert_allclose(
        leg.root_position_m, rest(Skeleton.from_height(H, "full", "NED"))[0][9], atol=1e-12
    )


def test_lower_body_matches_xio_sensor_names() -> None:
    sk = Skeleton.from_height(H, "lower")
    idx = sk.order(XIO_SENSORS)
    assert [XIO_SENSORS[i] for i in idx] == [
        "pelvis", "left_upper_leg", "left_lower_leg", "left_foot",
        "right_upper_leg", "right_lower_leg", "right_foot",
    ]


@pytest.mark.parametrize(
    ("names", "match"),
    [
        (XIO_SENSORS[:-1], r"missing: \['right_thigh'\]"),
        ([*XIO_SENSORS, "left_thigh"], r"repeated: \['left_thigh'\]"),
        ([*XIO_SENSORS[:-1], "right_elbow"], "unknown segment name 'right_elbow'"),
        ([*XIO_SENSORS, "head"], r"not in this skeleton: \['head'\]"),
    ],
)
def test_order_rejects_bad_names(names: list[str], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Skeleton.from_height(H, "lower").order(names)


def test_measured_dimensions_override_the_proportions() -> None:
    sk = Skeleton.from_height(H, "right_leg", dimensions_m={"thigh": 0.5, "shank": 0.4})
    joints, _ = rest(sk)
    assert joints[1, 2] == pytest.approx(joints[0, 2] - 0.5)
    assert joints[2, 2] == pytest.approx(joints[0, 2] - 0.9)
    assert sk.root_position_m[2] == pytest.approx(0.5 + 0.4 + 0.039 * H)
    with pytest.raises(ValueError, match="unknown dimension 'femur'"):
        Skeleton.from_height(H, "full", dimensions_m={"femur": 0.5})
    with pytest.raises(ValueError, match=r"dimensions_m\['thigh'\] must be a finite number > 0"):
        Skeleton.from_height(H, "full", dimensions_m={"thigh": -0.5})


def test_dimensions_from_height_validates() -> None:
    assert dimensions_from_height(2.0)["upper_arm"] == pytest.approx(0.372)
    with pytest.raises(ValueError, match=r"height_m must be a body height in metres"):
        dimensions_from_height(180.0)  # centimetres by mistake
    with pytest.raises(ValueError, match="unknown preset 'arm'"):
        Skeleton.from_height(H, "arm")
    with pytest.raises(ValueError, match="frame must be 'NED' or 'ENU'"):
        Skeleton.from_height(H, "full", "NWU")


def test_custom_skeleton_validation() -> None:
    pelvis = Segment("pelvis", None, [0, 0, 0], [0, 0, 0])
    thigh = Segment("left_upper_leg", "pelvis", [-0.1, 0, 0], [0, 0, -0.4])
    assert thigh.name == "left_thigh"  # aliases are stored canonical
    sk = Skeleton((pelvis, thigh), "ENU", [0, 0, 1.0])
    assert sk.names == ("pelvis", "left_thigh") and list(sk.parents) == [-1, 0]
    with pytest.raises(ValueError, match="unique; repeated: left_thigh"):
        Skeleton((pelvis, thigh, thigh))
    with pytest.raises(ValueError, match="exactly one root"):
        Skeleton((pelvis, Segment("trunk", None, [0, 0, 0], [0, 0, 0.5])))
    with pytest.raises(ValueError, match="not listed before it"):
        Skeleton((pelvis, Segment("left_shank", "left_thigh", [0, 0, -0.4], [0, 0, -0.4])))
    with pytest.raises(ValueError, match="root segment 'pelvis' must have offset_m = 0"):
        Segment("pelvis", None, [0, 0, 1], [0, 0, 0])
    with pytest.raises(ValueError, match="unknown segment name 'tail'"):
        Segment("tail", "pelvis", [0, 0, 0], [0, 0, -1])
    with pytest.raises(ValueError, match=r"left_thigh\.end_m must be a finite 3-vector"):
        Segment("left_thigh", "pelvis", [0, 0, 0], [0, np.nan, -1])
    with pytest.raises(ValueError, match="segment 'head' is not in this skeleton"):
        sk.index("head")
