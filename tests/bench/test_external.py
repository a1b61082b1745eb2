"""The peers' adapters (``margtrack.bench.external``) against simulated truth."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.accuracy import error_series


def test_the_offline_vqf_adapter_returns_enu_orientations_and_is_acausal():
    pytest.importorskip("vqf", reason="offline VQF is the peer (pip install vqf)")
    from margtrack.bench.external import EXTERNAL

    rec = sim.simulate_motion("random", duration_s=20, seed=1, noise=False)
    q = EXTERNAL["vqf-offline"](rec)
    err = error_series(q, rec.quat_true)
    # converges on noise-free data; a frame mix-up would show 90 or 180 deg
    assert np.degrees(np.sqrt(np.mean(err.total_rad[500:] ** 2))) < 3.0
    gyr = rec.gyr.copy()
    gyr[1500:] += np.radians(2.0)  # a change after 15 s moves earlier estimates: acausal
    later = EXTERNAL["vqf-offline"](type(rec)(t=rec.t, gyr=gyr, acc=rec.acc, mag=rec.mag))
    assert np.degrees(quat.angle_between(q[:1500], later[:1500])).max() > 1e-3
