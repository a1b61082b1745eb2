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

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from margtrack import frames
from margtrack.estimator import Estimator, Flag, Params, State, param
from margtrack.filters._async import LiveSensors, align_to_gyro
from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.kernels import gradient as kernel

Array = NDArray[np.float64]

__all__ = [
    "ACC_IGNORED",
    "MAG_IGNORED",
    "MAG_OBJECTIVES",
    "MAG_REJECTED",
    "Gradient",
    "GradientParams",
    "GradientState",
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

#: ``ignored`` bits (0-7) to ``Flag`` bits: what ``Gradient._method_flags`` adds
_SCHEMA = np.array(
    [
        (Flag.ACC_IGNORED if bits & ACC_IGNORED else 0)
        | (Flag.MAG_IGNORED if bits & MAG_REJECTED else 0)
        for bits in range(8)
    ],
    dtype=np.uint16,
)

# q_frame = c ⊗ q_nwu: NWU (x north, y west, z up) is where the kernel computes
_FROM_NWU = {
    "ENU": np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)]),  # +90 deg about up
    "NED": np.array([0.0, 1.0, 0.0, 0.0]),  # half turn about north
}

#: Default β, rad/s: the best single value for all 16 BROAD trials by
#: ``margtrack.bench.tune`` (MARG, forward component, exact integration), printed by
#: ``python benchmarks/madgwick_baseline.py`` next to ahrs's tuned Madgwick. See GradientParams.
DEFAULT_BETA = 0.025


def _read_only(a: Array) -> Array:
    """A read-only view of ``a``, so the kernel always sees one array type.

    Inputs arrive writable or not (Recordings freeze theirs) and numba compiles one
    specialisation per combination; read-only views keep it to one compilation.
    """
    view = a.view()
    view.flags.writeable = False
    return view


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


@dataclass(kw_only=True)
class GradientState(State):
    """Orientation, clock and screening (see :class:`State`) plus the slow-sensor samples.

    acc_held : (S, 3) m/s², the accelerometer sample held for the next live gyro step: the
        newest one received by ``update_acc`` as received (a non-finite one included: the
        screening flags it at each step that uses it), or after ``run``/``update`` the last
        sample processed as screened (zeros: none, or unusable).
    mag_held : (S, 3) field unit, the same for the magnetometer (zeros: none yet).
    mag_ref : (S, 2) [b_x, b_z], unit field reference of ``mag_objective="fixed"`` in
        north/up components (b_x = 0: not measured yet).

    A restart after a gap keeps all three (they belong to the sensors and the field, not
    to the orientation): see ``Gradient.kept_on_restart``.
    """

    acc_held: Array
    mag_held: Array
    mag_ref: Array

    def copy(self) -> GradientState:
        """A copy of every field, base ones included (explicit: cheaper in ``update``)."""
        return GradientState(
            quat=self.quat.copy(),
            t_last_s=self.t_last_s,
            ready=None if self.ready is None else self.ready.copy(),
            screen=None if self.screen is None else self.screen.copy(),
            acc_held=self.acc_held.copy(),
            mag_held=self.mag_held.copy(),
            mag_ref=self.mag_ref.copy(),
        )


class Gradient(LiveSensors, Estimator[GradientParams, GradientState]):
    """Gradient-descent filter of 004, magnetometer forward component (``--method gradient``).

    Outputs (``Estimate.outputs``, arrays (…, N, ...)):

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
      common schema): ``ACC_IGNORED`` (no usable accelerometer: gyro-only step, no
      magnetometer term either; ``Flag.ACC_IGNORED``), ``MAG_IGNORED`` (accelerometer used,
      no magnetometer term: zero field or its forward component below 1 % of it),
      ``MAG_REJECTED`` (a non-zero field the filter itself did not use: forward component
      vanished, or no accelerometer to go with it; ``Flag.MAG_IGNORED``). A zero field is
      the screening's sentinel: it has flagged why (``MAG_IGNORED`` or ``MAG_DISTURBED``).
      A no-op sample (``dt = 0``, neither measurement: a skipped timestamp) has no bits.

    Input policy (:mod:`margtrack.estimator.screening`): the kernel sees screened samples;
    an unusable accelerometer or magnetometer arrives as the zero vector and only its
    correction is skipped. After a gap the filter restarts from the TRIAD orientation of
    the first usable sample (with β as it is: it re-converges within a few seconds), keeping
    the held samples and the ``fixed`` field reference.

    Live use with sensors at different rates: :meth:`update_acc`, :meth:`update_mag`,
    :meth:`update_gyr` (zero-order hold); offline: :func:`align_to_gyro` (interpolation).

    Convention mapping to ``ahrs.filters.Madgwick`` (earth frame NWU): with
    ``mag_objective="madgwick", integration="euler"`` and the same β, the quaternion here in ENU is
    ``q_enu = q_z(+90°) ⊗ q_nwu`` and in NED ``q_ned = [0, 1, 0, 0] ⊗ q_nwu``, sample by
    sample to rounding, from the same initial quaternion (ahrs's MARG start, ``ecompass``,
    is the same TRIAD orientation). ahrs skips the whole update when the gyro reads exactly
    zero; this filter still corrects then. The recursion runs in NWU whatever the output
    frame, because the unit-norm form of the objective makes the normalised step depend on
    the earth frame (see :func:`margtrack.kernels.gradient.gradient_filter`).
    """

    name = "gradient"
    params_type = GradientParams
    kept_on_restart = ("acc_held", "mag_held", "mag_ref")

    def _new_state(self, quat0: Array) -> GradientState:
        n = quat0.shape[0]
        return GradientState(
            quat=np.array(quat0, dtype=np.float64),
            acc_held=np.zeros((n, 3)),
            mag_held=np.zeros((n, 3)),
            mag_ref=np.zeros((n, 2)),
        )

    def _initial_quat(self, acc0: Array, mag0: Array | None) -> Array:
        return super()._initial_quat(acc0, mag0 if self._params.use_mag else None)

    def _process(
        self,
        state: GradientState,
        gyr: Array | None,
        acc: Array,
        mag: Array | None,
        dt: Array,
    ) -> tuple[Array, dict[str, NDArray[Any]]]:
        assert gyr is not None  # guaranteed by uses_gyr; narrows the type
        p = self._params
        n_sensors, n = acc.shape[0], acc.shape[1]
        has_mag = mag is not None and p.use_mag
        quat = np.empty((n_sensors, n, 4))
        euler = np.empty((n_sensors, n, 3))
        gravity = np.empty((n_sensors, n, 3))
        lin_acc = np.empty((n_sensors, n, 3))
        flags = np.empty((n_sensors, n), dtype=np.int8)
        kernel.gradient_filter(
            state.quat, state.mag_ref, _read_only(gyr), _read_only(acc),
            _read_only(mag if (has_mag and mag is not None) else np.zeros((n_sensors, 1, 3))),
            has_mag, _read_only(dt), p.beta, _FROM_NWU[p.frame], frames.up(p.frame),
            MAG_OBJECTIVES[p.mag_objective], p.integration == "exact", p.gravity_m_s2,
            quat, euler, gravity, lin_acc, flags,
        )
        state.acc_held[...] = acc[:, -1]
        if mag is not None:
            state.mag_held[...] = mag[:, -1]
        outputs: dict[str, NDArray[Any]] = {
            "euler_rad": euler,
            "gravity_body_m_s2": gravity,
            "lin_acc_earth_m_s2": lin_acc,
            "ignored": flags,
        }
        return quat, outputs

    def _method_flags(self, outputs: Mapping[str, NDArray[Any]]) -> NDArray[np.uint16] | None:
        """``ignored`` in the flag schema: ``ACC_IGNORED`` → ``Flag.ACC_IGNORED``,
        ``MAG_REJECTED`` → ``Flag.MAG_IGNORED``.

        A zero field is the screening's sentinel, already flagged with its reason
        (MAG_IGNORED, or MAG_DISTURBED alone), so the kernel's ``MAG_IGNORED`` bit is not
        mapped; what the filter adds is the usable field it could not use.
        """
        return _SCHEMA[outputs["ignored"]]
