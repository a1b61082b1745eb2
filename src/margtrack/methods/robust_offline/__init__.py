"""robust-offline: the robust filter run forwards and backwards over a whole recording.

For analysis after recording, where every sample is available (``run`` only; ``update``
refuses: a sample's estimate depends on samples after it). Four passes of the robust
filter's compiled kernel (:mod:`margtrack.methods.robust`), the same parameters:

1. forward, as ``robust``;
2. backward: time reversed (``t' = t_N - t`` read backwards), the gyro negated and
   reversed, acc and mag reversed, the bias state seeded with the forward run's final
   bias (negated) and variance. Both runs' orientations describe the same trajectory;
3. the gyro bias smoothed: per sample and axis, the inverse-variance fusion of the two
   runs' bias estimates, ``b = (b_f / P_f + b_b / P_b) / (1 / P_f + 1 / P_b)`` (the
   two-filter form of the fixed-interval smoother, Fraser & Potter 1969), variance
   ``1 / (1 / P_f + 1 / P_b)``;
4. forward and backward again on ``gyr - b(t)`` with the bias frozen; the inclination is
   the fusion of the two 6-D estimates' body-frame "up" vectors (their accelerometer
   low-pass lags cancel: the forward run's lags behind, the backward run's leads), each
   weighted by ``1 - exp(-since_start / (3 tau_acc_s))`` so a direction's start transient
   does not count; the heading that of the forward (causal) 9-D run, except just after a
   forward (re)start, where the backward run's converged heading takes over with weight
   ``exp(-since_f / tau_mag_s) (1 - exp(-since_b / tau_mag_s))``.

The kernel integrates sample i's rate over ``(t_{i-1}, t_i]``; read backwards that
interval is closed by sample i - 1, so the backward gyro is moved by one sample (without
it, the backward run is not exact on noise-free data and its inclination on BROAD is 1.07
instead of 0.62 deg). BROAD, 16 shared trials, robust defaults (nothing tuned here):
total / heading / inclination 1.88 / 1.77 / 0.58 deg; robust 2.03 / 1.82 / 0.82; offline
VQF 2.52 / 2.44 / 0.56.

Why the heading stays (mostly) causal, measured on the 16 trials: (1) the field seen
through the optical truth points north within 0.5 deg at rest but is turned by a mean
-2.1 deg (through the filter's 6-D, undisturbed trials) while the sensor moves, and its
dip changes by about 2 deg (an orientation- or position-dependent field error; BROAD's
truth heading agrees with the field at rest); (2) the 6-D heading drifts during motion by
-0.01 to +0.17 deg/s against the truth (undisturbed trials), and a plain strapdown of
the bias-smoothed gyro drifts the same (a gyro error the accelerometer cannot see, not
the filter's). A heading
low-pass with time constant ``tau_mag_s`` lags a drift ``r`` by ``r * tau_mag_s``:
forwards that lag has the opposite sign of the field's offset on most trials and cancels
it (trial 01: field -2.65 deg, lag +2.40, forward heading error -0.73 deg on average),
backwards it adds (-5.59 deg). Hence backward heading 4.02 deg against forward 1.82, and
a zero-phase heading low-pass of the field (tau 5 to 40 s) 3.4 to 5.6 deg. A data-only
magnetometer calibration (ellipsoid, and the misalignment that keeps the dip constant)
was ill-conditioned on these trials (2.0 -> 13 deg) and shifting the field by the 7 ms it
lags the gyro made robust worse (2.03 -> 2.06 deg); both dropped.

Outputs as ``robust``: ``quat`` (9-D with a magnetometer, else 6-D), ``quat6d`` (the
fused 6-D), ``gyr_bias_rad_s`` and ``gyr_bias_sd_rad_s`` (the smoothed bias and its
standard deviation, rad/s, body axes); ``flags`` are the final forward pass's (the
screening's flags are the same in both directions). Samples before either direction's
first start keep the forward pass's output.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.estimator import skeleton as kc
from margtrack.estimator.compiled import CompiledState
from margtrack.estimator.estimate import Estimate
from margtrack.estimator.flags import Flag
from margtrack.methods.robust import Robust, RobustParams

Array = NDArray[np.float64]

__all__ = ["RobustOffline"]

#: a direction's inclination counts fully once START_SCALE * tau_acc_s have passed since
#: its start (weight ``1 - exp(-since_start / (START_SCALE * tau_acc_s))``)
START_SCALE = 3.0

#: the bias is frozen in the final passes: its prior deviation (deg/s) and walk
_FROZEN = {"bias_sigma_init_deg_s": 1e-6, "bias_walk_deg_s_sqrt_s": 0.0}


def _since_start(t: Array, flags: NDArray[np.uint16]) -> Array:
    """(S, N) time since each sensor's last (re)start, s (inf before the first): a start is
    the first sample not ``INITIALISING`` after one that was, or a ``GAP``."""
    started = (flags & int(Flag.INITIALISING)) == 0
    before = np.concatenate([np.zeros_like(started[:, :1]), started[:, :-1]], axis=1)
    start = started & (~before | ((flags & int(Flag.GAP)) != 0))
    t_start = np.maximum.accumulate(np.where(start, t[None, :], -np.inf), axis=1)
    return np.where(started, t[None, :] - t_start, np.inf)


def _reversed(x: Array | None) -> Array | None:
    """(S, N, ...) read backwards in time (a contiguous copy)."""
    return None if x is None else np.ascontiguousarray(x[:, ::-1])


class RobustOffline(Robust):
    """The robust filter smoothed forwards and backwards (``--method robust-offline``).

    Same parameters as :class:`~margtrack.methods.robust.Robust` (module docstring for
    the scheme). ``run`` processes one whole series from a fresh state; a second ``run``
    without ``reset()`` raises (it cannot continue a smoothed run). Afterwards ``state``
    is the final forward pass's. ``update`` raises: the method is offline.
    """

    name = "robust-offline"
    params_type = RobustParams
    #: needs the whole series: ``update`` refuses, ``run`` is not resumable
    offline: ClassVar[bool] = True

    def update(
        self,
        gyr: ArrayLike | None,
        acc: ArrayLike,
        mag: ArrayLike | None = None,
        dt: float | None = None,
    ) -> Array:
        """Refused: robust-offline is offline (module docstring)."""
        raise TypeError(
            "robust-offline is an offline method: each estimate uses samples after it, so it "
            "needs the whole recording at once (run()); for sample-by-sample (live) "
            "updates use method 'robust'"
        )

    def _pass(
        self,
        params: RobustParams,
        t: Array,
        gyr: Array | None,
        acc: Array,
        mag: Array | None,
        seed: tuple[Array, Array] | None = None,
    ) -> tuple[Estimate, CompiledState]:
        """One run of the robust kernel on (S, N, 3) arrays; ``seed``: (bias, variance)
        (S, 3) the sensors start with (their first start then keeps them)."""
        inner = Robust(params, rate_hz=self.rate_hz)
        if seed is not None:
            state = inner._new_rows(acc.shape[0])
            for name, value in (
                ("gyr_bias_rad_s", seed[0]),
                ("bias_var_rad2_s2", seed[1]),
                ("gyr_bias_sd_rad_s", np.sqrt(seed[1])),
            ):
                offset, width = state.layout[name]
                state.rows[:, offset : offset + width] = value
            state.rows[:, kc.K_STARTS] = 1.0  # the first start keeps the seeded bias
            inner._state = state
        est = Robust._run_arrays(inner, gyr, acc, mag, t, check_units=False)
        return est, inner._state  # type: ignore[return-value]

    def _both(
        self,
        params: RobustParams,
        t: Array,
        gyr: Array,
        acc: Array,
        mag: Array | None,
        seed_from_forward: bool,
    ) -> tuple[Estimate, CompiledState, Estimate]:
        """Forward then backward; the backward Estimate is put back in forward time order
        (its bias negated back)."""
        fwd, state = self._pass(params, t, gyr, acc, mag)
        seed = None
        if seed_from_forward:
            seed = (-state.get("gyr_bias_rad_s"), state.get("bias_var_rad2_s2"))
        t_back = np.ascontiguousarray(t[-1] - t[::-1])
        # the kernel integrates sample i's rate over (t_{i-1}, t_i]; read backwards, that
        # interval is closed by sample i - 1, so the reversed rates move by one sample to
        # integrate each interval with the same rate as the forward run
        gyr_back = -_reversed(gyr)  # type: ignore[operator]
        gyr_back[:, 1:] = gyr_back[:, :-1].copy()
        back, _ = self._pass(params, t_back, gyr_back, _reversed(acc), _reversed(mag), seed)
        outputs = {k: _reversed(v) for k, v in back.outputs.items()}
        outputs["since_start_s"] = _reversed(_since_start(t_back, back.flags))  # type: ignore[arg-type]
        outputs["gyr_bias_rad_s"] = -outputs["gyr_bias_rad_s"]  # type: ignore[operator]
        back = dataclasses.replace(
            back, quat=_reversed(back.quat), t=t, outputs=outputs, flags=_reversed(back.flags)
        )
        fwd.outputs["since_start_s"] = _since_start(t, fwd.flags)  # type: ignore[index, arg-type]
        return fwd, state, back

    def _run_arrays(
        self,
        gyr: ArrayLike | None,
        acc: ArrayLike,
        mag: ArrayLike | None,
        t: Array,
        *,
        check_units: bool,
    ) -> Estimate:
        if self._state is not None:
            raise ValueError(
                "robust-offline smooths one whole recording per run and cannot continue from "
                "an earlier run's state (a recording run in pieces would be smoothed piece by "
                "piece); call reset() before the next recording, and run a recording in one "
                "piece (or use method 'robust', which continues exactly)"
            )
        x = self._validated(gyr, acc, mag, t, check_units=check_units)
        if x.gyr is None:  # pragma: no cover - uses_gyr: _validated refuses it
            raise ValueError("robust-offline needs gyroscope data (gyr)")
        params = self._params
        # 1-2: forward and backward with the bias estimated
        fwd, _, back = self._both(params, x.t, x.gyr, x.acc, x.mag, seed_from_forward=True)
        # 3: the smoothed bias (two-filter form); a zero variance cannot occur (> walk * dt)
        b_f, b_b = fwd.outputs["gyr_bias_rad_s"], back.outputs["gyr_bias_rad_s"]
        w_f = 1.0 / np.maximum(fwd.outputs["gyr_bias_sd_rad_s"], 1e-12) ** 2
        w_b = 1.0 / np.maximum(back.outputs["gyr_bias_sd_rad_s"], 1e-12) ** 2
        bias = (b_f * w_f + b_b * w_b) / (w_f + w_b)
        bias_sd = np.sqrt(1.0 / (w_f + w_b))
        # 4: forward and backward on the corrected gyro, the bias frozen
        frozen = dataclasses.replace(params, **_FROZEN)
        fwd2, state, back2 = self._both(
            frozen, x.t, x.gyr - bias, x.acc, x.mag, seed_from_forward=False
        )
        q6_f, q6_b = fwd2.outputs["quat6d"], back2.outputs["quat6d"]
        up = frames.up(params.frame)
        # each direction's weight grows as its start transient (tilt of one start sample,
        # taken out with the time constant tau_acc_s) decays
        tau = START_SCALE * params.tau_acc_s
        w_f = -np.expm1(-fwd2.outputs["since_start_s"] / tau)[..., None]
        w_b = -np.expm1(-back2.outputs["since_start_s"] / tau)[..., None]
        u = w_f * quat.rotate_inverse(q6_f, up) + w_b * quat.rotate_inverse(q6_b, up)
        norm = np.linalg.norm(u, axis=-1, keepdims=True)
        started = np.isfinite(fwd2.outputs["since_start_s"])
        started &= np.isfinite(back2.outputs["since_start_s"])
        fuse = started & (norm[..., 0] > 1e-6)
        u = np.where(fuse[..., None], u / np.where(norm > 1e-6, norm, 1.0), 0.0)
        arc = quat.shortest_arc(quat.rotate(q6_f, np.where(fuse[..., None], u, up)), up)
        arc = np.where(fuse[..., None], arc, quat.identity(arc.shape[:-1]))
        q6 = quat.normalize(quat.multiply(arc, q6_f))
        # the forward run's heading (a rotation about the vertical) on the fused 6-D; just
        # after a forward (re)start, while its heading is still converging (tau_mag_s), the
        # backward run's heading where that one has converged
        heading = quat.multiply(fwd2.quat, quat.conjugate(q6_f))
        if x.mag is not None:
            other = quat.multiply(back2.quat, quat.conjugate(q6_f))
            vertical = np.sum(other[..., 1:] * up, axis=-1)
            yaw_b = 2.0 * np.arctan2(vertical, other[..., 0])
            yaw_f = 2.0 * np.arctan2(np.sum(heading[..., 1:] * up, axis=-1), heading[..., 0])
            since_f = fwd2.outputs["since_start_s"]
            since_b = back2.outputs["since_start_s"]
            w = np.exp(-since_f / params.tau_mag_s) * -np.expm1(-since_b / params.tau_mag_s)
            w = np.where(np.isfinite(since_f) & np.isfinite(since_b), w, 0.0)
            yaw = yaw_f + w * (np.mod(yaw_b - yaw_f + np.pi, 2.0 * np.pi) - np.pi)
            heading = quat.from_axis_angle(up, yaw)
        q9 = quat.normalize(quat.multiply(heading, q6))
        self._state = state
        self._last_flags = fwd2.flags[:, -1].copy()  # type: ignore[index]
        self._flag_one = None
        outputs: dict[str, NDArray[Any]] = {
            "quat6d": q6,
            "gyr_bias_rad_s": bias,
            "gyr_bias_sd_rad_s": bias_sd,
        }
        return Estimate(
            quat=q9,
            t=x.t.copy(),
            frame=params.frame,
            method=self.name,
            params=dict(self._params_dict),
            outputs=outputs,
            flags=fwd2.flags,
        )
