"""The input policy: what is done with each sample before a method sees it.

One policy for every method at every entry point (``run`` on arrays or Recordings,
``update``, the live engine, files through the CLI), compiled in ``estimator/screen_kernel.py``:

- a non-finite or out-of-range rate (``gyr_range_deg_s``) is flagged and replaced by the
  last good rate, so one absurd sample costs one sample's rotation, not the recording;
- a non-finite, zero or out-of-range acceleration (``acc_range_g``) is flagged and not
  used for correction;
- a magnetometer sample that is non-finite or zero, an axis that holds one value while the
  sensor turns (stuck, ``mag_stuck_s``) or sits at a level learned as its clip level, and,
  for methods without their own rejection, a norm or dip far from the reference
  (``mag_norm_tol``, ``mag_dip_tol_deg``, reference from ``mag_norm_ref``/
  ``mag_dip_ref_deg`` or learned) is flagged and not used;
- an interval longer than ``max_gap_s`` (or a clock reset) is not integrated: the method
  restarts from the first usable sample after it, keeping what it knows of the sensor
  (gyro bias); a repeated, backward or non-finite timestamp is skipped;
- initialisation waits for the first usable sample (before it the output is held).

With ``strict=True`` the first flagged sample raises ``ValueError`` instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator import screen_kernel as kernel
from margtrack.estimator.params import Params

Array = NDArray[np.float64]

__all__ = ["ScreenState", "Screened", "screen"]


@dataclass
class ScreenState:
    """Per-sensor memory of the screening (S sensors): ``packed`` (S, N_SCREEN).

    The layout is ``estimator/screen_kernel.py``'s ``S_*`` offsets; the properties name the parts:
    the last good rate (used in place of a bad one), the last usable acceleration, the
    previous field sample, how long each field axis has held its value while turning,
    the largest |value| and the learned clip level of each axis, and the field reference.
    """

    packed: Array

    @classmethod
    def new(cls, n_sensors: int) -> ScreenState:
        """Nothing seen yet."""
        packed = np.empty((n_sensors, kernel.N_SCREEN))
        kernel.fresh(packed)
        return cls(packed=packed)

    def copy(self) -> ScreenState:
        """An independent copy."""
        return ScreenState(packed=self.packed.copy())

    def _part(self, offset: int, width: int) -> Array:
        return self.packed[:, offset : offset + width]

    @property
    def last_gyr_rad_s(self) -> Array:
        """(S, 3) view: the last good rate, rad/s."""
        return self._part(kernel.S_LAST_GYR, 3)

    @property
    def mag_hold_s(self) -> Array:
        """(S, 3) view: how long each field axis has held its value while turning, s."""
        return self._part(kernel.S_MAG_HOLD, 3)

    @property
    def mag_clip(self) -> Array:
        """(S, 3) view: learned clip level of each field axis (0: none), field unit."""
        return self._part(kernel.S_MAG_CLIP, 3)

    @property
    def mag_ref(self) -> Array:
        """(S, 5) view: reference norm, dip (rad), candidate norm, dip and steady time (s)."""
        return self._part(kernel.S_REF, kernel.N_REF)

    @property
    def mag_norm_ref(self) -> Array:
        """(S,) the field norm currently taken as undisturbed (0: none yet)."""
        return self.packed[:, kernel.S_REF + kernel.R_NORM].copy()

    @property
    def mag_dip_ref_rad(self) -> Array:
        """(S,) the dip currently taken as undisturbed, rad (nan: none yet)."""
        return self.packed[:, kernel.S_REF + kernel.R_DIP].copy()


@dataclass
class Screened:
    """What a method's kernel gets: usable values or sentinels, intervals and flags.

    dt : (N,) s to integrate before each sample (0: nothing). gyr, acc, mag : (S, N, 3)
    (acc and mag all-zero where not to be used; mag None without a magnetometer).
    flags : (S, N) uint16 (``Flag`` bits). t_last_s : last accepted time.
    """

    dt: Array
    gyr: Array
    acc: Array
    mag: Array | None
    flags: NDArray[np.uint16]
    t_last_s: float


def coefficients(params: Params, check_disturbance: bool) -> Array:
    """The screening kernel's coefficient vector from the shared parameters."""
    c = np.zeros(kernel.N_COEF)
    c[kernel.C_GYR_RANGE] = math.radians(params.gyr_range_deg_s)
    c[kernel.C_ACC_RANGE] = params.acc_range_g * 9.80665
    c[kernel.C_MAX_GAP] = params.max_gap_s
    c[kernel.C_MAG_STUCK] = params.mag_stuck_s
    c[kernel.C_NORM_TOL] = params.mag_norm_tol
    c[kernel.C_DIP_TOL] = math.radians(params.mag_dip_tol_deg)
    c[kernel.C_CHECK_DISTURBANCE] = 1.0 if check_disturbance else 0.0
    c[kernel.C_REF_NORM] = params.mag_norm_ref or 0.0
    dip = params.mag_dip_ref_deg
    c[kernel.C_REF_DIP] = math.nan if dip is None else math.radians(dip)
    return c


def screen(
    state: ScreenState,
    t_last_s: float,
    coef: Array,
    t: Array,
    gyr: Array | None,
    acc: Array,
    mag: Array | None,
) -> Screened:
    """Screen S sensors' samples (arrays (S, N, 3), t (N,)); updates ``state`` in place."""
    n_sensors, n = acc.shape[0], acc.shape[1]
    dt = np.empty(n)
    time_flags = np.empty(n, dtype=np.uint16)
    t_last = kernel.screen_time(t, t_last_s, coef[kernel.C_MAX_GAP], dt, time_flags)
    gyr_in = gyr if gyr is not None else np.zeros_like(acc)
    gyr_out = np.empty_like(acc)
    acc_out = np.empty_like(acc)
    mag_out = np.empty_like(acc) if mag is not None else np.zeros((n_sensors, n, 3))
    flags = np.empty((n_sensors, n), dtype=np.uint16)
    kernel.screen_samples(
        coef,
        dt,
        time_flags,
        gyr_in,
        acc,
        acc if mag is None else mag,
        mag is not None,
        gyr is not None,
        state.packed,
        gyr_out,
        acc_out,
        mag_out,
        flags,
    )
    return Screened(
        dt=dt,
        gyr=gyr_out,
        acc=acc_out,
        mag=mag_out if mag is not None else None,
        flags=flags,
        t_last_s=float(t_last),
    )
