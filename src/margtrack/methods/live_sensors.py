"""Sensors at different rates: interpolate slower ones onto gyro times, or hold them live.

004 (Overview) assumes synchronous data and interpolates the slower accelerometer and
magnetometer onto the gyroscope timestamps. Offline that is :func:`align_to_gyro`
(linear interpolation by :func:`margtrack.recording.resample`). Live, the next slow sample
is not known yet, so interpolating would add up to one slow-sensor period of latency;
:class:`LiveSensors` instead holds the newest accelerometer and magnetometer sample
(zero-order hold) and runs one filter step per gyroscope sample.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.recording import Recording, resample

Array = NDArray[np.float64]

__all__ = ["LiveSensors", "align_to_gyro"]


def align_to_gyro(
    t_gyr: ArrayLike,
    gyr: ArrayLike,
    t_acc: ArrayLike,
    acc: ArrayLike,
    t_mag: ArrayLike | None = None,
    mag: ArrayLike | None = None,
    **fields: Any,
) -> Recording:
    """A Recording on the gyroscope timestamps, slower sensors linearly interpolated (004).

    Parameters
    ----------
    t_gyr : (N,) s, strictly increasing; gyr (N, 3) rad/s.
    t_acc : (M,) s, strictly increasing; acc (M, 3) m/s².
    t_mag, mag : (K,) s and (K, 3) any field unit, or both None (6-D data).
    **fields : further Recording fields (``name``, ``frame``, ``quat_true`` on ``t_gyr``...).

    Returns
    -------
    Recording with ``t = t_gyr``. Gyro samples outside an interpolated sensor's time span
    hold its first or last sample; ``meta["acc_held_samples"]`` and
    ``meta["mag_held_samples"]`` count them.
    """
    if (t_mag is None) != (mag is None):
        raise ValueError("give both t_mag and mag, or neither")
    t = np.asarray(t_gyr, dtype=np.float64)
    ta = np.asarray(t_acc, dtype=np.float64)
    meta = dict(fields.pop("meta", {}))
    meta["acc_held_samples"] = int(np.sum((t < ta[0]) | (t > ta[-1]))) if ta.size else 0
    acc_on_gyr = resample(ta, acc, t)
    mag_on_gyr = None
    if mag is not None and t_mag is not None:
        tm = np.asarray(t_mag, dtype=np.float64)
        meta["mag_held_samples"] = int(np.sum((t < tm[0]) | (t > tm[-1]))) if tm.size else 0
        mag_on_gyr = resample(tm, mag, t)
    return Recording(t=t, gyr=gyr, acc=acc_on_gyr, mag=mag_on_gyr, meta=meta, **fields)


def _sample(value: ArrayLike, name: str, n_sensors: int | None) -> Array:
    """One sample (3,) or one per sensor (S, 3) as an (S, 3) float64 array.

    Shape and type are the caller's to fix (``ValueError``); values are not judged here: a
    non-finite sample is held like any other and the input screening flags and skips it
    at each step that uses it (:mod:`margtrack.estimator.screening`).
    """
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    if arr.shape == (3,):
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (3,) or (S, 3), got {arr.shape}")
    if n_sensors is not None and arr.shape[0] != n_sensors:
        raise ValueError(
            f"{name} has {arr.shape[0]} sensor(s) but the filter tracks {n_sensors}; "
            "reset() first to change the number of sensors"
        )
    return arr


class LiveSensors:
    """Live input from sensors arriving separately: ``update_acc``/``_mag``/``_gyr``.

    Mix into a :class:`~margtrack.estimator.compiled.CompiledEstimator` whose state rows
    have ``acc_held`` and ``mag_held`` slots of width 3 (its ``state_layout``; zeros:
    nothing received). Accelerometer and magnetometer
    samples are stored as they arrive; each gyroscope sample runs one step of the filter
    (``update``) with the newest of them (zero-order hold, no latency; offline,
    :func:`align_to_gyro` interpolates instead). Samples that arrive before the first
    gyroscope sample are kept to initialise the orientation at that first gyroscope sample.

    Input policy: held samples reach ``update`` as received, so the screening judges them
    at every gyroscope step, exactly as ``run`` on the zero-order-held series would. A
    non-finite accelerometer sample held is not refused: each step until the next
    ``update_acc`` is flagged ``INVALID | ACC_IGNORED`` and is a gyro-only step (the
    screening's zero sentinel); a held non-finite, stuck or disturbed field is likewise
    flagged and not used. Before the first usable accelerometer sample the output is held
    (``INITIALISING``). Per-step flags are in :attr:`flags`.
    """

    _state: Any

    def _pending(self) -> dict[str, Array]:
        return self.__dict__.setdefault("_pending_samples", {})

    def _held(self, name: str) -> slice:
        """Columns of the state's rows that hold ``name`` ("acc_held", "mag_held")."""
        offset, width = self._state.layout[name]
        return slice(offset, offset + width)

    def _n_sensors(self) -> int | None:
        if self._state is not None:
            return int(self._state.rows.shape[0])
        held = self._pending()
        return None if not held else int(next(iter(held.values())).shape[0])

    def reset(self, q0: ArrayLike | None = None) -> None:
        """Forget the state and any sample held for initialisation (see ``Estimator.reset``)."""
        self._pending().clear()
        super().reset(q0)  # type: ignore[misc]

    def update_acc(self, acc: ArrayLike) -> None:
        """Store the newest accelerometer sample, (3,) or (S, 3) m/s² (body, points up at rest).

        A non-finite sample is stored too; the steps that use it flag and skip it.
        """
        arr = _sample(acc, "acc", self._n_sensors())
        if self._state is None:
            self._pending()["acc"] = arr
        else:
            self._state.rows[:, self._held("acc_held")] = arr

    def update_mag(self, mag: ArrayLike) -> None:
        """Store the newest magnetometer sample, (3,) or (S, 3) in any field unit (body).

        A non-finite sample is stored too; the steps that use it flag and skip it.
        """
        arr = _sample(mag, "mag", self._n_sensors())
        if self._state is None:
            self._pending()["mag"] = arr
        else:
            self._state.rows[:, self._held("mag_held")] = arr

    def update_gyr(self, gyr: ArrayLike, dt: float | None = None) -> Array:
        """Process one gyroscope sample (3,) or (S, 3) rad/s with the held acc/mag samples.

        ``dt`` is the time since the previous gyroscope sample in s (default 1 / rate_hz).
        The first call after a reset returns the orientation measured from the held samples
        (or ``q0``), like ``update``; with an unusable held accelerometer sample it holds
        the output until a usable one arrives. Returns (4,) or (S, 4). The held samples
        stay as received (the step's screening does not replace them by its sentinels).
        """
        g = np.asarray(gyr, dtype=np.float64)
        one = g.ndim == 1
        state = self._state
        if state is None:
            held = self._pending()
            if "acc" not in held:
                raise ValueError(
                    "update_gyr() before any accelerometer sample: call update_acc() first "
                    "(it sets the initial orientation) or reset(q0)"
                )
            acc, mag = held["acc"], held.get("mag")
        else:
            acc = state.rows[:, self._held("acc_held")].copy()
            mag = state.rows[:, self._held("mag_held")].copy()
            if not any(mag.flat):  # none received yet
                mag = None
        q = self.update(  # type: ignore[attr-defined]
            g, acc[0] if one else acc, None if mag is None else (mag[0] if one else mag), dt
        )
        # the kernel stored the screened samples; keep holding them as received, so the
        # next step sees (and flags) what run() on the held series would
        rows = self._state.rows
        rows[:, self._held("acc_held")] = acc
        if mag is not None:
            rows[:, self._held("mag_held")] = mag
        if state is None:
            self._pending().clear()
        return q
