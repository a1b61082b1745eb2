"""The state of S sensors of a compiled method: one flat row per sensor and a shared clock."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator import screening
from margtrack.estimator import skeleton as kc

Array = NDArray[np.float64]

__all__ = ["CompiledState"]


@dataclass
class CompiledState:
    """State of S sensors of a compiled method: ``rows`` (S, R) and the ``clock`` (1,).

    The first ``N_CONTRACT`` slots of a row are the contract's (started flag, number of
    starts, last output, screening state); the method's own follow, named by its
    ``layout`` (name -> (offset, width) within the row). Read them with :meth:`get`.
    """

    rows: Array
    clock: Array
    layout: Mapping[str, tuple[int, int]] = dataclasses.field(default_factory=dict)

    def copy(self) -> CompiledState:
        """An independent copy."""
        return CompiledState(self.rows.copy(), self.clock.copy(), self.layout)

    @property
    def quat(self) -> Array:
        """(S, 4) the last output orientation."""
        return self.rows[:, kc.K_Q : kc.K_Q + 4].copy()

    @property
    def t_last_s(self) -> float:
        """Time of the last accepted sample, s (nan before the first)."""
        return float(self.clock[0])

    @property
    def ready(self) -> NDArray[np.bool_]:
        """(S,) whether each sensor has started (since the start or the last gap)."""
        return self.rows[:, kc.K_READY] > 0.0

    @property
    def screen(self) -> screening.ScreenState:
        """The screening state (a copy)."""
        return screening.ScreenState(
            packed=self.rows[:, kc.K_SCREEN : kc.K_SCREEN + screening.kernel.N_SCREEN].copy()
        )

    def get(self, name: str) -> Array:
        """(S, width) a copy of the named part of the method's state."""
        offset, width = self.layout[name]
        return self.rows[:, offset : offset + width].copy()

    def gyr_bias_rad_s(self) -> Array | None:
        """(S, 3) the gyro bias estimate, rad/s, if the method has one."""
        return self.get("gyr_bias_rad_s") if "gyr_bias_rad_s" in self.layout else None

    def gyr_bias_sd_rad_s(self) -> Array | None:
        """(S, 3) its standard deviation, rad/s, if the method knows it."""
        return self.get("gyr_bias_sd_rad_s") if "gyr_bias_sd_rad_s" in self.layout else None
