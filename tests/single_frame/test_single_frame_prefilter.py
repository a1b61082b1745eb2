"""The low-pass prefilter (002 Fig. 5): against scipy.signal, inside every estimator."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.estimator.lowpass import coefficients, lowpass
from margtrack.single_frame.davenport import Davenport
from margtrack.single_frame.fqa import Fqa
from margtrack.single_frame.gauss_newton import GaussNewton, Newton
from margtrack.single_frame.prefilter import LowpassParams
from margtrack.single_frame.quest import Quest
from margtrack.single_frame.triad import Triad

pytestmark = pytest.mark.kernel

CLASSES = [Triad, Fqa, Quest, Davenport, GaussNewton, Newton]
# the screening's norm/dip gate wide open: screened raw and screened filtered fields would
# otherwise drop different noisy samples
OPEN = {"mag_norm_tol": 10.0, "mag_dip_tol_deg": 180.0}


def _filter(x, dt, cutoff, order):
    out = np.empty_like(x)
    lowpass(x, dt, cutoff, order, np.zeros((x.shape[0], 4, 3)), np.zeros(x.shape[0], bool), out)
    return out


@pytest.mark.parametrize("order", [1, 2])
def test_coefficients_are_scipy_butterworth(order):
    b, a = signal.butter(order, 7.0, fs=200.0)
    ours = coefficients(7.0, 1.0 / 200.0, order)
    np.testing.assert_allclose(ours[: order + 1], b, rtol=1e-13)
    np.testing.assert_allclose(ours[3 : 3 + order], a[1:], rtol=1e-13, atol=1e-15)
    # -3 dB at the cut-off: |H(e^{jω_c})| = 1/√2
    _, h = signal.freqz(b, a, worN=[7.0], fs=200.0)
    assert abs(h[0]) == pytest.approx(np.sqrt(0.5), rel=1e-12)


@pytest.mark.parametrize("order", [1, 2])
def test_lowpass_kernel_equals_scipy_lfilter_started_in_steady_state(order):
    rng = np.random.default_rng(1)
    x = rng.normal(size=(2, 500, 3)) + [1.0, -2.0, 9.0]
    b, a = signal.butter(order, 5.0, fs=100.0)
    expected = np.empty_like(x)
    for s in range(2):
        zi = signal.lfilter_zi(b, a)[:, None] * x[s, 0]
        expected[s], _ = signal.lfilter(b, a, x[s], axis=0, zi=zi)
    np.testing.assert_allclose(_filter(x, np.full(500, 0.01), 5.0, order), expected, atol=1e-12)


def test_coefficients_follow_irregular_sample_times():
    rng = np.random.default_rng(2)
    dt = rng.uniform(0.004, 0.012, 300)
    x = rng.normal(size=(1, 300, 3))
    got = _filter(x, dt, 8.0, 2)
    y = np.empty((300, 3))
    hist = [x[0, 0]] * 2 + [x[0, 0]] * 2  # x1, x2, y1, y2
    y[0] = x[0, 0]
    for i in range(1, 300):
        b, a = signal.butter(2, 8.0, fs=1.0 / dt[i])
        y[i] = b[0] * x[0, i] + b[1] * hist[0] + b[2] * hist[1] - a[1] * hist[2] - a[2] * hist[3]
        hist = [x[0, i], hist[0], y[i], hist[2]]
    np.testing.assert_allclose(got[0], y, atol=1e-12)


def _signals(n=400, seed=3):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    q = quat.from_rotvec(np.c_[np.sin(t), 0.5 * t, np.cos(2 * t)])
    acc = quat.rotate_inverse(q, frames.gravity_reference("ENU"))
    acc += rng.normal(scale=1.0, size=(n, 3))
    mag = quat.rotate_inverse(q, frames.mag_reference("ENU", 60.0, 50.0)) + rng.normal(
        scale=3.0, size=(n, 3))
    return t, acc, mag


@pytest.mark.parametrize("cls", CLASSES)
def test_estimator_with_prefilter_equals_estimator_on_prefiltered_signals(cls):
    t, acc, mag = _signals()
    dt = np.r_[0.0, np.diff(t)]
    filtered = cls(acc_lowpass_hz=4.0, mag_lowpass_hz=2.0, lowpass_order=1, **OPEN).run(
        acc=acc, mag=mag, t=t)
    acc_f = _filter(acc[None], dt, 4.0, 1)[0]
    mag_f = _filter(mag[None], dt, 2.0, 1)[0]
    plain = cls(**OPEN).run(acc=acc_f, mag=mag_f, t=t)
    np.testing.assert_allclose(filtered.quat, plain.quat, atol=1e-12)


def test_prefilter_reduces_the_effect_of_acceleration_noise():
    t, acc, mag = _signals(2000, seed=4)
    q_true = quat.from_rotvec(np.c_[np.sin(t), 0.5 * t, np.cos(2 * t)])
    raw = Fqa().run(acc=acc, mag=mag, t=t)
    smooth = Fqa(acc_lowpass_hz=2.0, mag_lowpass_hz=2.0).run(acc=acc, mag=mag, t=t)
    rms = lambda q: np.sqrt(np.mean(quat.angle_between(q, q_true)[200:] ** 2))  # noqa: E731
    assert rms(smooth.quat) < 0.5 * rms(raw.quat)


def test_turning_the_filter_on_mid_run_starts_it_at_that_sample():
    t, acc, mag = _signals(50)
    est = Triad(**OPEN)
    est.run(acc=acc[:20], mag=mag[:20], t=t[:20])
    est.set_params(acc_lowpass_hz=3.0)
    out = est.run(acc=acc[20:], mag=mag[20:], t=t[20:])
    expected = Triad(acc_lowpass_hz=3.0, **OPEN).run(acc=acc[20:], mag=mag[20:], t=t[20:])
    np.testing.assert_allclose(out.quat, expected.quat, atol=1e-14)


def test_cutoff_at_or_above_nyquist_is_refused_naming_the_parameter():
    t, acc, mag = _signals(20)
    with pytest.raises(ValueError, match=r"acc_lowpass_hz = 50.0 Hz is not below half"):
        Fqa(acc_lowpass_hz=50.0).run(acc=acc, mag=mag, t=t)
    with pytest.raises(ValueError, match=r"mag_lowpass_hz = 60.0 Hz"):
        Quest(mag_lowpass_hz=60.0).run(acc=acc, mag=mag, t=t)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"acc_lowpass_hz": 0.0}, "parameter acc_lowpass_hz must be a finite number, > 0 Hz"),
        ({"mag_lowpass_hz": -2.0}, "parameter mag_lowpass_hz must be a finite number, > 0 Hz"),
        ({"acc_lowpass_hz": float("inf")}, "parameter acc_lowpass_hz must be a finite number"),
        ({"lowpass_order": 3}, "parameter lowpass_order must be a finite number, >= 1 and <= 2"),
        ({"lowpass_order": 1.5}, "parameter lowpass_order must be a whole number"),
    ],
)
def test_prefilter_parameters_are_validated(kwargs, message):
    with pytest.raises(ValueError, match=message):
        LowpassParams(**kwargs)
