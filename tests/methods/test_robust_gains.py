"""The robust kernel's interval gains kept in two slots equal a fresh computation, bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack import sim
from margtrack.methods.robust import RobustParams, kernel

pytestmark = pytest.mark.kernel


def _steps(rec, dt, forget):
    """The kernel's step over rec's samples with intervals dt; ``forget``: both slots
    cleared before every step, so every sample computes its gains afresh."""
    n = dt.size
    coef = RobustParams().coefficients()
    row = np.zeros(kernel.N_ROW)
    kernel._start(row, coef, True, *quat.normalize(np.array([1.0, 0.1, -0.2, 0.3])))
    q, x = np.zeros((n, 4)), np.zeros((n, kernel.N_OUT))
    slot_dt = np.zeros(n)
    for i in range(n):
        if forget:
            row[kernel.R_GAINS : kernel.R_GAINS_IN_USE] = np.nan
        kernel._step(row, coef, dt[i], *rec.gyr[i], *rec.acc[i], *rec.mag[i], True, q[i], x[i])
        slot_dt[i] = row[kernel.R_GAINS + int(row[kernel.R_GAINS_IN_USE]) + kernel.G_DT]
    return q, x, row, slot_dt


def test_two_slots_give_the_gains_of_each_interval_as_computed_afresh():
    rec = sim.simulate_motion("random", duration_s=4.0, rate_hz=100.0, seed=11)
    n = rec.t.size
    # a steady clock's intervals differ in the last bits, in turn; plus a few other ones
    rng = np.random.default_rng(2)
    base = np.diff(np.arange(n + 1) / 285.714)
    dt = np.where(rng.random(n) < 0.05, rng.choice([0.0, 0.02, 0.25], size=n), base)
    assert np.unique(base).size >= 3
    q_kept, x_kept, row, slot_dt = _steps(rec, dt, forget=False)
    q_fresh, x_fresh, _, _ = _steps(rec, dt, forget=True)
    np.testing.assert_array_equal(q_kept, q_fresh)
    np.testing.assert_array_equal(x_kept, x_fresh)
    # the slot in use after a step with dt > 0 holds that interval's gains, as computed
    moved = dt > 0.0
    np.testing.assert_array_equal(slot_dt[moved], dt[moved])
    g = kernel.R_GAINS + int(row[kernel.R_GAINS_IN_USE])
    last = dt[moved][-1]
    coef = RobustParams().coefficients()
    b0, a1, a2 = kernel.butterworth_coefficients(last, coef[kernel.C_TAU_ACC])
    np.testing.assert_array_equal(row[g + kernel.G_BW : g + kernel.G_BW + 3], [b0, a1, a2])
    tau = coef[kernel.C_TAU_MAG]
    assert row[g + kernel.G_K_MAG] == 1.0 - math.exp(-last / tau)
