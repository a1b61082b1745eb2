"""Gauss-Newton and Newton quaternion fits to gravity and the magnetic field (001 sec. 4.2).

The quaternion minimising the earth-frame error between the known references (up and the
reference field) and the measured body vectors turned by the quaternion (001 eqs. 20-21)
is found by Gauss-Newton (eqs. 22-23) or Newton (eqs. 24-26) iterations. Each sample
starts from the previous estimate (tracking: one iteration is usually enough), the first
from TRIAD, as is any sample whose previous estimate lies more than 30 deg from its TRIAD
orientation (after a jump far from the minimum Gauss-Newton is slow and Newton can stop at
a saddle point). Two safeguards go beyond 001: that restart, and halving an update that
would increase the criterion (ill-conditioned samples, with the accelerometer nearly
parallel to the field, otherwise diverge). The iteration count and the final criterion are
outputs. The normalised
minimum is the weighted Wahba solution, so with ``mag_weight`` ρ it equals Davenport's
with weights (1, ρ²). For the EKF of 001 (approach 2), the kernel-level functions
:func:`margtrack.single_frame.gauss_newton_kernel.gauss_newton_solve` and
``gauss_newton_step`` can be called from other numba kernels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.estimator import param
from margtrack.single_frame.gauss_newton_kernel import gauss_newton_run
from margtrack.single_frame.prefilter import LowpassParams, MeasuredDipState, SingleFrameEstimator

__all__ = ["GaussNewton", "GaussNewtonParams", "GaussNewtonState", "Newton", "NewtonParams"]


@dataclass(frozen=True)
class GaussNewtonParams(LowpassParams):
    """Parameters of the Gauss-Newton and Newton fits (plus ``frame`` and the prefilter).

    mag_weight : ρ > 0 multiplying the magnetic residual (000 eq. 17): the criterion is
        ``|ε_g|² + ρ² |ε_m|²``. Default 1 (equal weight, as 001). Lowering it lets a
        disturbed field pull less on the estimate; 0 leaves the heading undetermined and
        is refused.
    tolerance : stop iterating when the criterion (dimensionless, unit vectors) or its
        decrease over the last iteration is at most this; default 1e-10 (001 5.1's
        convergence experiment; the quaternion is then within about 1e-5 rad of the
        noise-free solution, and with noise the last iteration changes it by less).
    max_iterations : cap on iterations per sample, in [1, 1000]; default 10 (001: 3-4 from
        a poor guess, 1 when tracking).

    The reference field's dip is the shared ``mag_dip_ref_deg``, deg, positive down
    (None, the default: measured from each sensor's first valid sample).
    """

    mag_weight: float = param(
        1.0, gt=0, help="weight rho of the magnetic residual: Q = |e_g|^2 + rho^2 |e_m|^2"
    )
    tolerance: float = param(
        1e-10, ge=0, help="stop when the criterion, or its decrease, is at most this"
    )
    max_iterations: int = param(10, ge=1, le=1000, help="cap on iterations per sample")


@dataclass(frozen=True)
class NewtonParams(GaussNewtonParams):
    """Newton's parameters: the same as :class:`GaussNewtonParams`."""


@dataclass(kw_only=True)
class GaussNewtonState(MeasuredDipState):
    """State of the fits: MeasuredDipState plus whether ``quat`` is an estimate yet.

    has_estimate : (S,) bool; False until the first valid sample (which then starts from
        TRIAD) unless ``reset(q0)`` gave an initial guess.
    """

    has_estimate: NDArray[np.bool_]

    @classmethod
    def fresh(cls, quat0: NDArray[np.float64], **extra: Any) -> GaussNewtonState:
        """A state for S sensors with no estimate yet."""
        extra.setdefault("has_estimate", np.zeros(quat0.shape[0], dtype=np.bool_))
        return super().fresh(quat0, **extra)  # type: ignore[return-value]


class GaussNewton(SingleFrameEstimator[GaussNewtonParams, GaussNewtonState]):
    """Gauss-Newton quaternion fit (``--method gauss-newton``), 001 eqs. 20-23.

    Outputs, per sample: ``degenerate`` int8 (0 ok, 1 zero accelerometer: the previous
    orientation is repeated; 2 zero magnetometer, 3 accelerometer parallel to the field,
    4 singular normal equations: levelled onto gravity, heading kept; mapped onto the
    flags, see ``prefilter``), ``iterations`` int32 (updates applied) and
    ``criterion`` (Q = |ε_g|² + ρ²|ε_m|² at the last iterate, NaN where flagged 1-3).
    ``reset(q0)`` makes q0 the first sample's initial guess. Quaternions have ``w >= 0``.
    """

    name = "gauss-newton"
    params_type: ClassVar[type[GaussNewtonParams]] = GaussNewtonParams
    _newton: ClassVar[bool] = False

    def _new_state(self, quat0: NDArray[np.float64]) -> GaussNewtonState:
        return GaussNewtonState.fresh(quat0)

    def reset(self, q0: ArrayLike | None = None) -> None:
        """Forget the state; with ``q0`` ((4,) or (S, 4)) use it as the first initial guess."""
        super().reset(q0)
        if self._state is not None:
            self._state.has_estimate[:] = True

    def _process(
        self,
        state: GaussNewtonState,
        gyr: NDArray[np.float64] | None,
        acc: NDArray[np.float64],
        mag: NDArray[np.float64] | None,
        dt: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], dict[str, NDArray[Any]]]:
        assert mag is not None  # guaranteed by mag_optional = False
        p = self.params
        up, north = self._earth_axes()
        acc_cut, mag_cut, order = self._lowpass_args(dt)
        shape = acc.shape[:2]
        out = np.empty((*shape, 4))
        flags = np.empty(shape, dtype=np.int8)
        iterations = np.empty(shape, dtype=np.int32)
        criterion = np.empty(shape)
        gauss_newton_run(
            acc, mag, dt, up, north, self._dip_rad(), p.mag_weight, p.tolerance,
            p.max_iterations, self._newton, acc_cut, mag_cut, order,
            state.quat, state.has_estimate, state.dip_rad, state.lowpass_history,
            state.lowpass_ready, out, flags, iterations, criterion,
        )
        return out, {"degenerate": flags, "iterations": iterations, "criterion": criterion}


class Newton(GaussNewton):
    """Newton quaternion fit (``--method newton``), 001 eqs. 24-26 with the Hessian
    derived afresh (the printed eq. 26 is -1/2 of it). Same outputs as :class:`GaussNewton`.
    Far from the minimum the Hessian is indefinite and Newton can stop at a saddle point;
    when tracking (previous estimate as guess) it converges like Gauss-Newton.
    """

    name = "newton"
    params_type = NewtonParams
    _newton = True
