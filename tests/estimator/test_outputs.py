"""``Estimate.outputs`` computed on first read: once, only when read, equal to the eager ones."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from margtrack import frames, sim
from margtrack import quaternion as quat
from margtrack.estimator import Flag
from margtrack.estimator.outputs import Deferred, Outputs
from margtrack.methods.gradient import Gradient


def _counting(value):
    calls = []

    def compute():
        calls.append(1)
        return value

    return Deferred(compute), calls


def test_deferred_value_is_computed_once_on_first_read_and_names_compute_nothing():
    a = np.arange(3.0)
    deferred, calls = _counting(a * 2.0)
    out = Outputs({"a": a, "b": deferred})
    assert list(out) == ["a", "b"] and len(out) == 2 and "b" in out
    assert out.pending() == ["b"] and calls == []
    np.testing.assert_array_equal(out["b"], [0.0, 2.0, 4.0])
    assert out["b"] is out["b"] and len(calls) == 1 and out.pending() == []


def test_mapped_stays_deferred_and_pickling_materialises():
    deferred, calls = _counting(np.ones((2, 4, 1)))
    out = Outputs({"x": deferred, "y": np.zeros((2, 4))})
    first = out.mapped(lambda _, v: v[0])
    assert calls == [] and first.pending() == ["x"]
    np.testing.assert_array_equal(first["y"], np.zeros(4))
    assert first["x"].shape == (4, 1) and len(calls) == 1
    copy = pickle.loads(pickle.dumps(Outputs({"x": _counting(np.eye(2))[0]})))
    assert copy.pending() == [] and np.array_equal(copy["x"], np.eye(2))
    out["x"] = np.full(3, 7.0)  # a set value replaces the deferred one
    assert out.pending() == [] and out["x"][0] == 7.0 and len(calls) == 1


@pytest.mark.kernel
def test_gradient_run_outputs_are_004s_outputs_of_its_orientations():
    # run keeps only the screened acc and the bits, expand() computes the rest on read: they
    # are 004's outputs of the orientations run gave (the same as update's, sample by
    # sample), with faults and a gap inside: Euler angles (ZYX), the gravity component in
    # the body, the earth-frame linear acceleration of the screened sample
    rec = sim.simulate_motion("random", duration_s=2.0, rate_hz=100.0, seed=3)
    gyr, acc, mag = rec.gyr.copy(), rec.acc.copy(), rec.mag.copy()
    acc[30:33] = 0.0
    acc[50] = np.nan
    mag[60:70] = 0.0
    t = rec.t.copy()
    t[120:] += 1.0  # a gap: a restart, held samples before it
    est = Gradient().run(gyr=gyr, acc=acc, mag=mag, t=t)
    assert isinstance(est.outputs, Outputs) and len(est.outputs.pending()) == 4
    live = Gradient()
    q_live = [live.update(gyr[i], acc[i], mag[i], dt=0.0 if i == 0 else t[i] - t[i - 1])
              for i in range(t.size)]  # these intervals add up to t exactly
    np.testing.assert_array_equal(est.quat, np.array(q_live))
    q, g = est.quat, Gradient().params.gravity_m_s2
    up = frames.up(est.frame)
    screened = np.where(np.isfinite(acc), acc, 0.0)  # the screening's "no measurement"
    # held samples (the restart's window after the gap) keep no measurement either, and
    # the restart's sample (the window's last) steps with the window's mean acceleration
    window = (est.flags & Flag.INITIALISING) != 0
    screened[window] = 0.0
    r = 120 + int(np.argmin(window[120:]))
    assert r > 120
    other = np.arange(t.size) != r
    np.testing.assert_allclose(est.outputs["euler_rad"], quat.to_euler(q), atol=1e-12)
    np.testing.assert_allclose(est.outputs["gravity_body_m_s2"], g * quat.rotate_inverse(q, up),
                               atol=1e-12)
    np.testing.assert_allclose(est.outputs["lin_acc_earth_m_s2"][other],
                               (quat.rotate(q, screened) - g * up)[other], atol=1e-9)
    ignored = est.outputs["ignored"]
    assert ignored.dtype == np.int8 and np.all(ignored[30:33] != 0) and np.all(ignored[:30] == 0)
    assert est.outputs["ignored"].dtype == np.int8 and est.outputs["ignored"].any()
