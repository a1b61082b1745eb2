"""robust-offline: the forward-backward robust filter, and offline VQF beside it."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import methods, sim
from margtrack import quaternion as quat
from margtrack.accuracy import error_series
from margtrack.bench.runner import evaluate
from margtrack.estimator import Flag
from margtrack.methods.robust import Robust
from margtrack.methods.robust_offline import RobustOffline, _since_start

BIAS_RAD_S = np.radians([0.4, -0.25, 0.3])


def _static_with_bias(seconds: float = 20.0):
    return sim.simulate(
        sim.static(seconds, 100.0),
        gyr_errors=sim.SensorErrors(noise_density=np.radians(0.01), bias=BIAS_RAD_S),
        seed=2,
    )


@pytest.mark.kernel
def test_registered_and_update_refused_with_the_reason():
    est = methods.create("robust-offline", rate_hz=100.0)
    assert isinstance(est, RobustOffline)
    with pytest.raises(TypeError, match=r"offline method.*whole recording.*'robust'"):
        est.update(np.zeros(3), np.array([0.0, 0.0, 9.81]), np.array([0.0, 20.0, -40.0]))


@pytest.mark.kernel
def test_a_second_run_without_reset_is_refused_not_smoothed_piecewise():
    rec = _static_with_bias(5.0)
    est = RobustOffline()
    first = est.run(rec)
    with pytest.raises(ValueError, match=r"whole recording per run.*reset\(\)"):
        est.run(rec)
    est.reset()
    again = est.run(rec)
    assert np.array_equal(first.quat, again.quat)


@pytest.mark.kernel
def test_the_backward_pass_gives_the_bias_from_the_first_sample():
    # at rest with a constant bias: the causal filter starts from bias 0 and learns it
    # after rest_min_s; the smoother knows it at sample 0 from the backward pass
    rec = _static_with_bias()
    fwd = Robust().run(rec)
    off = RobustOffline().run(rec)
    assert np.all(fwd.outputs["gyr_bias_rad_s"][0] == 0.0)
    # white noise 0.01 deg/s/√Hz through the 0.5 s rest low-pass: sd 0.007 deg/s; 3 sigma
    err = np.degrees(off.outputs["gyr_bias_rad_s"] - BIAS_RAD_S)
    assert np.all(np.abs(err[0]) < 0.02) and np.all(np.abs(err[-1]) < 0.02)
    # two independent estimates fused: the variance is below either direction's
    assert np.all(off.outputs["gyr_bias_sd_rad_s"] <= fwd.outputs["gyr_bias_sd_rad_s"] + 1e-15)
    # and so the orientation does not drift while the causal filter learns the bias
    e_off = np.degrees(error_series(off.quat, rec.quat_true).total_rad)
    e_fwd = np.degrees(error_series(fwd.quat, rec.quat_true).total_rad)
    assert e_off.max() < 0.1 < e_fwd.max()


@pytest.mark.kernel
def test_it_is_acausal_where_robust_is_causal():
    traj = sim.random_motion(30.0, 100.0, seed=5, max_rate_deg_s=120.0, bandwidth_hz=0.5)
    rec = sim.simulate(traj, gyr_errors=sim.SensorErrors(bias=np.radians([0.3, 0.2, -0.2])),
                       seed=3)
    late = rec.gyr.copy()
    late[2000:] += np.radians(1.0)  # a change after 20 s
    changed = type(rec)(t=rec.t, gyr=late, acc=rec.acc, mag=rec.mag, quat_true=rec.quat_true)
    for cls, causal in ((Robust, True), (RobustOffline, False)):
        a, b = cls().run(rec).quat[:2000], cls().run(changed).quat[:2000]
        moved = np.degrees(quat.angle_between(a, b)).max()
        assert (moved < 1e-9) if causal else (moved > 1e-3), (cls.name, moved)


@pytest.mark.kernel
def test_simulated_motion_in_both_frames_is_as_good_as_the_causal_filter():
    traj = sim.random_motion(60.0, 100.0, seed=4, max_rate_deg_s=150.0, bandwidth_hz=1.0)
    for frame in ("ENU", "NED"):
        rec = sim.simulate(traj, frame=frame, seed=0)
        off = RobustOffline(frame=frame).run(rec)
        fwd = Robust(frame=frame).run(rec)
        rmse = [np.degrees(np.sqrt(np.mean(error_series(e.quat, rec.quat_true, frame, frame)
                                           .total_rad ** 2))) for e in (off, fwd)]
        # noise-free apart from the simulator's default noise: both well under a degree,
        # and the smoother no worse than the filter it smooths
        assert rmse[0] < 1.0 and rmse[0] <= rmse[1] + 0.05, (frame, rmse)
        assert np.allclose(np.linalg.norm(off.quat, axis=-1), 1.0)


@pytest.mark.kernel
def test_two_sensors_at_once_equal_each_alone():
    recs = [_static_with_bias(10.0), sim.simulate(sim.static(10.0, 100.0), seed=7)]
    both = RobustOffline().run(recs)
    for s, rec in enumerate(recs):
        alone = RobustOffline().run(rec)
        assert np.allclose(both.quat[s], alone.quat, atol=1e-12)
        assert np.allclose(both.outputs["gyr_bias_rad_s"][s], alone.outputs["gyr_bias_rad_s"],
                           atol=1e-15)


@pytest.mark.kernel
def test_bad_samples_are_flagged_skipped_and_the_output_stays_aligned():
    rec = _static_with_bias(10.0)
    gyr, t = rec.gyr.copy(), rec.t.copy()
    gyr[300] = np.nan  # a non-finite rate
    t[600:] += 5.0  # a 5 s gap: a restart in both directions
    est = RobustOffline().run(gyr=gyr, acc=rec.acc, mag=rec.mag, t=t)
    assert est.quat.shape == (rec.n_samples, 4) and np.all(np.isfinite(est.quat))
    assert est.flags[300] & Flag.INVALID
    assert est.flags[600] & Flag.GAP
    # the restart keeps the bias, and the smoothed bias holds across the gap
    assert np.all(np.abs(np.degrees(est.outputs["gyr_bias_rad_s"][[0, 599, 600, -1]]
                                    - BIAS_RAD_S)) < 0.03)
    # timestamps going back: flagged (CLOCK) and skipped by both directions
    t2 = rec.t.copy()
    t2[400] = t2[398]
    est2 = RobustOffline().run(gyr=rec.gyr, acc=rec.acc, mag=rec.mag, t=t2)
    assert est2.flags[400] & Flag.CLOCK and np.all(np.isfinite(est2.quat))
    with pytest.raises(ValueError, match="acc_unit='g'"):
        RobustOffline().run(gyr=rec.gyr, acc=rec.acc / 9.80665, mag=rec.mag, t=rec.t)


@pytest.mark.kernel
def test_since_start_counts_from_each_start_and_restart():
    t = np.arange(8) * 0.5
    init, gap = int(Flag.INITIALISING), int(Flag.GAP)
    flags = np.array([[init, init, 0, 0, gap, 0, 0, 0]], dtype=np.uint16)
    since = _since_start(t, flags)[0]
    assert np.all(np.isinf(since[:2]))
    assert np.allclose(since[2:], [0.0, 0.5, 0.0, 0.5, 1.0, 1.5])


# (not marked kernel: an accuracy figure on real data, the kernels' arithmetic is the
# tests' above)
def test_on_a_broad_trial_it_beats_robust_and_offline_vqf(broad_folder):
    from margtrack.io import read_broad

    rec = read_broad(next(broad_folder.glob("08_*.hdf5"))).slice(0, 20000)  # 70 s, fast
    off = evaluate(methods.get("robust-offline")(), rec)
    fwd = evaluate(methods.get("robust")(), rec)
    # measured 5.69 / 1.10 deg against robust's 6.35 / 1.88 deg (inclination smoothed)
    assert off.total_rmse_deg < fwd.total_rmse_deg
    assert off.inclination_rmse_deg < fwd.inclination_rmse_deg - 0.2
    pytest.importorskip("vqf", reason="offline VQF is the peer (pip install vqf)")
    from margtrack.bench.external import EXTERNAL

    peer = evaluate(EXTERNAL["vqf-offline"], rec)
    assert np.isfinite(peer.total_rmse_deg) and peer.n_scored == off.n_scored


@pytest.mark.kernel
def test_the_live_engine_refuses_it_before_the_first_sample():
    from margtrack.live.engine import Engine
    from margtrack.live.replay import ReplaySource

    rec = _static_with_bias(1.0)
    source = ReplaySource(rec.t, rec.gyr[None], rec.acc[None], rec.mag[None], ["s0"])
    with pytest.raises(ValueError, match=r"'robust-offline' is offline.*'robust'"):
        Engine(source.info, "robust-offline")


@pytest.mark.kernel
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
