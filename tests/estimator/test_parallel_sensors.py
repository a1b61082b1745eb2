"""Many sensors in one ``run`` (threads over sensors) equal each sensor run alone."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import methods, sim
from margtrack.estimator import compiled, sensor_threads
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


# (not marked kernel: threads concern the compiled kernels, which release the GIL)
@pytest.mark.parametrize(("name", "threaded"), [(m, t) for m in COMPILED for t in (False, True)])
def test_threads_over_sensors_equal_each_sensor_alone(name, threaded, monkeypatch):
    parts = []
    if threaded:  # 5 sensors in 3 threads: parts of 2, 1 and 2 sensors
        monkeypatch.setattr(compiled, "PARALLEL_MIN_SAMPLES", 0)
        monkeypatch.setattr(sensor_threads, "thread_count", lambda: 3)
    real = sensor_threads.run_threaded
    monkeypatch.setattr(compiled, "run_threaded", lambda *a, **k: parts.append(k) or real(*a, **k))
    t, gyr, acc, mag = _sensors()
    together = methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=t)
    # (an offline method runs its kernel more than once)
    expected = {"align": 1, "n_threads": None if threaded else 1}
    assert parts and all(k == expected for k in parts)
    # the threads call numba's dispatcher: it must release the GIL to run alongside
    dispatcher = methods.get(name).kernel.run
    if hasattr(dispatcher, "targetoptions"):  # (not under NUMBA_DISABLE_JIT: plain Python)
        assert dispatcher.targetoptions.get("nogil")
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
