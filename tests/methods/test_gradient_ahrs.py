"""The full-vector variant against ahrs.filters.Madgwick (oracle), sample by sample.

Convention mapping: ahrs's Madgwick estimates the body orientation in NWU (x north, y west,
z up), [w, x, y, z], same product and meaning as margtrack (docs/conventions.md). Here
``q_nwu = qz(-90°) ⊗ q_enu`` and ``q_nwu = [0, 1, 0, 0] ⊗ q_ned``. ahrs integrates with the
first-order step ``q + q̇ Δt`` then normalises: ``integration="euler"``. Both start from
the same quaternion (ours, converted), and ahrs gets the same per-sample Δt. ahrs skips
the whole update when a gyro sample is exactly zero (BROAD's quantised gyro has some):
those samples are nudged by 1e-6 rad/s so both filters do the same thing.
"""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.io import broad_trials, read_broad
from margtrack.methods.gradient import Gradient

ahrs_filters = pytest.importorskip("ahrs.filters", reason="ahrs is a test-only oracle")

_TO_NWU = {
    "ENU": quat.from_axis_angle([0.0, 0.0, 1.0], -np.pi / 2),
    "NED": np.array([0.0, 1.0, 0.0, 0.0]),
}


@pytest.fixture(scope="module")
def broad_slice(broad_folder):
    trial = next(t for t in broad_trials(broad_folder) if t.name.startswith("06_"))
    # 1.7 s at rest, then 7 s of fast rotation (up to 7 rad/s)
    rec = read_broad(trial.path).slice(10253, 12753)
    gyr = rec.gyr.copy()
    still = np.linalg.norm(gyr, axis=1) == 0.0
    gyr[still, 0] = 1e-6
    return rec.t, gyr, rec.acc, rec.mag


def _ahrs(q0_nwu, t, gyr, acc, mag, beta):
    m = ahrs_filters.Madgwick(gain=beta)
    out = np.empty((len(t), 4))
    out[0] = q0_nwu
    for i in range(1, len(t)):
        dt = t[i] - t[i - 1]
        if mag is None:
            out[i] = m.updateIMU(out[i - 1], gyr[i], acc[i], dt=dt)
        else:
            out[i] = m.updateMARG(out[i - 1], gyr[i], acc[i], mag[i], dt=dt)
    return out


@pytest.mark.parametrize("frame", ["ENU", "NED"])
@pytest.mark.parametrize("with_mag", [True, False])
def test_madgwick_variant_equals_ahrs_to_rounding(broad_slice, frame, with_mag):
    t, gyr, acc, mag = broad_slice
    mag = mag if with_mag else None
    est = Gradient(frame=frame, beta=0.1, mag_objective="madgwick", integration="euler").run(
        gyr=gyr, acc=acc, mag=mag, t=t
    )
    ours_nwu = quat.multiply(_TO_NWU[frame], est.quat)
    oracle = _ahrs(ours_nwu[0], t, gyr, acc, mag, 0.1)
    sign = np.sign(np.sum(ours_nwu * oracle, axis=1))[:, None]
    # each step agrees to ~1e-16; the correction is contractive, so it stays there
    assert np.max(np.abs(sign * ours_nwu - oracle)) < 1e-12


def test_ahrs_own_marg_start_is_our_initial_orientation(broad_slice):
    t, gyr, acc, mag = broad_slice
    rate = 1.0 / np.median(np.diff(t))
    n = 300
    oracle = ahrs_filters.Madgwick(gyr=gyr[:n], acc=acc[:n], mag=mag[:n], frequency=rate,
                                   gain=0.1).Q
    est = Gradient(beta=0.1, mag_objective="madgwick", integration="euler").run(
        gyr=gyr[:n], acc=acc[:n], mag=mag[:n], t=np.arange(n) / rate
    )
    ours_nwu = quat.multiply(_TO_NWU["ENU"], est.quat)
    # ahrs.common.orientation.ecompass (its MARG start) is TRIAD in NWU
    assert np.max(quat.angle_between(ours_nwu, oracle)) < 1e-10


def test_exact_integration_differs_from_euler_by_second_order_only(broad_slice):
    t, gyr, acc, mag = broad_slice
    runs = {
        kind: Gradient(beta=0.1, integration=kind).run(gyr=gyr, acc=acc, mag=mag, t=t).quat
        for kind in ("exact", "euler")
    }
    gap = quat.angle_between(runs["exact"], runs["euler"])
    # a normalised Euler step turns by 2 atan(θ/2) = θ - θ³/12 + ... instead of θ = |ω| Δt;
    # the gradient step also enters before instead of after the rotation: O(β Δt θ)
    theta = np.linalg.norm(gyr, axis=1) * np.median(np.diff(t))
    bound = np.sum(theta**3 / 12 + 0.1 * np.median(np.diff(t)) * theta)
    assert 1e-7 < np.max(gap) < bound
