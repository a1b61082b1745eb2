"""Many sensors in one ``run`` (threads over sensors) equal each sensor run alone."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import methods, sim
from margtrack.estimator import compiled
from margtrack.estimator.compiled import CompiledEstimator

COMPILED = [m for m in methods.available() if issubclass(methods.get(m), CompiledEstimator)]


def _sensors(n_sensors: int = 5, duration_s: float = 3.0):
    recs = [sim.simulate_motion("random", duration_s=duration_s, rate_hz=100.0, seed=s)
            for s in range(n_sensors)]
    gyr = np.stack([r.gyr for r in recs])
    acc = np.stack([r.acc for r in recs])
    mag = np.stack([r.mag for r in recs])
    # one sensor with absurd and missing samples, one whose field dies half-way
    gyr[1, 40:45] = np.nan
    acc[1, 80] = 0.0
    gyr[2, 120] = 1e9
    mag[3, 150:] = 0.0
    return recs[0].t, gyr, acc, mag


#: the threaded path (``run_many``) is one template for every method
#: (``contract.run_series_parallel``); two methods keep its slow compilation out of the rest
THREADED = ["gyro", "robust"]


@pytest.mark.kernel
@pytest.mark.parametrize(
    ("name", "threaded"), [(m, False) for m in COMPILED] + [(m, True) for m in THREADED]
)
def test_threads_over_sensors_equal_each_sensor_alone(name, threaded, monkeypatch):
    if threaded:
        monkeypatch.setattr(compiled, "PARALLEL_MIN_SAMPLES", 0)
    t, gyr, acc, mag = _sensors()
    together = methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=t)
    run_many = methods.get(name).kernel.run_many
    if threaded and hasattr(run_many, "signatures"):  # numba: the threaded entry compiled
        assert run_many.signatures
    assert together.quat.shape == (5, t.size, 4)
    for s in range(gyr.shape[0]):
        alone = methods.create(name).run(gyr=gyr[s], acc=acc[s], mag=mag[s], t=t)
        np.testing.assert_array_equal(together.quat[s], alone.quat)
        np.testing.assert_array_equal(together.flags[s], alone.flags)
        for key, value in alone.outputs.items():
            np.testing.assert_array_equal(together.outputs[key][s], value)
    # the faults of sensors 1-3 are theirs alone: sensor 0 and 4 carry no data flags
    assert np.any(together.flags[1] != 0) and np.any(together.flags[3] != 0)


@pytest.mark.kernel
@pytest.mark.parametrize("name", ["robust", "bias-kf"])
def test_two_halves_over_many_sensors_equal_one_run(name):
    t, gyr, acc, mag = _sensors()
    whole = methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=t)
    est = methods.create(name)
    half = t.size // 2
    first = est.run(gyr=gyr[:, :half], acc=acc[:, :half], mag=mag[:, :half], t=t[:half])
    second = est.run(gyr=gyr[:, half:], acc=acc[:, half:], mag=mag[:, half:], t=t[half:])
    np.testing.assert_allclose(np.concatenate([first.quat, second.quat], axis=1), whole.quat,
                               rtol=0, atol=1e-12)
