"""A Kalman filter forwards and a Rauch-Tung-Striebel pass backwards over a whole recording.

For analysis after recording (``run`` only). Every sample's orientation and gyro bias use
the whole recording, before and after it, as a fixed-interval smoother does: no lag in
the inclination's accelerometer low-pass or the heading's field low-pass, and the gyro
bias of the start known from the data after it. The scheme (kernel module docstring):

1. ``robust`` forward, for what it detects: rest (``REST``, where the gyro measures its
   bias), rejected field disturbances (``MAG_DISTURBED``, the field not used), the input
   screening's flags, and the orientation each (re)start begins from;
2. the accelerometer low-passed with zero phase (``acc_lowpass_hz``) in the level frame of
   ``robust``'s 6-D orientation, where gravity is fixed, and carried back into the body: a
   limb's acceleration, which turns with the sensor, does not leak into the inclination
   (``kernel.lowpassed_acc``; docs/methods.md);
3. an error-state Kalman filter over the orientation error in the earth frame and the gyro
   bias, forward, storing its filtered and predicted states;
4. the Rauch-Tung-Striebel backward pass over them.

The filter's noise follows from ``robust``'s parameters, so both have the same time
constants: a random walk of the orientation of density ``q_θ`` (``motion_walk_deg_s_sqrt_hz``)
against a measurement of variance ``r`` per sample of interval ``dt`` is a first-order
low-pass of time constant ``τ = sqrt(r dt / q_θ)`` (the steady-state Kalman-Bucy gain), so
``r_acc = tau_acc_s² q_θ / dt`` and ``r_mag = tau_mag_s² q_θ / dt``. At rest (``robust``'s
``REST``) the orientation walks with the gyro's white noise only
(``gyr_noise_deg_s_sqrt_hz``) and both variances scale with it, the time constants staying
the same (with the motion's variances at rest, the field's heading there would take a
time constant fifty times longer, and a rest its heading from the motion around it:
docs/methods.md); the bias walks with
``bias_walk_deg_s_sqrt_s``; at rest each gyro sample measures the bias with the variance of
``bias_rest_noise_deg_s`` over ``rest_tau_s`` (``σ² rest_tau_s / dt``).

Outputs: ``quat`` (9-D with a magnetometer, else 6-D: the heading then the gyro's),
``gyr_bias_rad_s`` and ``gyr_bias_sd_rad_s`` (smoothed, rad/s, body axes); ``flags`` are
the forward ``robust`` pass's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as quat
from margtrack.estimator import param
from margtrack.estimator.estimate import Estimate
from margtrack.estimator.flags import Flag
from margtrack.methods.robust import Robust, RobustParams
from margtrack.methods.robust.gains import butterworth_coefficients
from margtrack.methods.smoother import kernel

Array = NDArray[np.float64]

__all__ = ["Smoother", "SmootherParams"]

_NO_GYR = int(Flag.INVALID | Flag.GYR_CLIPPED)
_NO_ACC = int(Flag.INVALID | Flag.ACC_IGNORED)
_NO_MAG = int(Flag.INVALID | Flag.MAG_IGNORED | Flag.MAG_DISTURBED)
_RESTART = int(Flag.GAP | Flag.CLOCK)
#: standard gravity, m/s² (the accelerometer's norm at rest when no rest is detected)
G = 9.80665


@dataclass(frozen=True)
class SmootherParams(RobustParams):
    """``robust``'s parameters (the same time constants and detectors), and the gyro noise
    that sets the orientation's random walk in the filter."""

    motion_walk_deg_s_sqrt_hz: float = param(
        1.0,
        unit="deg/s/√Hz",
        gt=0,
        help="the orientation's random walk in motion: gyro noise, scale and axis errors",
    )
    gyr_noise_deg_s_sqrt_hz: float = param(
        0.02,
        unit="deg/s/√Hz",
        gt=0,
        help="the gyro's white noise: the orientation's random walk at rest",
    )
    incl_sigma_init_deg: float = param(
        5.0, unit="deg", gt=0, help="standard deviation of a (re)start's inclination"
    )
    heading_sigma_init_deg: float = param(
        30.0, unit="deg", gt=0, help="standard deviation of a (re)start's heading"
    )
    acc_lowpass_hz: float = param(
        0.5,
        unit="Hz",
        ge=0,
        help="cut-off of the zero-phase low-pass of the accelerometer in robust's level "
        "frame, before the filter (0: none)",
    )

    def smoother_coefficients(self, dt_s: float, gravity_m_s2: float) -> Array:
        """The kernel's coefficients for a median sample interval ``dt_s`` and the
        accelerometer's norm at rest."""
        c = np.zeros(kernel.N_COEF)
        q = math.radians(self.motion_walk_deg_s_sqrt_hz) ** 2
        c[kernel.C_Q_ANGLE] = q
        c[kernel.C_Q_REST] = math.radians(self.gyr_noise_deg_s_sqrt_hz) ** 2
        c[kernel.C_Q_BIAS] = math.radians(self.bias_walk_deg_s_sqrt_s) ** 2
        c[kernel.C_R_ACC] = self.tau_acc_s**2 * q / dt_s
        c[kernel.C_R_MAG] = self.tau_mag_s**2 * q / dt_s
        # at rest the orientation walks with the gyro's white noise: the same time
        # constants ask for variances as much smaller
        q_rest = c[kernel.C_Q_REST]
        c[kernel.C_R_ACC_AT_REST] = self.tau_acc_s**2 * q_rest / dt_s
        c[kernel.C_R_MAG_AT_REST] = self.tau_mag_s**2 * q_rest / dt_s
        c[kernel.C_R_REST] = math.radians(self.bias_rest_noise_deg_s) ** 2 * self.rest_tau_s / dt_s
        c[kernel.C_P0_INCL] = math.radians(self.incl_sigma_init_deg) ** 2
        c[kernel.C_P0_HEAD] = math.radians(self.heading_sigma_init_deg) ** 2
        c[kernel.C_P0_BIAS] = math.radians(self.bias_sigma_init_deg_s) ** 2
        c[kernel.C_UP] = -1.0 if self.frame == "NED" else 1.0
        c[kernel.C_GRAVITY] = gravity_m_s2
        return c


class Smoother(Robust):
    """Fixed-interval smoother over a whole recording (``--method smoother``); see the
    module docstring. ``run`` takes one whole recording from a fresh state (a second
    ``run`` without ``reset()`` raises: it cannot continue a smoothed run); afterwards
    ``state`` is the forward ``robust`` pass's. ``update`` raises: the method is offline."""

    name = "smoother"
    params_type = SmootherParams
    #: needs the whole series: ``update`` refuses, ``run`` is not resumable
    offline: ClassVar[bool] = True
    outputs_layout = (("gyr_bias_rad_s", 3), ("gyr_bias_sd_rad_s", 3))

    def update(
        self,
        gyr: ArrayLike | None,
        acc: ArrayLike,
        mag: ArrayLike | None = None,
        dt: float | None = None,
    ) -> Array:
        """Refused: the smoother is offline (module docstring)."""
        raise TypeError(
            "smoother is an offline method: each estimate uses samples after it, so it needs "
            "the whole recording at once (run()); for sample-by-sample (live) updates use "
            "method 'robust'"
        )

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
                "smoother smooths one whole recording per run and cannot continue from an "
                "earlier run's state (a recording run in pieces would be smoothed piece by "
                "piece); call reset() before the next recording, and run a recording in one "
                "piece (or use method 'robust', which continues exactly)"
            )
        x = self._validated(gyr, acc, mag, t, check_units=check_units)
        params: SmootherParams = self._params
        forward = Robust(params, rate_hz=self.rate_hz)
        fwd = Robust._run_arrays(forward, x.gyr, x.acc, x.mag, x.t, check_units=False)
        n_sensors, n = x.acc.shape[:2]
        dt = np.diff(x.t)
        dt_s = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.01
        rest = (fwd.flags & int(Flag.REST)) != 0
        norms = np.linalg.norm(x.acc[rest], axis=-1)
        norms = norms[np.isfinite(norms)]
        coefs = params.smoother_coefficients(dt_s, float(np.median(norms)) if norms.size else G)
        lowpass = _lowpass_coefficients(params.acc_lowpass_hz, dt_s)
        quat = np.empty((n_sensors, n, 4))
        bias = np.empty((n_sensors, n, 3))
        bias_var = np.empty((n_sensors, n, 3))
        for s in range(n_sensors):
            flags = fwd.flags[s]
            restart = (flags & _RESTART) != 0
            restart[1:] |= dt <= 0
            use_gyr, use_acc, use_mag, at_rest = (np.empty(n, dtype=np.bool_) for _ in range(4))
            mag_s = np.empty((n, 3))
            # a magnet carried by the sensor: robust's accepted hard-iron offset comes off
            kernel.measurements(flags, x.gyr[s], x.acc[s], None if x.mag is None else x.mag[s],
                                fwd.outputs["mag_offset_ut"][s], _NO_GYR, _NO_ACC, _NO_MAG,
                                int(Flag.REST), use_gyr, use_acc, use_mag, at_rest, mag_s)
            initialising = (flags & int(Flag.INITIALISING)) != 0
            acc_s = x.acc[s]
            if lowpass is not None:
                acc_s = np.empty_like(acc_s)
                kernel.lowpassed_acc(fwd.outputs["quat6d"][s], x.acc[s], use_acc & ~initialising,
                                     restart, *lowpass, acc_s)
                # a restart's window: robust's orientation still forming, the samples as read
                acc_s[initialising] = x.acc[s][initialising]
            q_start = _start_orientations(
                x.t, x.gyr[s], use_gyr, restart, initialising, fwd.quat[s],
                fwd.outputs["gyr_bias_rad_s"][s])
            b0 = np.zeros(3)
            store = _Store(n)
            kernel.forward(x.t, x.gyr[s], acc_s, mag_s, use_gyr, use_acc, use_mag, at_rest,
                           restart, q_start, b0, coefs, *store.forward_arrays())
            kernel.backward(x.t, restart, at_rest, coefs, *store.forward_arrays(), quat[s], bias[s],
                            bias_var[s])
        self._state = forward._state
        self._last_flags = fwd.flags[:, -1].copy()
        self._flag_one = None
        outputs: dict[str, NDArray[Any]] = {
            "gyr_bias_rad_s": bias,
            "gyr_bias_sd_rad_s": np.sqrt(np.maximum(bias_var, 0.0)),
        }
        return Estimate(
            quat=quat,
            t=x.t.copy(),
            frame=params.frame,
            method=self.name,
            params=dict(self._params_dict),
            outputs=outputs,
            flags=fwd.flags,
        )


def _lowpass_coefficients(cutoff_hz: float, dt_s: float) -> tuple[float, float, float] | None:
    """(b0, a1, a2) of the accelerometer's Butterworth low-pass at ``cutoff_hz`` for the
    sample interval ``dt_s`` (``robust``'s low-pass, ``gains.butterworth_coefficients``);
    None when off (0). Raises ``ValueError`` at or above the Nyquist frequency."""
    if cutoff_hz <= 0.0:
        return None
    if cutoff_hz >= 0.5 / dt_s:
        raise ValueError(
            f"acc_lowpass_hz={cutoff_hz:g} Hz is at or above half the sample rate "
            f"({0.5 / dt_s:g} Hz); give a lower cut-off, or 0 for none"
        )
    tau_s = math.sqrt(2.0) / (2.0 * math.pi * cutoff_hz)  # the cut-off's time constant
    return butterworth_coefficients(dt_s, tau_s)


def _start_orientations(
    t: Array,
    gyr: Array,
    use_gyr: NDArray[np.bool_],
    restart: NDArray[np.bool_],
    initialising: NDArray[np.bool_],
    q_robust: Array,
    bias: Array,
) -> Array:
    """(N, 4) with each start's orientation at its start row (sample 0 and every restart):
    ``robust``'s orientation at the end of its start's window (its first sample not
    ``INITIALISING``; the start row itself when there is no window), carried back to the
    start row by the gyroscope (``q_k = q_j ⊗ conj(Π exp((ω_i - b) dt_i))``, i from k + 1
    to j, ``b`` the bias ``robust`` knows at the segment's end): a restart in motion is
    measured over ``robust``'s window, not from one sample."""
    q_start = np.array(q_robust, dtype=np.float64)
    starts = np.flatnonzero(restart)
    starts = np.concatenate([[0], starts[starts > 0]])
    ends = np.concatenate([starts[1:], [t.size]])
    for k, end in zip(starts, ends, strict=True):
        settled = np.flatnonzero(~initialising[k:end])
        j = k + int(settled[0]) if settled.size else end - 1
        if j == k:
            continue
        rates = np.where(use_gyr[k + 1 : j + 1, None], gyr[k + 1 : j + 1], 0.0) - bias[end - 1]
        steps = quat.from_rotvec(rates * np.diff(t[k : j + 1])[:, None])
        carried = quat.identity(())
        for step in steps:
            carried = quat.multiply(carried, step)
        q_start[k] = quat.normalize(quat.multiply(q_robust[j], quat.conjugate(carried)))
    return q_start


class _Store:
    """The forward pass's filtered and predicted states, kept for the backward pass."""

    def __init__(self, n: int) -> None:
        self.q_f, self.b_f = np.empty((n, 4)), np.empty((n, 3))
        self.q_p = np.empty((n, 4))
        self.p_f = np.empty((n, 21))  # the filtered covariance's upper triangle

    def forward_arrays(self) -> tuple[Array, ...]:
        return self.q_f, self.b_f, self.q_p, self.p_f
