"""Tests for margtrack.frames: reference vectors, frame names, NED <-> ENU conversion.

Oracles for the frame conventions are vqf and imufusion (dev extras), fed with sensor
readings that margtrack itself generates from a known NED orientation.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from margtrack import frames
from margtrack import quaternion as quat

G = frames.STANDARD_GRAVITY_M_S2
# ENU coordinates -> NED coordinates: [n, e, d] = [y, x, -z]; its own inverse.
P = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
S3 = np.sqrt(3.0)

PROPERTY = settings(max_examples=60, deadline=None, derandomize=True, database=None)

_coord = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False, allow_subnormal=False)
unit_quats = (
    hnp.arrays(np.float64, 4, elements=_coord)
    .filter(lambda a: np.linalg.norm(a) > 0.1)
    .map(lambda a: a / np.linalg.norm(a))
)
vectors = hnp.arrays(
    np.float64,
    3,
    elements=st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False, allow_subnormal=False),
)


def random_quats(seed: int, n: int) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def sign_free_error(a, b) -> float:
    a, b = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    return float(np.max(np.minimum(np.abs(a - b).max(axis=-1), np.abs(a + b).max(axis=-1))))


# ----------------------------------------------------------------------------- check_frame


@pytest.mark.parametrize(
    ("name", "expected"), [("NED", "NED"), ("ENU", "ENU"), ("ned", "NED"), ("Enu", "ENU")]
)
def test_check_frame_accepts_both_frames_in_any_case(name, expected):
    assert frames.check_frame(name) == expected


@pytest.mark.parametrize("name", ["NWU", "", "north", "NED ", "E N U", None, 1])
def test_check_frame_rejects_other_names_with_a_clear_message(name):
    with pytest.raises(
        ValueError, match=r"frame must be 'NED' or 'ENU', got " + re.escape(repr(name))
    ):
        frames.check_frame(name)


def test_frames_constant():
    assert frames.FRAMES == ("NED", "ENU")


# ----------------------------------------------------------------------------- references


def test_up():
    np.testing.assert_array_equal(frames.up("NED"), [0.0, 0.0, -1.0])
    np.testing.assert_array_equal(frames.up("ENU"), [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(frames.up("enu"), [0.0, 0.0, 1.0])


def test_gravity_reference_is_what_a_level_accelerometer_reads():
    assert G == 9.80665
    np.testing.assert_array_equal(frames.gravity_reference("NED"), [0.0, 0.0, -G])
    np.testing.assert_array_equal(frames.gravity_reference("ENU"), [0.0, 0.0, G])
    np.testing.assert_array_equal(frames.gravity_reference("ned", 9.81), [0.0, 0.0, -9.81])
    np.testing.assert_array_equal(frames.gravity_reference("ENU", 1.0), [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(
        P @ frames.gravity_reference("ENU"), frames.gravity_reference("NED")
    )


@pytest.mark.parametrize("bad", [0.0, -9.81, np.nan, np.inf])
def test_gravity_reference_rejects_bad_magnitude(bad):
    with pytest.raises(ValueError, match="gravity_m_s2"):
        frames.gravity_reference("NED", bad)


def test_gravity_reference_rejects_bad_frame():
    with pytest.raises(ValueError, match="frame must be"):
        frames.gravity_reference("NWU")


@pytest.mark.parametrize(
    ("dip", "field", "ned", "enu"),
    [
        (0.0, 1.0, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        (90.0, 1.0, [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]),
        (-90.0, 2.0, [0.0, 0.0, -2.0], [0.0, 0.0, 2.0]),
        (60.0, 50.0, [25.0, 0.0, 25.0 * S3], [0.0, 25.0, -25.0 * S3]),
        (
            -60.0,
            50.0,
            [25.0, 0.0, -25.0 * S3],
            [0.0, 25.0, 25.0 * S3],
        ),  # southern hemisphere: points up
        (30.0, 2.0, [S3, 0.0, 1.0], [0.0, S3, -1.0]),
    ],
)
def test_mag_reference_hand_values(dip, field, ned, enu):
    np.testing.assert_allclose(
        frames.mag_reference("NED", dip, field), ned, rtol=0, atol=1e-14 * field
    )
    np.testing.assert_allclose(
        frames.mag_reference("ENU", dip, field), enu, rtol=0, atol=1e-14 * field
    )
    np.testing.assert_allclose(
        frames.mag_reference("enu", dip, field), enu, rtol=0, atol=1e-14 * field
    )
    # one field, two coordinate systems
    np.testing.assert_allclose(
        P @ frames.mag_reference("ENU", dip, field), frames.mag_reference("NED", dip, field)
    )


def test_mag_reference_defaults_to_unit_horizontal_north():
    np.testing.assert_array_equal(frames.mag_reference("NED"), [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(frames.mag_reference("ENU"), [0.0, 1.0, 0.0])


@pytest.mark.parametrize("dip", [0.0, 12.5, 45.0, 66.6, 90.0, -33.0])
def test_mag_reference_dip_is_the_angle_below_horizontal(dip):
    for frame in ("NED", "ENU"):
        m = frames.mag_reference(frame, dip, 48.0)
        assert np.linalg.norm(m) == pytest.approx(48.0, rel=1e-15)
        down = -frames.up(frame)
        assert np.degrees(np.arcsin(m @ down / 48.0)) == pytest.approx(dip, abs=1e-6)


@pytest.mark.parametrize("dip", [90.0001, -90.5, 180.0, np.nan, np.inf, -np.inf])
def test_mag_reference_rejects_bad_dip(dip):
    with pytest.raises(ValueError, match="dip_deg"):
        frames.mag_reference("NED", dip, 1.0)


@pytest.mark.parametrize("field", [0.0, -50.0, np.nan, np.inf])
def test_mag_reference_rejects_bad_field(field):
    with pytest.raises(ValueError, match="field_ut"):
        frames.mag_reference("ENU", 60.0, field)


def test_mag_reference_rejects_bad_frame():
    with pytest.raises(ValueError, match="frame must be"):
        frames.mag_reference("NWU", 60.0, 1.0)


# ----------------------------------------------------------------------------- convert


def test_convert_identity_is_the_coordinate_permutation():
    c = frames.convert(quat.identity(), "ENU", "NED")
    np.testing.assert_allclose(quat.to_matrix(c), P, atol=1e-15)
    np.testing.assert_allclose(
        quat.to_matrix(frames.convert(quat.identity(), "NED", "ENU")), P, atol=1e-15
    )


@PROPERTY
@given(unit_quats, vectors)
def test_convert_enu_to_ned_maps_body_vectors_through_p(q_enu, v_body):
    q_ned = frames.convert(q_enu, "ENU", "NED")
    np.testing.assert_allclose(
        quat.rotate(q_ned, v_body), P @ quat.rotate(q_enu, v_body), rtol=0, atol=1e-12
    )
    assert abs(np.linalg.norm(q_ned) - 1.0) < 1e-15


@PROPERTY
@given(unit_quats, vectors)
def test_convert_ned_to_enu_maps_body_vectors_through_p(q_ned, v_body):
    q_enu = frames.convert(q_ned, "NED", "ENU")
    np.testing.assert_allclose(
        quat.rotate(q_enu, v_body), P @ quat.rotate(q_ned, v_body), rtol=0, atol=1e-12
    )


@PROPERTY
@given(unit_quats)
def test_convert_twice_is_identity_up_to_sign(q):
    for a, b in (("NED", "ENU"), ("ENU", "NED")):
        back = frames.convert(frames.convert(q, a, b), b, a)
        assert sign_free_error(back, q) < 1e-15


def test_convert_same_frame_is_an_unchanged_copy():
    q = random_quats(1, 5)
    for frame in ("NED", "ENU", "ned"):
        out = frames.convert(q, frame, frame.upper())
        np.testing.assert_array_equal(out, q)
        assert out is not q


def test_convert_broadcasts_over_leading_axes_and_accepts_lower_case():
    q = random_quats(2, 24).reshape(2, 3, 4, 4)
    out = frames.convert(q, "enu", "ned")
    assert out.shape == q.shape
    np.testing.assert_array_equal(out[1, 2, 3], frames.convert(q[1, 2, 3], "ENU", "NED"))


@pytest.mark.parametrize(("src", "dst"), [("NED", "NED"), ("NED", "ENU"), ("ENU", "ENU")])
def test_convert_rejects_wrong_quaternion_shape(src, dst):
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        frames.convert([1.0, 0.0, 0.0], src, dst)


@pytest.mark.parametrize(("src", "dst"), [("NWU", "NED"), ("NED", "xyz")])
def test_convert_rejects_bad_frame(src, dst):
    with pytest.raises(ValueError, match="frame must be 'NED' or 'ENU'"):
        frames.convert(quat.identity(), src, dst)


def test_level_sensor_facing_north_in_enu_converts_to_ned():
    """Body x points north (heading 90 deg from east, about ENU's up axis), body z up."""
    q_enu = np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])
    np.testing.assert_allclose(
        quat.rotate(q_enu, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15
    )  # north in ENU
    np.testing.assert_allclose(
        quat.rotate(q_enu, [0.0, 0.0, 1.0]), [0.0, 0.0, 1.0], atol=1e-15
    )  # up
    q_ned = frames.convert(q_enu, "ENU", "NED")
    np.testing.assert_allclose(
        quat.rotate(q_ned, [1.0, 0.0, 0.0]), [1.0, 0.0, 0.0], atol=1e-15
    )  # north
    np.testing.assert_allclose(
        quat.rotate(q_ned, [0.0, 0.0, 1.0]), [0.0, 0.0, -1.0], atol=1e-15
    )  # up
    # body z up is upside down for NED's level (body z down) convention: a half turn about north
    assert sign_free_error(q_ned, [0.0, 1.0, 0.0, 0.0]) < 1e-15
    np.testing.assert_allclose(quat.to_euler(q_ned), [0.0, 0.0, np.pi], atol=1e-15)


def test_level_sensor_facing_north_in_ned_is_identity():
    np.testing.assert_allclose(quat.rotate(quat.identity(), [1.0, 0.0, 0.0]), [1.0, 0.0, 0.0])
    q_enu = frames.convert(quat.identity(), "NED", "ENU")
    np.testing.assert_allclose(
        quat.rotate(q_enu, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15
    )  # north
    np.testing.assert_allclose(
        quat.rotate(q_enu, [0.0, 0.0, 1.0]), [0.0, 0.0, -1.0], atol=1e-15
    )  # down


@PROPERTY
@given(unit_quats, st.floats(-90.0, 90.0))
def test_sensor_readings_do_not_depend_on_the_earth_frame(q_ned, dip):
    """A body-frame reading is the same whichever earth frame the orientation is written in."""
    q_enu = frames.convert(q_ned, "NED", "ENU")
    for ref in (frames.gravity_reference, lambda f: frames.mag_reference(f, dip, 50.0)):
        body_ned = quat.rotate_inverse(q_ned, ref("NED"))
        body_enu = quat.rotate_inverse(q_enu, ref("ENU"))
        np.testing.assert_allclose(body_ned, body_enu, rtol=0, atol=1e-12)


def test_level_accelerometer_reading_in_body_frame():
    """At the reference orientation the body axes are the earth axes."""
    np.testing.assert_array_equal(
        quat.rotate_inverse(quat.identity(), frames.gravity_reference("NED")), [0, 0, -G]
    )
    np.testing.assert_array_equal(
        quat.rotate_inverse(quat.identity(), frames.gravity_reference("ENU")), [0, 0, G]
    )
    # pitched nose-up by 90 deg in NED (about body y): body x points up, so acc reads +g on x
    q = quat.from_euler([0.0, np.pi / 2, 0.0])
    np.testing.assert_allclose(
        quat.rotate_inverse(q, frames.gravity_reference("NED")), [G, 0.0, 0.0], atol=1e-14
    )


# ----------------------------------------------------------------------------- other libraries


def _static_readings(q_ned, n, dip=60.0):
    acc = np.tile(quat.rotate_inverse(q_ned, frames.gravity_reference("NED")), (n, 1))
    mag = np.tile(quat.rotate_inverse(q_ned, frames.mag_reference("NED", dip, 50.0)), (n, 1))
    return np.zeros((n, 3)), acc, mag


ORIENTATIONS_NED = [
    quat.from_euler([2.0, 0.5, -0.7]),
    quat.from_euler([-2.9, -1.1, 2.5]),
    quat.from_euler([0.3, 0.2, 0.1]),
]


@pytest.mark.parametrize("q_ned", ORIENTATIONS_NED)
def test_vqf_9d_quaternion_is_enu_with_the_same_meaning(q_ned):
    """vqf returns [w, x, y, z] of the body relative to ENU, v_earth = q ⊗ v_body ⊗ q*.

    Noise-free static data, 20 s at 100 Hz: vqf converges to ~1e-6 rad; 1e-4 rad is far
    below the 90-180 deg a wrong frame, order or conjugation would give.
    """
    vqf = pytest.importorskip("vqf")
    gyr, acc, mag = _static_readings(q_ned, 2000)
    q_vqf = vqf.offlineVQF(gyr, acc, mag, 0.01)["quat9D"][-1]
    assert quat.angle_between(q_vqf, frames.convert(q_ned, "NED", "ENU")) < 1e-4


@pytest.mark.parametrize("q_ned", ORIENTATIONS_NED)
@pytest.mark.parametrize("frame", ["NED", "ENU"])
def test_imufusion_conventions_match_frames(q_ned, frame):
    """imufusion's get_quaternion() is [w, x, y, z] with our meaning in the chosen convention.

    imufusion computes in float32, hence ~1e-5 rad at convergence; 1e-3 rad tolerance.
    Inputs: gyro in deg/s, accelerometer in g.
    """
    imufusion = pytest.importorskip("imufusion")
    gyr, acc, mag = _static_readings(q_ned, 2000)
    settings_ = imufusion.AhrsSettings()
    settings_.convention = getattr(imufusion, f"CONVENTION_{frame}")
    settings_.sample_rate = 100
    ahrs = imufusion.Ahrs()
    ahrs.set_settings(settings_)
    for i in range(len(acc)):
        ahrs.update(np.degrees(gyr[i]), acc[i] / G, mag[i])
    expected = frames.convert(q_ned, "NED", frame)
    assert quat.angle_between(ahrs.get_quaternion(), expected) < 1e-3


# ahrs 0.4.0 has no single convention: what each estimator returns for a known q_NED, with
# the dip sign each one needs (its magnetic reference takes the dip with opposite signs).
# q_NWU = [0, 1, 0, 0] ⊗ q_NED (NWU: x north, y west, z up). Recorded in docs/conventions.md.
_NWU_FROM_NED = np.array([0.0, 1.0, 0.0, 0.0])
AHRS_CASES = {
    "Madgwick": (lambda f, g, a, m: f.Madgwick(gyr=g, acc=a, mag=m, frequency=100.0), "NWU"),
    "FAMC": (lambda f, g, a, m: f.FAMC(acc=a, mag=m), "NWU"),
    "QUEST": (lambda f, g, a, m: f.QUEST(acc=a, mag=m, magnetic_dip=-60.0), "NWU"),
    "Davenport": (lambda f, g, a, m: f.Davenport(acc=a, mag=m, magnetic_dip=-60.0), "NWU"),
    "EKF-NED": (
        lambda f, g, a, m: f.EKF(gyr=g, acc=a, mag=m, frequency=100.0, magnetic_ref=-60.0),
        "NWU",
    ),
    "Mahony": (lambda f, g, a, m: f.Mahony(gyr=g, acc=a, mag=m, frequency=100.0), "ENU"),
    "EKF-ENU": (
        lambda f, g, a, m: f.EKF(
            gyr=g, acc=a, mag=m, frequency=100.0, frame="ENU", magnetic_ref=60.0
        ),
        "ENU",
    ),
    "FQA": (
        lambda f, g, a, m: f.FQA(acc=a, mag=m, mag_ref=frames.mag_reference("NED", 60.0)),
        "NED",
    ),
    "SAAM": (lambda f, g, a, m: f.SAAM(acc=a, mag=m), "NWU*"),
    "AQUA": (lambda f, g, a, m: f.AQUA(acc=a, mag=m), "NWU*"),
}


@pytest.mark.parametrize("q_ned", ORIENTATIONS_NED[:2])
@pytest.mark.parametrize("name", sorted(AHRS_CASES))
def test_ahrs_estimator_frames(name, q_ned):
    """Noise-free static data: these ahrs estimators return their closed-form solution to
    ~1e-11 rad; a wrong frame or a conjugation is off by tens of degrees."""
    ahrs = pytest.importorskip("ahrs")
    gyr, acc, mag = _static_readings(q_ned, 50)
    make, frame = AHRS_CASES[name]
    q_est = make(ahrs.filters, gyr, acc, mag).Q[-1]
    q_nwu = quat.multiply(_NWU_FROM_NED, q_ned)
    expected = {
        "NED": q_ned,
        "ENU": frames.convert(q_ned, "NED", "ENU"),
        "NWU": q_nwu,
        "NWU*": quat.conjugate(q_nwu),
    }[frame]
    assert quat.angle_between(q_est, expected) < 1e-6
