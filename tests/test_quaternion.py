"""Tests for margtrack.quaternion: hand values, scipy as oracle, properties, errors, broadcasting.

scipy.spatial.transform.Rotation is the oracle throughout. It stores quaternions
scalar-last, ``[x, y, z, w]``, while margtrack is scalar-first, ``[w, x, y, z]``: every
conversion goes through :func:`to_scipy` and :func:`from_scipy` below, never by hand.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.spatial.transform import Rotation, Slerp

from margtrack import quaternion as quat

PI = np.pi
H = np.sqrt(0.5)
EX, EY, EZ = np.eye(3)

# Deterministic hypothesis runs (derandomize), no example database written to disk.
PROPERTY = settings(max_examples=60, deadline=None, derandomize=True, database=None)


# ----------------------------------------------------------------------------- helpers


def to_scipy(q) -> Rotation:
    """margtrack quaternion(s) [w, x, y, z] -> scipy Rotation, which takes [x, y, z, w]."""
    return Rotation.from_quat(np.asarray(q, dtype=float)[..., [1, 2, 3, 0]])


def from_scipy(r: Rotation) -> np.ndarray:
    """scipy Rotation (as_quat gives [x, y, z, w]) -> margtrack [w, x, y, z]."""
    return r.as_quat()[..., [3, 0, 1, 2]]


def sign_free_error(a, b) -> np.ndarray:
    """Largest component difference between quaternions a and b, up to the sign of b."""
    a, b = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    return np.minimum(np.abs(a - b).max(axis=-1), np.abs(a + b).max(axis=-1))


def assert_same_rotation(a, b, atol: float) -> None:
    err = sign_free_error(a, b)
    assert np.max(err) <= atol, f"max quaternion difference (up to sign) {np.max(err):.3e} > {atol}"


def wrap(angle) -> np.ndarray:
    """Angle wrapped to [-pi, pi]."""
    return np.angle(np.exp(1j * np.asarray(angle)))


def random_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


_coord = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False, allow_subnormal=False)
raw_quats = hnp.arrays(np.float64, 4, elements=_coord).filter(lambda a: np.linalg.norm(a) > 0.1)
unit_quats = raw_quats.map(lambda a: a / np.linalg.norm(a))
vectors = hnp.arrays(
    np.float64,
    3,
    elements=st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False, allow_subnormal=False),
)
nonzero_vectors = vectors.filter(lambda v: np.linalg.norm(v) > 1e-3)
rates = hnp.arrays(
    np.float64,
    3,
    elements=st.floats(-5.0, 5.0, allow_nan=False, allow_infinity=False, allow_subnormal=False),
)
fractions = st.floats(0.0, 1.0, allow_nan=False)


# ----------------------------------------------------------------------------- hand values


QI, QJ, QK, ONE = (
    np.array(v, dtype=float) for v in ([0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [1, 0, 0, 0])
)


@pytest.mark.parametrize(
    ("p", "q", "expected"),
    [
        (QI, QJ, QK),
        (QJ, QK, QI),
        (QK, QI, QJ),
        (QJ, QI, -QK),
        (QK, QJ, -QI),
        (QI, QK, -QJ),
        (QI, QI, -ONE),
        (QJ, QJ, -ONE),
        (QK, QK, -ONE),
        (ONE, QI, QI),
        (QJ, ONE, QJ),
    ],
)
def test_hamilton_product_of_units(p, q, expected):
    np.testing.assert_array_equal(quat.multiply(p, q), expected)


def test_ijk_is_minus_one():
    np.testing.assert_array_equal(quat.multiply(quat.multiply(QI, QJ), QK), -ONE)


# 004, "Normalize Quaternions" table. Each row: quaternion, axis, angle, and the images of
# the body basis vectors x, y, z in the earth frame (rotate(q, e_x), ...), worked out by hand.
TABLE_004 = [
    ([1, 0, 0, 0], EX, 0.0, [EX, EY, EZ]),
    ([0, 1, 0, 0], EX, PI, [EX, -EY, -EZ]),
    ([0, 0, 1, 0], EY, PI, [-EX, EY, -EZ]),
    ([0, 0, 0, 1], EZ, PI, [-EX, -EY, EZ]),
    ([H, H, 0, 0], EX, PI / 2, [EX, EZ, -EY]),
    ([H, 0, H, 0], EY, PI / 2, [-EZ, EY, EX]),
    ([H, 0, 0, H], EZ, PI / 2, [EY, -EX, EZ]),
    ([H, -H, 0, 0], EX, -PI / 2, [EX, -EZ, EY]),
    ([H, 0, -H, 0], EY, -PI / 2, [EZ, EY, -EX]),
    ([H, 0, 0, -H], EZ, -PI / 2, [-EY, EX, EZ]),
]


@pytest.mark.parametrize(("q", "axis", "angle", "images"), TABLE_004)
def test_table_004_rotates_basis_vectors(q, axis, angle, images):
    images = np.array(images, dtype=float)
    np.testing.assert_allclose(quat.rotate(q, np.eye(3)), images, atol=1e-15)
    # the matrix has the images as columns
    np.testing.assert_allclose(quat.to_matrix(q), images.T, atol=1e-15)
    # body vectors come back from the earth frame
    np.testing.assert_allclose(quat.rotate_inverse(q, images), np.eye(3), atol=1e-15)
    np.testing.assert_allclose(quat.from_axis_angle(axis, angle), q, atol=1e-15)


@pytest.mark.parametrize(("q", "axis", "angle", "images"), TABLE_004)
def test_table_004_axis_angle_and_rotvec(q, axis, angle, images):
    got_axis, got_angle = quat.to_axis_angle(q)
    assert got_angle == pytest.approx(abs(angle), abs=1e-15)
    expected_axis = np.sign(angle) * axis if angle != 0.0 else EX
    np.testing.assert_allclose(got_axis, expected_axis, atol=1e-15)
    np.testing.assert_allclose(quat.to_rotvec(q), angle * axis, atol=1e-15)


def test_rotate_is_the_sandwich_product():
    """rotate(q, v) is the vector part of q ⊗ (0, v) ⊗ q* (004, DESIGN 'Meaning')."""
    rng = np.random.default_rng(11)
    q = random_quats(rng, 500)
    v = rng.normal(size=(500, 3))
    pure = np.concatenate([np.zeros((500, 1)), v], axis=-1)
    sandwich = quat.multiply(quat.multiply(q, pure), quat.conjugate(q))
    np.testing.assert_allclose(sandwich[:, 0], 0.0, atol=1e-15)
    np.testing.assert_allclose(quat.rotate(q, v), sandwich[:, 1:], atol=1e-14)
    back = quat.multiply(quat.multiply(quat.conjugate(q), pure), q)
    np.testing.assert_allclose(quat.rotate_inverse(q, v), back[:, 1:], atol=1e-14)


def test_rate_matches_004_product_definition():
    """q̇ = ½ q ⊗ (0, ω), written out with 004's product (q1..q4 = w, x, y, z).

    004's expanded q̇ has a sign slip in its third row (``- ½ q4 ωx``); the product
    definition it expands gives ``+ ½ q4 ωx``, which is what is checked here.
    """
    q1, q2, q3, q4 = 0.5, -0.1, 0.7, 0.3
    wx, wy, wz = 0.4, -1.3, 2.2
    expected = 0.5 * np.array(
        [
            -q2 * wx - q3 * wy - q4 * wz,
            q1 * wx + q3 * wz - q4 * wy,
            q1 * wy - q2 * wz + q4 * wx,
            q1 * wz + q2 * wy - q3 * wx,
        ]
    )
    np.testing.assert_allclose(quat.rate([q1, q2, q3, q4], [wx, wy, wz]), expected, atol=1e-16)


def test_identity_shapes_and_values():
    np.testing.assert_array_equal(quat.identity(), [1.0, 0.0, 0.0, 0.0])
    ident = quat.identity((2, 3))
    assert ident.shape == (2, 3, 4)
    np.testing.assert_array_equal(ident[..., 0], 1.0)
    np.testing.assert_array_equal(ident[..., 1:], 0.0)
    np.testing.assert_array_equal(quat.identity(5), np.tile([1.0, 0, 0, 0], (5, 1)))


# ----------------------------------------------------------------------------- scipy oracle


def test_multiply_matches_scipy_composition():
    rng = np.random.default_rng(1)
    p, q = random_quats(rng, 2000), random_quats(rng, 2000)
    assert_same_rotation(quat.multiply(p, q), from_scipy(to_scipy(p) * to_scipy(q)), 1e-15)


def test_rotate_and_rotate_inverse_match_scipy_apply():
    rng = np.random.default_rng(2)
    q = random_quats(rng, 2000)
    v = rng.normal(scale=10.0, size=(2000, 3))
    r = to_scipy(q)
    np.testing.assert_allclose(quat.rotate(q, v), r.apply(v), rtol=0, atol=1e-13)
    np.testing.assert_allclose(
        quat.rotate_inverse(q, v), r.apply(v, inverse=True), rtol=0, atol=1e-13
    )


def test_to_matrix_matches_scipy():
    rng = np.random.default_rng(3)
    q = random_quats(rng, 2000)
    np.testing.assert_allclose(quat.to_matrix(q), to_scipy(q).as_matrix(), rtol=0, atol=3e-15)


def test_from_matrix_matches_scipy():
    rng = np.random.default_rng(4)
    m = Rotation.random(2000, random_state=rng).as_matrix()
    got = quat.from_matrix(m)
    assert np.all(got[:, 0] >= 0.0)
    assert_same_rotation(got, from_scipy(Rotation.from_matrix(m)), 1e-15)


def test_euler_matches_scipy_away_from_gimbal_lock():
    rng = np.random.default_rng(5)
    n = 4000
    angles = np.stack(
        [
            rng.uniform(-PI, PI, n),
            rng.uniform(-PI / 2 + 0.01, PI / 2 - 0.01, n),
            rng.uniform(-PI, PI, n),
        ],
        axis=-1,
    )
    r = Rotation.from_euler("ZYX", angles)  # intrinsic z-y'-x'', angles [yaw, pitch, roll]
    q = from_scipy(r)
    got = quat.to_euler(q)
    assert np.max(np.abs(wrap(got - r.as_euler("ZYX")))) < 1e-12
    assert np.max(np.abs(wrap(got - angles))) < 1e-12
    # and back: from_euler equals scipy's from_euler('ZYX', [yaw, pitch, roll])
    assert_same_rotation(quat.from_euler(angles), q, 1e-15)


def test_from_euler_matches_scipy_for_any_angles():
    rng = np.random.default_rng(6)
    angles = rng.uniform(-3 * PI, 3 * PI, size=(2000, 3))  # outside the output ranges too
    assert_same_rotation(
        quat.from_euler(angles), from_scipy(Rotation.from_euler("ZYX", angles)), 1e-14
    )


def test_euler_004_formulas():
    """004's yaw/pitch/roll formulas (its extracted text drops the squares in the atan2
    denominators: q1² + q2² - q3² - q4² and q1² - q2² - q3² + q4²)."""
    rng = np.random.default_rng(7)
    q = random_quats(rng, 2000)
    q1, q2, q3, q4 = q.T
    yaw = np.arctan2(2 * (q2 * q3 + q4 * q1), q2**2 - q3**2 - q4**2 + q1**2)
    pitch = np.arcsin(np.clip(-2 * (q2 * q4 - q3 * q1), -1.0, 1.0))
    roll = np.arctan2(2 * (q3 * q4 + q2 * q1), -(q2**2) - q3**2 + q4**2 + q1**2)
    got = quat.to_euler(q)
    keep = np.cos(pitch) > 0.05  # asin loses digits near the poles
    np.testing.assert_allclose(
        wrap(got[keep] - np.stack([yaw, pitch, roll], -1)[keep]), 0.0, atol=1e-13
    )


def test_from_euler_is_rz_ry_rx():
    yaw, pitch, roll = 0.7, -0.4, 2.1
    cy, cp, cr = np.cos([yaw, pitch, roll])
    sy, sp, sr = np.sin([yaw, pitch, roll])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    q = quat.from_euler([yaw, pitch, roll])
    np.testing.assert_allclose(quat.to_matrix(q), rz @ ry @ rx, atol=1e-15)
    composed = quat.multiply(
        quat.from_axis_angle(EZ, yaw),
        quat.multiply(quat.from_axis_angle(EY, pitch), quat.from_axis_angle(EX, roll)),
    )
    np.testing.assert_allclose(q, composed, atol=1e-15)
    np.testing.assert_allclose(quat.to_euler(q), [yaw, pitch, roll], atol=1e-15)


def test_euler_hand_values():
    np.testing.assert_allclose(quat.to_euler([H, 0, 0, H]), [PI / 2, 0, 0], atol=1e-15)
    np.testing.assert_allclose(quat.to_euler([H, H, 0, 0]), [0, 0, PI / 2], atol=1e-15)
    np.testing.assert_allclose(quat.to_euler([H, 0, -H, 0]), [0, -PI / 2, 0], atol=1e-15)
    np.testing.assert_allclose(quat.to_euler([H, 0, 0, -H]), [-PI / 2, 0, 0], atol=1e-15)
    np.testing.assert_allclose(
        quat.from_euler([0.3, 0, 0]), [np.cos(0.15), 0, 0, np.sin(0.15)], atol=1e-16
    )


def test_euler_output_ranges():
    rng = np.random.default_rng(8)
    e = quat.to_euler(random_quats(rng, 5000))
    assert np.all((e[:, 0] > -PI) & (e[:, 0] <= PI))
    assert np.all((e[:, 1] >= -PI / 2) & (e[:, 1] <= PI / 2))
    assert np.all((e[:, 2] > -PI) & (e[:, 2] <= PI))


@pytest.mark.parametrize("sign", [1.0, -1.0])
@pytest.mark.parametrize(
    "offset", [0.0, 1e-15, 1e-13, 1e-12, 1e-11, 1e-10, 1e-9, 1e-8, 1e-6, 1e-4, 1e-2]
)
def test_euler_round_trip_near_and_at_gimbal_lock(sign, offset):
    """Angles are not unique at the lock, so check the rotation, not the angles.

    Tolerance: ~1e-15 is reachable everywhere; the policy of snapping roll to 0 within
    cos(pitch) < 1e-12 of the lock may cost up to ~3e-12, hence 1e-11.
    """
    rng = np.random.default_rng(9)
    n = 500
    yaw, roll = rng.uniform(-PI, PI, size=(2, n))
    q = quat.from_euler(np.stack([yaw, np.full(n, sign * (PI / 2 - offset)), roll], axis=-1))
    back = quat.from_euler(quat.to_euler(q))
    worst = float(np.max(quat.angle_between(q, back)))
    assert worst < 1e-11, f"round-trip error {worst:.2e} rad at {offset=}"


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_gimbal_lock_policy_sets_roll_to_zero(sign):
    rng = np.random.default_rng(10)
    n = 200
    yaw, roll = rng.uniform(-PI, PI, size=(2, n))
    q = quat.from_euler(np.stack([yaw, np.full(n, sign * PI / 2), roll], axis=-1))
    e = quat.to_euler(q)
    np.testing.assert_array_equal(e[:, 2], 0.0)
    np.testing.assert_allclose(e[:, 1], sign * PI / 2, atol=1e-12)
    # only yaw - roll (pitch up) or yaw + roll (pitch down) is defined; it goes to yaw
    np.testing.assert_allclose(wrap(e[:, 0] - (yaw - sign * roll)), 0.0, atol=1e-12)


def test_rotvec_matches_scipy():
    rng = np.random.default_rng(12)
    axis = unit(rng.normal(size=(3000, 3)))
    angle = np.concatenate(
        [
            rng.uniform(0, PI, 2990),
            [0, 1e-12, 1e-9, 2e-9, 1e-6, 1.1e-6, 1e-3, 3.0, PI - 1e-9, PI - 1e-6],
        ]
    )
    rotvec = axis * angle[:, None]
    q = quat.from_rotvec(rotvec)
    assert_same_rotation(q, from_scipy(Rotation.from_rotvec(rotvec)), 1e-15)
    np.testing.assert_allclose(quat.to_rotvec(q), to_scipy(q).as_rotvec(), rtol=0, atol=2e-15)


def test_slerp_matches_scipy():
    rng = np.random.default_rng(13)
    t = np.linspace(0.0, 1.0, 11)
    for _ in range(100):
        p, q = random_quats(rng, 2)
        gap = quat.angle_between(p, q)
        if gap > PI - 1e-6:  # the shortest path is not unique at half a turn
            continue
        expected = from_scipy(Slerp([0.0, 1.0], to_scipy(np.stack([p, q])))(t))
        assert_same_rotation(quat.slerp(p, q, t), expected, 1e-14)


def test_angle_between_matches_scipy():
    rng = np.random.default_rng(14)
    p, q = random_quats(rng, 3000), random_quats(rng, 3000)
    expected = (to_scipy(p).inv() * to_scipy(q)).magnitude()
    np.testing.assert_allclose(quat.angle_between(p, q), expected, rtol=0, atol=1e-14)


def test_integrate_matches_scipy():
    rng = np.random.default_rng(15)
    q = random_quats(rng, 2000)
    gyr = rng.normal(scale=3.0, size=(2000, 3))
    dt = rng.uniform(1e-4, 0.5, size=2000)
    expected = from_scipy(to_scipy(q) * Rotation.from_rotvec(gyr * dt[:, None]))
    assert_same_rotation(quat.integrate(q, gyr, dt), expected, 1e-15)


# ----------------------------------------------------------------------------- properties


@PROPERTY
@given(unit_quats, unit_quats)
def test_multiply_keeps_unit_norm(p, q):
    assert abs(np.linalg.norm(quat.multiply(p, q)) - 1.0) < 1e-15


@PROPERTY
@given(raw_quats, st.floats(1e-6, 1e6))
def test_normalize_gives_unit_norm_and_same_direction(q, scale):
    n = quat.normalize(q * scale)
    assert abs(np.linalg.norm(n) - 1.0) < 1e-15
    np.testing.assert_allclose(n, q / np.linalg.norm(q), atol=1e-15)


@PROPERTY
@given(unit_quats, rates, st.floats(0.0, 10.0))
def test_integrate_keeps_unit_norm(q, gyr, dt):
    assert abs(np.linalg.norm(quat.integrate(q, gyr, dt)) - 1.0) < 1e-15


@PROPERTY
@given(unit_quats, unit_quats, fractions)
def test_slerp_keeps_unit_norm(p, q, t):
    assert abs(np.linalg.norm(quat.slerp(p, q, t)) - 1.0) < 1e-15


@PROPERTY
@given(unit_quats, vectors)
def test_q_and_minus_q_are_one_rotation(q, v):
    np.testing.assert_allclose(quat.rotate(-q, v), quat.rotate(q, v), rtol=0, atol=1e-13)
    np.testing.assert_allclose(
        quat.rotate_inverse(-q, v), quat.rotate_inverse(q, v), rtol=0, atol=1e-13
    )
    np.testing.assert_allclose(quat.to_matrix(-q), quat.to_matrix(q), rtol=0, atol=1e-15)
    np.testing.assert_allclose(wrap(quat.to_euler(-q) - quat.to_euler(q)), 0.0, atol=1e-12)
    assert quat.angle_between(q, -q) < 1e-15
    if q[0] != 0.0:  # a half turn has two rotation vectors, +pi*axis and -pi*axis
        np.testing.assert_allclose(quat.to_rotvec(-q), quat.to_rotvec(q), rtol=0, atol=1e-14)


@PROPERTY
@given(unit_quats)
def test_conjugate_is_inverse_of_unit_quaternion(q):
    np.testing.assert_allclose(quat.multiply(q, quat.conjugate(q)), ONE, atol=1e-15)
    np.testing.assert_allclose(quat.multiply(quat.conjugate(q), q), ONE, atol=1e-15)
    np.testing.assert_allclose(quat.inverse(q), quat.conjugate(q), atol=1e-15)
    np.testing.assert_array_equal(quat.conjugate(q), q * [1, -1, -1, -1])


@PROPERTY
@given(raw_quats, st.floats(0.01, 100.0))
def test_inverse_of_non_unit_quaternion(q, scale):
    q = q * scale
    np.testing.assert_allclose(quat.multiply(q, quat.inverse(q)), ONE, atol=1e-14)
    np.testing.assert_allclose(quat.multiply(quat.inverse(q), q), ONE, atol=1e-14)


@PROPERTY
@given(unit_quats, unit_quats, unit_quats)
def test_multiply_is_associative(p, q, r):
    left = quat.multiply(quat.multiply(p, q), r)
    right = quat.multiply(p, quat.multiply(q, r))
    np.testing.assert_allclose(left, right, atol=1e-15)


@PROPERTY
@given(unit_quats, unit_quats, vectors)
def test_rotate_composes_like_multiply(p, q, v):
    """rotate(p ⊗ q, v) = rotate(p, rotate(q, v)): q acts first."""
    np.testing.assert_allclose(
        quat.rotate(quat.multiply(p, q), v), quat.rotate(p, quat.rotate(q, v)), atol=1e-13
    )


@PROPERTY
@given(unit_quats, vectors)
def test_rotate_then_rotate_inverse_round_trip(q, v):
    earth = quat.rotate(q, v)
    np.testing.assert_allclose(np.linalg.norm(earth), np.linalg.norm(v), rtol=1e-14, atol=1e-13)
    np.testing.assert_allclose(quat.rotate_inverse(q, earth), v, atol=1e-13)
    np.testing.assert_allclose(quat.rotate(q, quat.rotate_inverse(q, v)), v, atol=1e-13)
    np.testing.assert_allclose(earth, quat.to_matrix(q) @ v, atol=1e-13)
    np.testing.assert_allclose(quat.rotate_inverse(q, v), quat.to_matrix(q).T @ v, atol=1e-13)


@PROPERTY
@given(unit_quats)
def test_from_matrix_inverts_to_matrix(q):
    got = quat.from_matrix(quat.to_matrix(q))
    assert got[0] >= 0.0
    assert_same_rotation(got, q, 1e-15)
    if abs(q[0]) > 1e-9:  # with w = 0 both signs are canonical
        np.testing.assert_allclose(got, quat.canonical(q), atol=1e-15)


def _branch(matrix: np.ndarray) -> np.ndarray:
    """Which of [trace, R11, R22, R33] is largest: the branch from_matrix should use."""
    return np.argmax(
        np.stack(
            [
                np.trace(matrix, axis1=-2, axis2=-1),
                matrix[..., 0, 0],
                matrix[..., 1, 1],
                matrix[..., 2, 2],
            ],
            -1,
        ),
        axis=-1,
    )


def _trace_only_from_matrix(m: np.ndarray) -> np.ndarray:
    """004's first branch used for every matrix: what from_matrix must not do."""
    n = 2.0 * np.sqrt(np.maximum(1.0 + np.trace(m, axis1=-2, axis2=-1), 1e-300))
    q = np.stack(
        [
            n / 4,
            (m[..., 2, 1] - m[..., 1, 2]) / n,
            (m[..., 0, 2] - m[..., 2, 0]) / n,
            (m[..., 1, 0] - m[..., 0, 1]) / n,
        ],
        -1,
    )
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def test_from_matrix_all_four_branches_to_full_precision():
    rng = np.random.default_rng(16)
    qs = [
        quat.identity(),
        quat.from_rotvec([0.1, -0.2, 0.3]),
        [0.0, 1.0, 0.0, 0.0],  # half turns about x, y, z: R11, R22, R33 largest, trace = -1
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
        quat.from_axis_angle(
            [1.0, 0.3, -0.2], PI - 1e-7
        ),  # near half turns about x-, y-, z-ish axes
        quat.from_axis_angle([0.2, -1.0, 0.3], PI - 1e-7),
        quat.from_axis_angle([-0.3, 0.2, 1.0], PI - 1e-7),
    ]
    axes = unit(rng.normal(size=(300, 3)))
    for w in (0.0, 1e-12, 1e-8, 1e-5, 1e-3):  # near-180-degree rotations about arbitrary axes
        qs.extend(np.concatenate([np.full((300, 1), w), axes * np.sqrt(1.0 - w * w)], -1))
    qs.extend(random_quats(rng, 300))
    q = quat.normalize(np.array(qs, dtype=float))
    m = quat.to_matrix(q)
    assert set(np.unique(_branch(m))) == {0, 1, 2, 3}  # the data covers every branch

    got = quat.from_matrix(m)
    assert np.all(got[:, 0] >= 0.0)
    assert_same_rotation(got, q, 1e-15)
    clear = np.abs(q[:, 0]) > 1e-9
    np.testing.assert_allclose(got[clear], quat.canonical(q[clear]), rtol=0, atol=1e-15)
    # the same data defeats a trace-only formula, so the check above has teeth
    assert np.max(sign_free_error(_trace_only_from_matrix(m), q)) > 1e-6


@pytest.mark.parametrize(
    ("matrix", "expected"),
    [
        (np.diag([1.0, -1.0, -1.0]), [0.0, 1.0, 0.0, 0.0]),
        (np.diag([-1.0, 1.0, -1.0]), [0.0, 0.0, 1.0, 0.0]),
        (np.diag([-1.0, -1.0, 1.0]), [0.0, 0.0, 0.0, 1.0]),
        (np.eye(3), [1.0, 0.0, 0.0, 0.0]),
        ([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], [H, 0.0, 0.0, H]),
    ],
)
def test_from_matrix_hand_values(matrix, expected):
    np.testing.assert_allclose(quat.from_matrix(matrix), expected, atol=1e-16)


@PROPERTY
@given(unit_quats)
def test_to_matrix_is_a_rotation(q):
    m = quat.to_matrix(q)
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-14)


@pytest.mark.parametrize(
    "angle",
    [
        0.0,
        1e-15,
        1e-12,
        1e-10,
        1e-9,
        2e-9,
        3e-9,
        1e-7,
        1e-6,
        1.5e-6,
        1e-4,
        0.5,
        2.0,
        3.0,
        PI - 1e-6,
    ],
)
def test_rotvec_round_trip_including_taylor_branches(angle):
    rng = np.random.default_rng(17)
    rotvec = unit(rng.normal(size=(200, 3))) * angle
    q = quat.from_rotvec(rotvec)
    # independent value: sin(angle/2)/angle = sinc(angle / 2pi) / 2 with numpy's sinc
    half = 0.5 * np.sinc(angle / (2 * PI))
    np.testing.assert_allclose(q[:, 1:], rotvec * half, rtol=1e-15, atol=0)
    np.testing.assert_allclose(q[:, 0], np.cos(angle / 2), rtol=0, atol=1e-15)
    back = quat.to_rotvec(q)
    np.testing.assert_allclose(back, rotvec, rtol=0, atol=4e-16 * angle)
    np.testing.assert_allclose(quat.from_rotvec(back), q, atol=1e-16)


@PROPERTY
@given(unit_quats)
def test_to_rotvec_then_from_rotvec_is_canonical(q):
    r = quat.to_rotvec(q)
    assert np.linalg.norm(r) <= PI + 1e-15
    assert_same_rotation(quat.from_rotvec(r), q, 1e-15)
    if abs(q[0]) > 1e-9:
        np.testing.assert_allclose(quat.from_rotvec(r), quat.canonical(q), atol=1e-15)


@PROPERTY
@given(raw_quats)
def test_canonical_has_non_negative_w_and_same_rotation(q):
    c = quat.canonical(q)
    assert c[0] >= 0.0
    assert np.all((c == q) | (c == -q))
    np.testing.assert_array_equal(quat.canonical(c), c)
    if q[0] != 0.0:
        np.testing.assert_array_equal(quat.canonical(-q), c)


@PROPERTY
@given(
    st.lists(unit_quats, min_size=1, max_size=20), st.lists(st.booleans(), min_size=20, max_size=20)
)
def test_continuous_makes_consecutive_dots_positive(series, flips):
    q = np.array(series)
    q = q * np.where(np.array(flips[: len(q)]), -1.0, 1.0)[:, None]
    c = quat.continuous(q)
    assert c.shape == q.shape
    np.testing.assert_array_equal(c[0], q[0])
    assert np.all(np.sum(c[1:] * c[:-1], axis=-1) >= 0.0)
    # each entry is the input or its negative: the rotations are unchanged
    assert np.all(np.all(c == q, axis=-1) | np.all(c == -q, axis=-1))


def test_continuous_works_per_series_along_axis_minus_two():
    rng = np.random.default_rng(18)
    base = quat.integrate(
        random_quats(rng, 3)[:, None, :], [0.3, -0.2, 0.5], np.arange(50.0)[None, :] * 0.1
    )
    signs = rng.choice([-1.0, 1.0], size=(3, 50, 1))
    c = quat.continuous(base * signs)
    for s in range(3):
        np.testing.assert_array_equal(c[s], quat.continuous((base * signs)[s]))
        assert np.all(np.sum(c[s, 1:] * c[s, :-1], axis=-1) > 0.0)
    # a smooth series with random signs is restored up to one global sign per series
    np.testing.assert_allclose(np.abs(np.sum(c * base, axis=-1)), 1.0, atol=1e-15)
    assert np.all(np.abs(np.diff(np.sign(np.sum(c * base, axis=-1)), axis=-1)) == 0)
    single = np.array([0.0, -1.0, 0.0, 0.0])
    out = quat.continuous(single)
    np.testing.assert_array_equal(out, single)
    assert out is not single


def _arc_checks(u, v, atol=1e-12):
    q = quat.shortest_arc(u, v)
    uh, vh = unit(u), unit(v)
    assert np.max(np.abs(np.linalg.norm(q, axis=-1) - 1.0)) < 1e-15
    np.testing.assert_allclose(quat.rotate(q, uh), vh, rtol=0, atol=atol)
    true_angle = np.arctan2(np.linalg.norm(np.cross(uh, vh), axis=-1), np.sum(uh * vh, axis=-1))
    np.testing.assert_allclose(
        quat.angle_between(quat.identity(), q), true_angle, rtol=0, atol=atol
    )
    # shortest: the rotation axis is perpendicular to u (and to v)
    np.testing.assert_allclose(np.sum(q[..., 1:] * uh, axis=-1), 0.0, atol=atol)
    np.testing.assert_allclose(np.sum(q[..., 1:] * vh, axis=-1), 0.0, atol=atol)
    return q


@PROPERTY
@given(nonzero_vectors, nonzero_vectors)
def test_shortest_arc_random_non_unit_vectors(u, v):
    uh, vh = unit(u), unit(v)
    assume(np.dot(uh, vh) > -1.0 + 1e-6)  # the near-antiparallel band has its own test
    _arc_checks(u, v)


@PROPERTY
@given(nonzero_vectors, st.floats(1e-3, 1e3))
def test_shortest_arc_parallel_is_identity(u, scale):
    q = _arc_checks(u, scale * u)
    np.testing.assert_allclose(q, ONE, atol=1e-15)


@PROPERTY
@given(nonzero_vectors, st.floats(1e-3, 1e3))
def test_shortest_arc_antiparallel_is_a_half_turn(u, scale):
    q = _arc_checks(u, -scale * u)
    assert abs(q[0]) < 1e-15


@pytest.mark.parametrize("axis", [EX, -EX, EY, -EY, EZ, -EZ])
@pytest.mark.parametrize("scale", [1e-3, 1.0, 7.0])
def test_shortest_arc_antiparallel_along_each_axis(axis, scale):
    q = _arc_checks(axis, -scale * axis)
    np.testing.assert_array_equal(q[0], 0.0)
    np.testing.assert_allclose(quat.rotate(q, axis), -axis, atol=1e-15)


@pytest.mark.parametrize("delta", [0.0, 1e-12, 1e-9, 1e-7, 1e-6, 1e-5, 1e-4, 1e-2])
def test_shortest_arc_near_antiparallel(delta):
    """u and v at pi - delta: u is still mapped onto v and the angle is pi - delta.

    float64 allows ~1e-15 here: a half turn to -u followed by the well-conditioned arc
    from -u to v. 1e-12 leaves a wide margin.
    """
    rng = np.random.default_rng(19)
    u = unit(rng.normal(size=(300, 3))) * rng.uniform(0.01, 100.0, size=(300, 1))
    perp = unit(np.cross(u, rng.normal(size=(300, 3))))
    v = (-np.cos(delta) * unit(u) + np.sin(delta) * perp) * 3.0
    _arc_checks(u, v)


def test_shortest_arc_004_formula_for_generic_vectors():
    """004: q = [s/2, (x × y)/s] with s = sqrt(2(1 + x·y)) for unit x, y."""
    x = unit([1.0, 2.0, -0.5])
    y = unit([-0.3, 0.4, 2.0])
    s = np.sqrt(2.0 * (1.0 + x @ y))
    np.testing.assert_allclose(
        quat.shortest_arc(x, y), np.concatenate([[s / 2], np.cross(x, y) / s]), atol=1e-16
    )


@PROPERTY
@given(unit_quats, unit_quats)
def test_slerp_endpoints_and_constant_angular_speed(p, q):
    gap = quat.angle_between(p, q)
    assume(gap < PI - 1e-6)  # half a turn has two shortest paths
    t = np.linspace(0.0, 1.0, 9)
    s = quat.slerp(p, q, t)
    np.testing.assert_allclose(s[0], p, atol=1e-15)
    assert_same_rotation(s[-1], q, 1e-15)
    np.testing.assert_allclose(quat.angle_between(p, s), t * gap, rtol=0, atol=1e-14)
    np.testing.assert_allclose(quat.angle_between(s, q), (1 - t) * gap, rtol=0, atol=1e-14)
    # q and -q interpolate the same way
    assert_same_rotation(quat.slerp(p, -q, t), s, 1e-15)


@PROPERTY
@given(unit_quats, rates, st.floats(1e-3, 2.0))
def test_integrate_matches_scipy_property(q, gyr, dt):
    expected = from_scipy(to_scipy(q) * Rotation.from_rotvec(gyr * dt))
    assert_same_rotation(quat.integrate(q, gyr, dt), expected, 2e-15)


@PROPERTY
@given(unit_quats, rates, st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_integrate_splits_over_time_for_constant_rate(q, gyr, a, b):
    two_steps = quat.integrate(quat.integrate(q, gyr, a), gyr, b)
    np.testing.assert_allclose(two_steps, quat.integrate(q, gyr, a + b), atol=1e-14)
    np.testing.assert_array_equal(quat.integrate(q, gyr, 0.0), q)


def _euler_steps(q, gyr, total, n):
    """004's update q <- q + q̇ dt with q̇ = rate(q, ω), n steps, no normalisation."""
    h = total / n
    for _ in range(n):
        q = q + quat.rate(q, gyr) * h
    return q


@pytest.mark.parametrize("n", [100, 1000])
def test_euler_steps_of_rate_converge_to_integrate(n):
    """For constant ω each step is q ⊗ (1, ωh/2): a rotation by 2·atan(|ω|h/2) instead of
    |ω|h about the right axis, with norm growth sqrt(1 + (|ω|h/2)²). So the direction
    error after n steps is n·(|ω|h - 2·atan(|ω|h/2)) ≈ |ω|³h²T/12 (second order) and the
    norm is (1 + (|ω|h/2)²)^(n/2).
    """
    rng = np.random.default_rng(20)
    q0 = random_quats(rng, 20)
    gyr = rng.normal(scale=2.0, size=(20, 3))
    exact = quat.integrate(q0, gyr, 1.0)
    assert_same_rotation(exact, from_scipy(to_scipy(q0) * Rotation.from_rotvec(gyr)), 1e-15)
    stepped = _euler_steps(q0, gyr, 1.0, n)
    step_angle = np.linalg.norm(gyr, axis=-1) / n
    expected_error = n * (step_angle - 2.0 * np.arctan(step_angle / 2.0))
    np.testing.assert_allclose(
        quat.angle_between(stepped, exact), expected_error, rtol=1e-6, atol=1e-13
    )
    np.testing.assert_allclose(
        np.linalg.norm(stepped, axis=-1), (1.0 + (step_angle / 2) ** 2) ** (n / 2), rtol=1e-12
    )


def test_euler_steps_error_shrinks_with_step_count():
    rng = np.random.default_rng(21)
    q0 = random_quats(rng, 20)
    gyr = rng.normal(scale=2.0, size=(20, 3))
    exact = quat.integrate(q0, gyr, 1.0)
    err_100 = quat.angle_between(_euler_steps(q0, gyr, 1.0, 100), exact)
    err_1000 = quat.angle_between(_euler_steps(q0, gyr, 1.0, 1000), exact)
    ratio = err_1000 / err_100
    assert np.all((ratio > 0.009) & (ratio < 0.011))  # second order: 10x the steps, 1/100 the error
    assert np.max(err_1000) < 1e-4


@PROPERTY
@given(unit_quats, rates)
def test_rate_is_derivative_of_integrate(q, gyr):
    h = 1e-6
    central = (quat.integrate(q, gyr, h) - quat.integrate(q, gyr, -h)) / (2 * h)
    np.testing.assert_allclose(quat.rate(q, gyr), central, rtol=0, atol=1e-9)


@PROPERTY
@given(unit_quats, rates)
def test_rate_is_tangent(q, gyr):
    """A unit quaternion's derivative is orthogonal to it (the norm does not change)."""
    assert abs(np.dot(quat.rate(q, gyr), q)) < 1e-14


# ----------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("q", "index"),
    [
        ([0.0, 0.0, 0.0, 0.0], r"\(\)"),
        ([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]], r"\(1,\)"),
        ([[[1.0, 0, 0, 0], [1.0, 0, 0, 0]], [[1.0, 0, 0, 0], [0.0, 0, 0, 0]]], r"\(1, 1\)"),
        ([[1.0, 0.0, 0.0, 0.0], [np.nan, 0.0, 0.0, 0.0]], r"\(1,\)"),
        ([[np.inf, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]], r"\(0,\)"),
        ([[1.0, 0, 0, 0], [0.0, 0, 0, 0], [1.0, 0, 0, 0], [0.0, 0, 0, 0]], r"\(1,\)"),  # first
    ],
)
def test_normalize_bad_norm_names_the_index(q, index):
    with pytest.raises(ValueError, match=r"normalize.*index " + index):
        quat.normalize(q)


def test_inverse_of_zero_raises():
    with pytest.raises(ValueError, match=r"inverse.*index \(2,\)"):
        quat.inverse([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0.0, 0, 0, 0]])


@pytest.mark.parametrize(
    "call",
    [
        lambda: quat.multiply([1.0, 0, 0], [1.0, 0, 0, 0]),
        lambda: quat.multiply([1.0, 0, 0, 0], np.zeros((2, 5))),
        lambda: quat.conjugate(1.0),
        lambda: quat.normalize(np.ones((4, 3))),
        lambda: quat.rotate([1.0, 0, 0], [1.0, 0, 0]),
        lambda: quat.rotate([1.0, 0, 0, 0], [1.0, 0, 0, 0]),
        lambda: quat.rotate_inverse([1.0, 0, 0, 0], [1.0, 0]),
        lambda: quat.to_matrix(np.ones(3)),
        lambda: quat.from_matrix(np.eye(4)),
        lambda: quat.from_matrix(np.ones(9)),
        lambda: quat.to_euler([1.0, 0, 0]),
        lambda: quat.from_euler([0.1, 0.2]),
        lambda: quat.from_rotvec([0.1, 0.2, 0.3, 0.4]),
        lambda: quat.to_rotvec([1.0, 0, 0, 0, 0]),
        lambda: quat.slerp([1.0, 0, 0], [1.0, 0, 0, 0], 0.5),
        lambda: quat.angle_between([1.0, 0, 0, 0], [1.0, 0, 0]),
        lambda: quat.rate([1.0, 0, 0, 0], [0.1, 0.2]),
        lambda: quat.rate([1.0, 0, 0], [0.1, 0.2, 0.3]),
        lambda: quat.integrate([1.0, 0, 0, 0], [0.1, 0.2, 0.3, 0.4], 0.01),
        lambda: quat.shortest_arc([1.0, 0], [0.0, 1.0, 0]),
        lambda: quat.from_axis_angle([1.0, 0], 0.3),
        lambda: quat.canonical([1.0, 0, 0]),
        lambda: quat.continuous(np.ones((3, 3))),
    ],
)
def test_wrong_last_axis_raises(call):
    with pytest.raises(ValueError, match=r"shape \(\.\.\., [34]\)|shape \(\.\.\., 3, 3\)"):
        call()


@pytest.mark.parametrize(
    ("u", "v"),
    [
        ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]),
        ([1.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
        ([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], [0.0, 1.0, 0.0]),
        ([np.nan, 0.0, 0.0], [0.0, 1.0, 0.0]),
    ],
)
def test_shortest_arc_zero_vector_raises(u, v):
    with pytest.raises(ValueError, match="non-zero"):
        quat.shortest_arc(u, v)


@pytest.mark.parametrize(
    "axis", [[0.0, 0.0, 0.0], [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], [np.nan, 0.0, 1.0]]
)
def test_from_axis_angle_zero_axis_raises(axis):
    with pytest.raises(ValueError, match="axis must be a non-zero vector"):
        quat.from_axis_angle(axis, 0.5)


# ----------------------------------------------------------------------------- broadcasting


def test_multiply_broadcasts_n_by_single():
    rng = np.random.default_rng(21)
    p, q = random_quats(rng, 7), random_quats(rng, 1)[0]
    out = quat.multiply(p, q)
    assert out.shape == (7, 4)
    for i in range(7):
        np.testing.assert_array_equal(out[i], quat.multiply(p[i], q))
    out = quat.multiply(q, p)
    for i in range(7):
        np.testing.assert_array_equal(out[i], quat.multiply(q, p[i]))


def test_multiply_broadcasts_nm_by_m():
    rng = np.random.default_rng(22)
    p = random_quats(rng, 15).reshape(5, 3, 4)
    q = random_quats(rng, 3)
    out = quat.multiply(p, q)
    assert out.shape == (5, 3, 4)
    for i in range(5):
        for j in range(3):
            np.testing.assert_array_equal(out[i, j], quat.multiply(p[i, j], q[j]))


def test_rotate_broadcasts_vectors_with_single_quaternion():
    rng = np.random.default_rng(23)
    q = random_quats(rng, 1)[0]
    v = rng.normal(size=(9, 3))
    out = quat.rotate(q, v)
    assert out.shape == (9, 3)
    np.testing.assert_allclose(out, v @ quat.to_matrix(q).T, atol=1e-15)
    np.testing.assert_allclose(quat.rotate_inverse(q, out), v, atol=1e-15)
    qs = random_quats(rng, 9)
    out = quat.rotate(qs, v[0])  # many quaternions, one vector
    for i in range(9):
        np.testing.assert_array_equal(out[i], quat.rotate(qs[i], v[0]))
    grid = quat.rotate(
        qs.reshape(3, 3, 4)[:, None], v.reshape(3, 3, 3)[None]
    )  # (3, 1, 3, 4) x (1, 3, 3, 3)
    assert grid.shape == (3, 3, 3, 3)
    np.testing.assert_array_equal(
        grid[2, 1, 0], quat.rotate(qs.reshape(3, 3, 4)[2, 0], v.reshape(3, 3, 3)[1, 0])
    )


def test_conversions_keep_leading_shape():
    rng = np.random.default_rng(24)
    q = random_quats(rng, 24).reshape(2, 3, 4, 4)
    m = quat.to_matrix(q)
    assert m.shape == (2, 3, 4, 3, 3)
    np.testing.assert_allclose(m[1, 2, 3], quat.to_matrix(q[1, 2, 3]), atol=0)
    np.testing.assert_allclose(quat.from_matrix(m), quat.canonical(q), atol=1e-15)
    e = quat.to_euler(q)
    assert e.shape == (2, 3, 4, 3)
    np.testing.assert_array_equal(e[0, 1, 2], quat.to_euler(q[0, 1, 2]))
    assert_same_rotation(quat.from_euler(e), q, 1e-14)
    r = quat.to_rotvec(q)
    assert r.shape == (2, 3, 4, 3)
    assert_same_rotation(quat.from_rotvec(r), q, 1e-15)
    assert quat.angle_between(q, q[0]).shape == (2, 3, 4)
    np.testing.assert_allclose(quat.angle_between(q, q[0])[0], 0.0, atol=1e-15)


def test_slerp_and_integrate_broadcast():
    rng = np.random.default_rng(25)
    p, q = random_quats(rng, 2)
    t = np.linspace(0.0, 1.0, 6)
    s = quat.slerp(p, q, t)
    assert s.shape == (6, 4)
    for i in range(6):
        np.testing.assert_allclose(s[i], quat.slerp(p, q, t[i]), atol=1e-16)
    ps, qs = random_quats(rng, 6), random_quats(rng, 6)
    s = quat.slerp(ps, qs, t)
    for i in range(6):
        np.testing.assert_allclose(s[i], quat.slerp(ps[i], qs[i], t[i]), atol=1e-16)

    gyr = rng.normal(size=(6, 3))
    dt = rng.uniform(0.001, 0.1, size=6)
    out = quat.integrate(p, gyr, dt)  # one start, per-sample rates and sample times
    assert out.shape == (6, 4)
    for i in range(6):
        np.testing.assert_allclose(out[i], quat.integrate(p, gyr[i], dt[i]), atol=1e-16)
    out = quat.integrate(ps, gyr[0], 0.01)  # many starts, one rate, scalar dt
    for i in range(6):
        np.testing.assert_allclose(out[i], quat.integrate(ps[i], gyr[0], 0.01), atol=1e-16)
    np.testing.assert_allclose(quat.rate(ps, gyr[0])[3], quat.rate(ps[3], gyr[0]), atol=0)


def test_integer_and_list_input_is_accepted():
    np.testing.assert_array_equal(quat.multiply([0, 1, 0, 0], [0, 0, 1, 0]), [0.0, 0.0, 0.0, 1.0])
    assert quat.normalize(np.array([2, 0, 0, 0], dtype=np.int32)).dtype == np.float64
    np.testing.assert_allclose(
        quat.rotate(np.array([1, 0, 0, 0], dtype=np.float32), [1, 2, 3]), [1.0, 2.0, 3.0]
    )
