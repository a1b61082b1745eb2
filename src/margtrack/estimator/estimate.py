"""What an estimator holds and returns: its :class:`State` and the :class:`Estimate`."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.estimator import screening
from margtrack.estimator.outputs import Outputs

Array = NDArray[np.float64]

__all__ = ["Estimate", "State", "rows_of", "squeezed"]


@dataclass
class State:
    """State shared by every method: orientations, the clock and the input screening.

    quat : (S, 4) orientation after the last processed sample.
    t_last_s : time of the last accepted sample, s (``nan`` before the first sample).
    ready : (S,) whether each sensor has been initialised (since the start or last gap).
    screen : the input screening's memory (:class:`~margtrack.estimator.screening.ScreenState`).
    """

    quat: Array
    t_last_s: float = float("nan")
    ready: NDArray[np.bool_] | None = None
    screen: screening.ScreenState | None = None

    def copy(self) -> State:
        """An independent copy (the kernels update state arrays in place).

        Arrays and nested state dataclasses are copied (the latter by their own
        ``copy()``), containers deep-copied, scalars shared; cheaper than a generic
        deep copy, which ``update`` would otherwise pay on every sample.
        """
        values = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray) or dataclasses.is_dataclass(value):
                value = value.copy()  # a nested state dataclass provides its own copy()
            elif isinstance(value, (list, dict, set)):
                value = copy.deepcopy(value)
            values[f.name] = value
        return type(self)(**values)

    def gyr_bias_rad_s(self) -> Array | None:
        """(S, 3) the gyro bias the method has estimated, rad/s (None: it has none)."""
        return None

    def gyr_bias_sd_rad_s(self) -> Array | None:
        """(S, 3) standard deviation of that bias estimate, rad/s (None: not known)."""
        return None


@dataclass(frozen=True)
class Estimate:
    """The orientation series an estimator produced, and what else it knows.

    quat : (N, 4) or (S, N, 4) orientation of the body in ``frame``, [w, x, y, z].
    t : (N,) sample times, s (as given).
    frame : earth frame of ``quat``.
    method : registered method name.
    params : the parameters used, as a dict.
    outputs : further per-sample series with units in their names (for example
        ``gyr_bias_rad_s`` (…, N, 3)); a method may compute some only when first read
        (:class:`~margtrack.estimator.outputs.Outputs`).
    flags : (N,) or (S, N) uint16 health flags (:class:`~margtrack.estimator.flags.Flag`).
    """

    quat: Array
    t: Array
    frame: frames.Frame
    method: str
    params: Mapping[str, Any]
    outputs: Mapping[str, NDArray[Any]] = field(default_factory=dict)
    flags: NDArray[np.uint16] | None = None

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.shape[0])

    def euler(self) -> Array:
        """ZYX Euler angles [yaw, pitch, roll] in rad, shape of ``quat`` with 3 last."""
        return quat.to_euler(self.quat)

    def in_frame(self, frame: str) -> Estimate:
        """The same estimate with orientations expressed in another earth frame."""
        target = frames.check_frame(frame)
        if target == self.frame:
            return self
        return dataclasses.replace(
            self, quat=frames.convert(self.quat, self.frame, target), frame=target
        )


def squeezed(est: Estimate) -> Estimate:
    """The single-sensor view of an (S = 1) estimate."""
    return dataclasses.replace(
        est,
        quat=est.quat[0],
        outputs=(
            est.outputs.mapped(lambda _, v: v[0])
            if isinstance(est.outputs, Outputs)
            else {k: v[0] for k, v in est.outputs.items()}
        ),
        flags=None if est.flags is None else est.flags[0],
    )


def rows_of(state: State, rows: NDArray[np.intp]) -> dict[str, Array]:
    """Copies of the given sensors' rows of every per-sensor array field of ``state``."""
    n_sensors = state.quat.shape[0]
    out = {}
    for f in dataclasses.fields(state):
        value = getattr(state, f.name)
        if f.name != "screen" and isinstance(value, np.ndarray) and value.ndim >= 1:
            if value.shape[0] == n_sensors and f.name != "ready":
                out[f.name] = value[rows].copy()
    return out
