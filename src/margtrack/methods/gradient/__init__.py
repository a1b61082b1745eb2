"""Gradient-descent orientation filter for wearables in electromagnetic noise (004, after Madgwick).

Each sample (004 "Gyroscope Equations" and "General Optimization Algorithm")::

    q̇_ω = ½ q ⊗ (0, ω)                                 gyro propagation
    ∇f  = J_gᵀ f_g + J_mᵀ f_m,  f(q, d, s) = q* ⊗ d ⊗ q - s   gradient of the objectives
    q   ← normalise(q + (q̇_ω - β ∇f / |∇f|) Δt)        one normalised step of size β Δt

(004's and Madgwick's first-order form, ``integration="euler"``; the default "exact" turns
by the gyro exactly, ``q ⊗ exp(ω Δt/2) - β Δt ∇f/|∇f|``, then normalises)
with the gravity objective (d = up, s = â) and a magnetic one. 004's change to Madgwick's
filter is the magnetometer's *forward component*: ``m_f = m - (m·v̂) v̂``, the rejection of
m from the gravity direction v̂, matched to horizontal north. The magnetic dip and any
vertical disturbance then cannot tilt the estimate; the magnetometer only corrects heading.
v̂ is 004's gravity component ``a_g`` (the filter's own estimate ``R(q)ᵀ up``, default) or
the raw accelerometer direction. With ``mag_objective="madgwick"`` the magnetic objective is
Madgwick's full vector (reference ``b = [|h_h|, 0, h_v]`` from ``h = q ⊗ m̂ ⊗ q*``), and with
``integration="euler"`` the step is his first-order one: that configuration is
``ahrs.filters.Madgwick`` to rounding (after the frame change NWU to ENU/NED, see
:class:`Gradient`).

Outputs besides the quaternion (004 "Inputs and Outputs"): Euler angles, the gravity
component of the accelerometer and the linear acceleration relative to the ground.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimator import Estimate, Params, param
from margtrack.estimator.compiled import CompiledEstimator
from margtrack.estimator.outputs import Outputs
from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.methods.gradient import kernel
from margtrack.methods.live_sensors import LiveSensors, align_to_gyro

Array = NDArray[np.float64]

__all__ = [
    "ACC_IGNORED",
    "MAG_IGNORED",
    "MAG_OBJECTIVES",
    "MAG_REJECTED",
    "Gradient",
    "GradientParams",
    "align_to_gyro",
]

#: magnetic objectives (``GradientParams.mag_objective``) and their kernel codes
MAG_OBJECTIVES = {
    "forward": kernel.FORWARD_ESTIMATED,
    "forward_measured": kernel.FORWARD_MEASURED,
    "madgwick": kernel.FULL_ADAPTIVE,
    "fixed": kernel.FULL_FIXED,
}

ACC_IGNORED = kernel.ACC_IGNORED
MAG_IGNORED = kernel.MAG_IGNORED
MAG_REJECTED = kernel.MAG_REJECTED

# q_frame = c ⊗ q_nwu: NWU (x north, y west, z up) is where the kernel computes
_FROM_NWU = {
    "ENU": np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)]),  # +90 deg about up
    "NED": np.array([0.0, 1.0, 0.0, 0.0]),  # half turn about north
}

#: Default β, rad/s: the best single value for all 16 BROAD trials by
#: ``margtrack.bench.tune`` (MARG, forward component, exact integration), printed by
#: ``python benchmarks/madgwick_baseline.py`` next to ahrs's tuned Madgwick. See GradientParams.
DEFAULT_BETA = 0.025


@dataclass(frozen=True)
class GradientParams(Params):
    """Parameters of the gradient-descent filter (and the shared ones of :class:`Params`).

    beta : step of the gradient correction, rad/s (Madgwick's β, 004's μ = β Δt), >= 0.
        The estimate turns towards the accelerometer/magnetometer solution at up to β rad/s:
        raising it forgets gyro drift faster but lets linear acceleration and magnetic
        disturbances in; 0 is pure gyro integration. Default ``DEFAULT_BETA`` = 0.025, the
        best single value on the 16 BROAD trials (benchmarks/madgwick_baseline.py).
    mag_objective : how the magnetometer corrects (see :data:`MAG_OBJECTIVES`):
        "forward" (default): 004's forward component, rejection of m from the estimated
        gravity direction ``R(q)ᵀ up`` (004's ``a_g``); heading only.
        "forward_measured": the same rejection from the raw accelerometer direction â
        (noisier heading: accelerometer noise and linear acceleration tilt the plane,
        amplified by tan(dip)).
        "madgwick": the full vector with Madgwick's reference re-estimated each sample
        (``b = [|h_h|, 0, h_v]``); plain Madgwick, the magnetometer also acts on tilt.
        "fixed": the full vector against the reference measured at the first sample and
        then kept (also across restarts after a gap), as a filter with a known field
        direction does; any later change of the field's dip tilts the estimate.
    use_mag : False ignores a given magnetometer (6-D estimate, heading free).
    integration : "exact" (``q ⊗ exp(ω Δt/2)``, default) or "euler" (004's and ahrs's
        ``q + q̇ Δt``, first order; for reproducing ahrs.filters.Madgwick).
    gravity_m_s2 : gravity magnitude subtracted for the linear acceleration, m/s², > 0.
    """

    beta: float = param(
        DEFAULT_BETA,
        unit="rad/s",
        ge=0,
        help="correction step (Madgwick's beta): higher forgets drift faster, admits more "
        "acceleration; 0 integrates the gyro only",
    )
    mag_objective: Literal["forward", "forward_measured", "madgwick", "fixed"] = param(
        "forward",
        choices=tuple(MAG_OBJECTIVES),
        help="magnetometer objective: 004's forward component (heading only), from the "
        "measured gravity, Madgwick's full vector, or a fixed full-vector reference",
    )
    use_mag: bool = param(True, help="use a given magnetometer (False: 6-D, heading free)")
    integration: Literal["exact", "euler"] = param(
        "exact",
        choices=("exact", "euler"),
        help="gyro step: exact q*exp(w dt/2), or 004's and ahrs's first-order q + q' dt",
    )
    gravity_m_s2: float = param(
        STANDARD_GRAVITY_M_S2,
        unit="m/s²",
        gt=0,
        help="gravity subtracted for the linear-acceleration output",
    )


class Gradient(LiveSensors, CompiledEstimator[GradientParams]):
    """Gradient-descent filter of 004, magnetometer forward component (``--method gradient``).

    Outputs (``Estimate.outputs``, arrays (…, N, ...); after ``run`` each is computed when
    first read, from the output orientations and the screened accelerometer samples kept
    by the kernel: the values the per-sample step computes, bit for bit):

    - ``euler_rad`` (…, N, 3): [yaw, pitch, roll] by 004's formulas, the ZYX angles of
      :func:`margtrack.quaternion.to_euler` (yaw and roll ill-defined at |pitch| = 90°).
    - ``gravity_body_m_s2`` (…, N, 3): the accelerometer's gravity component ``a_g``, body
      frame, pointing up: ``g · rotate_inverse(q, up)``.
    - ``lin_acc_earth_m_s2`` (…, N, 3): acceleration relative to the ground ``a_m`` in the
      earth frame, ``rotate(q, a) - g · up``. Noise: the accelerometer's own noise plus
      ``g · sin(tilt error)`` (0.17 m/s² per degree of inclination error), and any
      accelerometer bias or scale error in full: ``σ² ≈ σ_acc² + (g σ_incl)²`` per
      horizontal axis, ``σ_acc²`` vertically. Noisier than the orientation (004).
      Where the accelerometer was not used (flag ACC_IGNORED) it holds no measurement
      (``-g · up``): read it with the flags.
    - ``ignored`` (…, N) int8 bits, method detail (``Estimate.flags`` carries them in the
      common schema, and :attr:`flags` in ``update``): ``ACC_IGNORED`` (no usable
      accelerometer: gyro-only step, no magnetometer term either; ``Flag.ACC_IGNORED``),
      ``MAG_IGNORED`` (accelerometer used, no magnetometer term: zero field or its forward
      component below 1 % of it), ``MAG_REJECTED`` (a non-zero field the filter itself did
      not use: forward component vanished, or no accelerometer to go with it;
      ``Flag.MAG_IGNORED``). A zero field is the screening's sentinel: it has flagged why
      (``MAG_IGNORED`` or ``MAG_DISTURBED``). A no-op sample (``dt = 0``, neither
      measurement: a skipped timestamp) has no bits, nor has a held sample before the
      start (``Flag.INITIALISING``; its outputs are those of the held orientation, its
      linear acceleration ``-g · up``).

    State (:class:`~margtrack.estimator.compiled.CompiledState`, read with
    ``state.get(name)``; the row layout is :mod:`margtrack.methods.gradient.kernel`'s):

    - ``quat_nwu`` (S, 4): the orientation in NWU, where the recursion runs;
    - ``mag_ref`` (S, 2) [b_x, b_z]: unit field reference of ``mag_objective="fixed"`` in
      north/up components (b_x = 0: not measured yet);
    - ``acc_held`` (S, 3) m/s²: the accelerometer sample held for the next live gyro step:
      the newest one received by ``update_acc`` as received (a non-finite one included: the
      screening flags it at each step that uses it), or after ``run``/``update`` the last
      sample processed as screened (zeros: none, or unusable);
    - ``mag_held`` (S, 3) field unit: the same for the magnetometer (zeros: none yet).

    A restart after a gap keeps ``mag_ref``, ``acc_held`` and ``mag_held`` (they belong to
    the sensors and the field, not to the orientation).

    Input policy (:mod:`margtrack.estimator.screening`): the kernel sees screened samples;
    an unusable accelerometer or magnetometer arrives as the zero vector and only its
    correction is skipped. Each sensor starts at its first usable sample (TRIAD, or gravity
    alone without a usable field or with ``use_mag=False``, which drops a given field
    before the screening) and after a gap restarts from the first usable sample again (with
    β as it is: it re-converges within a few seconds), keeping the held samples and the
    ``fixed`` field reference. The whole per-sample path (screening, clock, starts, the
    step) is one compiled call (:mod:`margtrack.estimator.compiled`).

    Live use with sensors at different rates: :meth:`update_acc`, :meth:`update_mag`,
    :meth:`update_gyr` (zero-order hold); offline: :func:`align_to_gyro` (interpolation).

    Convention mapping to ``ahrs.filters.Madgwick`` (earth frame NWU): with
    ``mag_objective="madgwick", integration="euler"`` and the same β, the quaternion here in ENU is
    ``q_enu = q_z(+90°) ⊗ q_nwu`` and in NED ``q_ned = [0, 1, 0, 0] ⊗ q_nwu``, sample by
    sample to rounding, from the same initial quaternion (ahrs's MARG start, ``ecompass``,
    is the same TRIAD orientation). ahrs skips the whole update when the gyro reads exactly
    zero; this filter still corrects then. The recursion runs in NWU whatever the output
    frame, because the unit-norm form of the objective makes the normalised step depend on
    the earth frame (see :func:`margtrack.methods.gradient.kernel._step`).
    """

    name = "gradient"
    params_type = GradientParams
    kernel = kernel
    state_layout: ClassVar[Mapping[str, tuple[int, int]]] = {
        "quat_nwu": (kernel.G_Q, 4),
        "mag_ref": (kernel.G_MAG_REF, 2),
        "acc_held": (kernel.G_ACC_HELD, 3),
        "mag_held": (kernel.G_MAG_HELD, 3),
    }
    outputs_layout = (
        ("euler_rad", 3),
        ("gravity_body_m_s2", 3),
        ("lin_acc_earth_m_s2", 3),
        ("ignored", 1),
    )

    def _coefficients(self) -> Array:
        p = self._params
        coef = np.zeros(kernel.N_COEF)
        coef[kernel.C_BETA] = p.beta
        coef[kernel.C_MAG_MODE] = MAG_OBJECTIVES[p.mag_objective]
        coef[kernel.C_EXACT] = 1.0 if p.integration == "exact" else 0.0
        coef[kernel.C_GRAVITY] = p.gravity_m_s2
        coef[kernel.C_TO_FRAME : kernel.C_TO_FRAME + 4] = _FROM_NWU[p.frame]
        coef[kernel.C_UP : kernel.C_UP + 3] = frames.up(p.frame)
        return coef

    def _has_bits(self, has: int) -> int:
        """A given field dropped with ``use_mag=False`` (then the screening does not judge
        it and a start levels on gravity alone)."""
        return has if self._params.use_mag else has & ~1

    def _run_arrays(self, *args: Any, **kwargs: Any) -> Estimate:
        est = super()._run_arrays(*args, **kwargs)
        # computed on first read (``estimator.outputs``); the kernel keeps the ``ignored``
        # bits as a float column: back to int8 (S, N)
        outputs = Outputs(est.outputs).mapped(_ignored_int8)
        return dataclasses.replace(est, outputs=outputs)


def _ignored_int8(name: str, value: NDArray[Any]) -> NDArray[Any]:
    """The ``ignored`` column (…, N, 1) as int8 bits (…, N); other outputs as they are."""
    return value[..., 0].astype(np.int8) if name == "ignored" else value
