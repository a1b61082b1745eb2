"""Sensors run in lockstep blocks (``estimator/lockstep.py``) equal each sensor run alone.

Bit for bit: the lockstep path gives each sensor the same arithmetic in the same order,
whatever the faults, (re)starts and clock events of its data, and whichever lane and block
it lands in.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from margtrack import io, methods, sim
from margtrack.estimator import compiled, jit, restart_kernel, sensor_threads
from margtrack.estimator import lockstep as contract_lanes
from margtrack.estimator import screen_kernel as screen
from margtrack.estimator.flags import Flag
from margtrack.estimator.jit import njit
from margtrack.estimator.skeleton import K_READY, K_SCREEN, N_CONTRACT, N_SCOEF

#: every online method with lockstep blocks (``contract.entry_points``) that runs without a
#: magnetometer too (smoother and bachmann-accmag run on those of robust and bachmann)
LOCKSTEP = [r.name for r in methods.RECORDS
            if r.online and getattr(methods.get(r.name), "mag_optional", False)
            and getattr(getattr(methods.get(r.name), "kernel", None), "lanes", None) is not None]
#: one full block and a partial one, so lanes at both ends of a block are checked
N_SENSORS = contract_lanes.LANES + 5
BROAD = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "broad"


def _faulty_sensors(n_sensors: int = N_SENSORS, duration_s: float = 12.0):
    """Simulated sensors with one kind of fault each, and a clock with a gap, a repeated
    timestamp and a reset back."""
    recs = [sim.simulate_motion("random", duration_s=duration_s, rate_hz=100.0, seed=s)
            for s in range(n_sensors)]
    gyr = np.stack([r.gyr for r in recs])
    acc = np.stack([r.acc for r in recs])
    mag = np.stack([r.mag for r in recs])
    t = recs[0].t.copy()
    gyr[1, 40:45] = np.nan  # invalid rate: the last good one is held
    acc[2, 80:90] = 0.0  # no acceleration
    gyr[3, 120] = 1e9  # clipped rate
    mag[4, 150:] = 0.0  # the field dies
    mag[5, 200:900, 1] = mag[5, 200, 1]  # one field axis stuck while turning
    mag[6, 300:700] *= 3.0  # a disturbed field, then a new steady one
    mag[7, 400:420] *= 100.0  # absurd field samples
    acc[8, 500:520] = 1e6  # acceleration beyond any range
    mag[9, :60] = np.nan  # no field at the start: the start waits for one
    acc[10, :30] = np.nan  # no acceleration at the start either
    if n_sensors > contract_lanes.LANES:
        mag[contract_lanes.LANES, 100:200] = np.inf  # the first lane of the second block
    t[600:] += 2.0  # a gap: every sensor restarts
    t[800] = t[799]  # a repeated timestamp: skipped
    t[1000:] -= 5.0  # the clock jumps back: a reset
    return t, gyr, acc, mag


def _assert_each_alone(name, t, gyr, acc, mag, together, **params):
    for s in range(acc.shape[0]):
        alone = methods.create(name, params).run(
            gyr=gyr[s], acc=acc[s], mag=None if mag is None else mag[s], t=t, check_units=False
        )
        np.testing.assert_array_equal(together.quat[s], alone.quat, err_msg=f"sensor {s}")
        np.testing.assert_array_equal(together.flags[s], alone.flags, err_msg=f"sensor {s}")
        for key, value in alone.outputs.items():
            np.testing.assert_array_equal(together.outputs[key][s], value, err_msg=key)


@pytest.mark.kernel
@pytest.mark.parametrize("name", LOCKSTEP)
def test_lockstep_is_the_path_for_many_sensors(name, monkeypatch):
    """From LANES_MIN_SENSORS sensors the kernel's ``lanes`` runs them, whole blocks per
    thread; below, ``run`` one sensor after the other."""
    calls = []
    kernel = methods.get(name).kernel
    for entry in ("run", "lanes"):
        real = getattr(kernel, entry)
        monkeypatch.setattr(kernel, entry,
                            lambda *a, _e=entry, _r=real: calls.append(_e) or _r(*a))
    aligns = []
    real_threaded = compiled.run_threaded
    monkeypatch.setattr(compiled, "run_threaded",
                        lambda part, n, **k: aligns.append(k["align"]) or real_threaded(part, n,
                                                                                         **k))
    t, gyr, acc, mag = _faulty_sensors(n_sensors=compiled.LANES_MIN_SENSORS)
    methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=t)
    assert set(calls) == {"lanes"} and set(aligns) == {contract_lanes.LANES}  # (offline: passes)
    calls.clear()
    aligns.clear()
    methods.create(name).run(gyr=gyr[1:], acc=acc[1:], mag=mag[1:], t=t)
    assert set(calls) == {"run"} and set(aligns) == {1}


def _assert_same_run(a, b):
    np.testing.assert_array_equal(a.quat, b.quat)
    np.testing.assert_array_equal(a.flags, b.flags)
    for key, value in a.outputs.items():
        np.testing.assert_array_equal(b.outputs[key], value, err_msg=key)


@pytest.mark.kernel
@pytest.mark.parametrize(
    ("name", "params"),
    [("gradient", {}), ("gradient", {"mag_objective": "fixed", "frame": "NED"}),
     ("gradient", {"mag_objective": "madgwick", "integration": "euler"}),
     ("gradient", {"mag_objective": "forward_measured"}),
     ("bachmann", {}), ("bachmann", {"correction_interval": 3, "round_robin": True}),
     ("bachmann", {"mag_reference": (0.0, 0.5, -0.8), "gravity_reference": (0.0, 0.1, 1.0),
                   "gyr_null_rest_s": 0.0, "frame": "NED"}),
     ("bachmann-accmag", {}),
     ("robust", {}), ("robust", {"frame": "NED", "mag_norm_ref": 50.0}),
     ("robust", {"converge_s": 0.0, "rest_min_s": 0.2})],
)
def test_lockstep_equals_sensor_by_sensor_under_faults(name, params, monkeypatch):
    if params and os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        pytest.skip("without the JIT, each method's default options only: the blocks run the "
                    "same Python for every option set, whose branches the method's own kernel "
                    "tests run")
    t, gyr, acc, mag = _faulty_sensors()
    together = methods.create(name, params).run(gyr=gyr, acc=acc, mag=mag, t=t,
                                                check_units=False)
    # the faults were seen (else the comparison proves little)
    flags = together.flags
    assert np.any(flags[1] != 0) and np.any(flags[5] != 0) and np.any(flags[6] != 0)
    assert np.any(flags[contract_lanes.LANES] != 0) and not np.any(flags[0, :590] != 0)
    # the same sensors through contract.run_series, one after the other
    monkeypatch.setattr(compiled, "LANES_MIN_SENSORS", 10**9)
    one_by_one = methods.create(name, params).run(gyr=gyr, acc=acc, mag=mag, t=t,
                                                  check_units=False)
    _assert_same_run(one_by_one, together)
    # (round robin: a sensor's turn is its index; with numba's JIT off the kernels run as
    # Python, where the comparison with one_by_one above has checked the same code)
    if not params.get("round_robin") and os.environ.get("NUMBA_DISABLE_JIT", "0") in ("", "0"):
        _assert_each_alone(name, t, gyr, acc, mag, together, **params)


# (not marked kernel, nor the BROAD test below: threads and real data concern the compiled
# blocks; without the JIT the faults test above runs the same Python)
@pytest.mark.parametrize("name", LOCKSTEP)
def test_lockstep_threads_and_halves_equal_one_run(name, monkeypatch):
    t, gyr, acc, mag = _faulty_sensors()
    alone = methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=t, check_units=False)
    monkeypatch.setattr(compiled, "PARALLEL_MIN_SAMPLES", 0)  # blocks shared among threads
    monkeypatch.setattr(sensor_threads, "thread_count", lambda: 2)  # a block each
    threaded = methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=t, check_units=False)
    np.testing.assert_array_equal(threaded.quat, alone.quat)
    np.testing.assert_array_equal(threaded.flags, alone.flags)
    # the state goes back to the rows: a run continued in a second call is the same run
    est = methods.create(name)
    half = 350
    first = est.run(gyr=gyr[:, :half], acc=acc[:, :half], mag=mag[:, :half], t=t[:half],
                    check_units=False)
    second = est.run(gyr=gyr[:, half:], acc=acc[:, half:], mag=mag[:, half:], t=t[half:],
                     check_units=False)
    np.testing.assert_array_equal(np.concatenate([first.quat, second.quat], axis=1), alone.quat)


@pytest.mark.kernel
@pytest.mark.parametrize("name", LOCKSTEP)
def test_lockstep_without_magnetometer_equals_each_sensor_alone(name):
    t, gyr, acc, _ = _faulty_sensors(n_sensors=compiled.LANES_MIN_SENSORS + 1)
    together = methods.create(name).run(gyr=gyr, acc=acc, t=t, check_units=False)
    _assert_each_alone(name, t, gyr, acc, None, together)


@pytest.mark.skipif(not (BROAD.is_dir() and any(BROAD.glob("*.hdf5"))),
                    reason="BROAD trials not in ../shared/data/broad")
@pytest.mark.parametrize("name", LOCKSTEP)
def test_lockstep_equals_each_sensor_alone_on_broad(name):
    trials = io.broad_trials(BROAD)
    rng = np.random.default_rng(3)
    n, windows = 1500, []
    for k in range(N_SENSORS):
        rec = io.read_broad(trials[k % len(trials)].path)
        i = int(rng.integers(0, rec.t.size - n))
        windows.append((rec.gyr[i:i + n], rec.acc[i:i + n], rec.mag[i:i + n]))
    gyr, acc, mag = (np.stack([w[c] for w in windows]) for c in range(3))
    t = np.arange(n) / 285.714
    together = methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=t)
    _assert_each_alone(name, t, gyr, acc, mag, together)


@njit(inline="always")
def _null_start_at(st, o, lanes, coef, first, qw, qx, qy, qz):
    """Nothing to set: the trivial method has no state of its own."""


@njit(inline="always")
def _null_step_at(st, o, lanes, coef, dt, g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, qa, qo,
                  xa, xo, outs, steady):
    qa[qo], qa[qo + outs], qa[qo + 2 * outs], qa[qo + 3 * outs] = g0 + a0, g1 + a1, m0 + m2, dt
    return 0


@njit(inline="always")
def _null_hold_at(st, o, lanes, coef, xa, xo, outs):
    """No extra outputs to hold."""


@njit(inline="always")
def _null_rare_at(st, o, lanes, coef, dt, has_mag, a0, a1, a2, m0, m1, m2):
    return False


@njit(error_model="numpy", _nrt=False)
def _null_scalar(st, o, n_row, coef, scoef, dt, has_mag):
    contract_lanes._scalar(_null_start_at, _null_step_at, _null_hold_at,
                           restart_kernel.no_own_field, st, o, n_row, coef, scoef, dt, has_mag)


@njit(error_model="numpy", _nrt=False)
def _null_block(st, rows, s0, coefs, dts, ks, tflags, gyr, acc, mag, has, q_out, x_out,
                flags_out, frame_major, s_in):
    scoef = jit.to_fixed_tuple(coefs, N_SCOEF)
    contract_lanes.block(_null_scalar, _null_step_at, _null_rare_at, N_CONTRACT, 0, st, rows,
                         s0, scoef, scoef, dts, ks, tflags, gyr, acc, mag, has, q_out, x_out,
                         flags_out, frame_major, s_in)


@pytest.mark.kernel
def test_lockstep_screening_equals_the_screening_alone():
    """The framework and the screening of a lockstep block, whether the method reads a field
    or not: a method with a trivial step, on faulty sensors, sees the samples, flags and
    screening state of the screening run sensor by sensor."""
    block = _null_block
    t, gyr, acc, mag = _faulty_sensors(n_sensors=contract_lanes.LANES)
    dts, tflags = np.empty(t.size), np.empty(t.size, np.int64)
    screen.screen_time(t, np.nan, 0.5, dts, tflags)
    ks = np.array([screen.ref_gain(d) for d in dts])
    coefs = methods.create("gradient")._coefs[:N_SCOEF]
    for has in (3, 2):  # with and without a field
        rows = np.zeros((gyr.shape[0], N_CONTRACT))
        screen.fresh(rows[:, K_SCREEN:])
        rows[:, K_READY] = 1.0  # started: no TRIAD start, every sample through the step
        q = np.empty((gyr.shape[0], t.size, 4))
        flags = np.empty((gyr.shape[0], t.size), np.uint16)
        block(np.empty((N_CONTRACT + contract_lanes.N_B) * contract_lanes.LANES), rows, 0,
              coefs, dts, ks, tflags, gyr, acc, mag, has, q, np.empty((gyr.shape[0], t.size, 0)),
              flags, False, 0)
        sc = np.empty((gyr.shape[0], screen.N_SCREEN))
        screen.fresh(sc)
        outs = [np.empty_like(gyr) for _ in range(3)]
        alone_flags = np.empty(flags.shape, np.uint16)
        screen.screen_samples(coefs, dts, tflags, gyr, acc, mag, has & 1 != 0, True, sc, *outs,
                              alone_flags)
        g, a, m = outs
        # a gap unreadies every lane: the step is skipped at the gap (a first start steps
        # its sample with dt 0) and over a restart's window (INITIALISING: restart_kernel),
        # whose last sample steps with the window's mean measurements
        gaps = (tflags & screen.GAP) != 0
        window = (flags & Flag.INITIALISING) != 0
        restart = ~window & np.concatenate([np.zeros_like(window[:, :1]), window[:, :-1]], 1)
        stepped = ~gaps[None, :] & ~window & ~restart
        assert window.any() and stepped.mean() > 0.9
        np.testing.assert_array_equal(q[..., 0][stepped], (g[..., 0] + a[..., 0])[stepped])
        np.testing.assert_array_equal(q[..., 2][stepped], (m[..., 0] + m[..., 2])[stepped])
        restart_flags = np.uint16(Flag.INITIALISING | Flag.HEADING_CARRIED)
        np.testing.assert_array_equal((flags & ~restart_flags)[:, ~gaps], alone_flags[:, ~gaps])
        np.testing.assert_array_equal(rows[:, K_SCREEN:K_SCREEN + screen.N_SCREEN], sc)
