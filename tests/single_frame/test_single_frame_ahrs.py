"""ahrs (0.4) as an independent oracle for FQA, QUEST, TRIAD and Davenport.

Conventions (docs/conventions.md, "Other libraries"): ahrs quaternions are [w, x, y, z]
but the earth frame depends on the estimator. With readings generated from a known q_ned:

- ``FQA(mag_ref=m_ned)`` returns q_ned itself;
- ``QUEST(magnetic_dip=-dip)`` and ``Davenport(magnetic_dip=-dip)`` return q_nwu (x north,
  y west, z up): ``q_ned = [0, 1, 0, 0] ⊗ q_nwu`` (a half turn about north). ahrs's
  Davenport does not normalise its inputs and uses a gravity reference of length
  ``gravity``: given unit vectors and ``gravity=1`` its weights are the a_i of Wahba's loss;
- ``TRIAD(v1=up_ned, v2=m_ned, representation="quaternion")`` returns the earth-to-body
  rotation, i.e. ``conj(q_ned)``.

ahrs has no singularity handling: its QUEST loses the quaternion near 180 deg in NWU and
its FQA divides by cos θ, so the oracle comparisons use orientations away from those (our
own behaviour there is tested against Davenport in test_single_frame_exact.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.single_frame.davenport import Davenport
from margtrack.single_frame.fqa import Fqa
from margtrack.single_frame.quest import Quest
from margtrack.single_frame.triad import Triad

ahrs_filters = pytest.importorskip("ahrs.filters", reason="ahrs is a test-only oracle")

pytestmark = pytest.mark.kernel

DIP = 60.0
NWU_TO_NED = np.array([0.0, 1.0, 0.0, 0.0])


def _data(n: int, seed: int, noise: bool):
    rng = np.random.default_rng(seed)
    q_ned = quat.normalize(rng.normal(size=(n, 4)))
    acc = quat.rotate_inverse(q_ned, frames.gravity_reference("NED", 9.81))
    mag = quat.rotate_inverse(q_ned, frames.mag_reference("NED", DIP, 48.0))
    if noise:
        acc += rng.normal(scale=0.2, size=acc.shape)
        mag += rng.normal(scale=3.0, size=mag.shape)
    return q_ned, acc, mag


@pytest.mark.parametrize("noise", [False, True])
def test_fqa_matches_ahrs_fqa_in_ned(noise):
    _, acc, mag = _data(300, seed=1, noise=noise)
    # ahrs has no offset sensor: compare with ours where we do not switch either
    ours = Fqa(frame="NED").run(acc=acc, mag=mag, rate_hz=1.0)
    keep = ~ours.outputs["switched"]
    theirs = ahrs_filters.FQA(acc=acc.copy(), mag=mag.copy(),
                              mag_ref=frames.mag_reference("NED", DIP)).Q
    assert keep.sum() > 250
    assert np.max(quat.angle_between(ours.quat[keep], theirs[keep])) < 1e-9


@pytest.mark.parametrize("noise", [False, True])
def test_quest_and_davenport_match_ahrs_in_nwu(noise):
    _, acc, mag = _data(300, seed=2, noise=noise)
    weights = (1.0, 0.5)
    quest = Quest(frame="NED", mag_dip_ref_deg=DIP, weights=weights)
    quest = quest.run(acc=acc, mag=mag, rate_hz=1.0)
    dav = Davenport(frame="NED", mag_dip_ref_deg=DIP, weights=weights)
    dav = dav.run(acc=acc, mag=mag, rate_hz=1.0)
    ahrs_quest = ahrs_filters.QUEST(acc=acc, mag=mag, magnetic_dip=-DIP,
                                    weights=np.array(weights)).Q
    unit_acc = acc / np.linalg.norm(acc, axis=1)[:, None]
    unit_mag = mag / np.linalg.norm(mag, axis=1)[:, None]
    ahrs_dav = ahrs_filters.Davenport(acc=unit_acc, mag=unit_mag, magnetic_dip=-DIP,
                                      weights=np.array(weights), gravity=1.0).Q
    # ahrs's QUEST has no sequential rotation: skip its half turns (angle > 170 deg in NWU)
    q_nwu = quat.multiply(NWU_TO_NED, quest.quat)
    regular = np.abs(q_nwu[:, 0]) > np.cos(np.radians(85.0))
    assert regular.sum() > 250
    got = quest.quat[regular]
    assert np.max(quat.angle_between(got, quat.multiply(NWU_TO_NED, ahrs_quest)[regular])) < 1e-9
    assert np.max(quat.angle_between(dav.quat, quat.multiply(NWU_TO_NED, ahrs_dav))) < 1e-9


@pytest.mark.parametrize("noise", [False, True])
def test_triad_matches_ahrs_triad_conjugated(noise):
    _, acc, mag = _data(300, seed=3, noise=noise)
    ours = Triad(frame="NED").run(acc=acc, mag=mag, rate_hz=1.0)
    theirs = ahrs_filters.TRIAD(w1=acc, w2=mag, v1=frames.up("NED"),
                                v2=frames.mag_reference("NED", DIP),
                                representation="quaternion").A
    assert np.max(quat.angle_between(ours.quat, quat.conjugate(theirs))) < 1e-9


def test_ahrs_quest_fails_near_half_turns_where_ours_does_not():
    # the reason for the sequential rotations: a rotation of 180 deg - 1e-12 rad in NWU,
    # where Shuster's [γ, X] is ~1e-12 of its scale and has lost its direction to rounding
    axis = np.array([0.3, -0.8, 0.5])
    q_nwu = quat.from_axis_angle(axis, np.pi - 1e-12)
    q_ned = quat.multiply(NWU_TO_NED, q_nwu)
    acc = quat.rotate_inverse(q_ned, frames.gravity_reference("NED"))[None]
    mag = quat.rotate_inverse(q_ned, frames.mag_reference("NED", DIP))[None]
    ours = Quest(frame="NED", mag_dip_ref_deg=DIP).run(acc=acc, mag=mag, rate_hz=1.0).quat[0]
    theirs = ahrs_filters.QUEST(acc=acc, mag=mag, magnetic_dip=-DIP).Q[0]
    assert quat.angle_between(ours, q_ned) < 1e-9
    assert quat.angle_between(quat.multiply(NWU_TO_NED, theirs), q_ned) > 1e-6
