"""Bachmann's quaternion complementary filter with Gauss-Newton drift correction (000, App. A).

Each sample: rate quaternion from the gyroscope ``q̇ = ½ q̂ ⊗ (0, ω)`` (eq. 26), plus a drift
correction ``q̇_ε = k Δq_full`` (eq. 25) that pulls the gravity and field predicted in the
body frame, ``ĥ = q̂* ⊗ m ⊗ q̂`` and ``b̂ = q̂* ⊗ n ⊗ q̂`` (eqs. 13-14), towards the measured
unit vectors ``h`` and ``b``; then Euler integration and normalisation (eq. 27).

The correction is one reduced-order Gauss-Newton step on the error (eqs. 15-18)
``ε = [h - ĥ; ρ (b - b̂)]`` with criterion ``φ = εᵀε`` (eq. 19):

- ``X`` (6×4, eq. 20) holds the derivatives of ``[ĥ; b̂]`` with respect to the four
  components of ``q̂`` (:func:`x_matrix`); ``∂ĥ/∂q_j = (e_j* ⊗ m ⊗ q̂ + q̂* ⊗ m ⊗ e_j)``
  with ``e_0 = 1, e_1 = i, e_2 = j, e_3 = k``. It is the derivative of the prediction, so
  ``ε`` changes by ``-X dq``; eq. 20 carries no ``ρ``.
- ``X_v = X [q̂⊗i, q̂⊗j, q̂⊗k]`` (6×3, eq. 22) is the derivative along ``q̂ ⊗ (1, v)``.
  Derived: ``d/dt (q̂ + t q̂⊗e)* ⊗ m ⊗ (q̂ + t q̂⊗e) = -e ⊗ ĥ + ĥ ⊗ e``, whose vector part is
  ``2 ĥ × e``, so ``X_v = 2 [[ĥ]×; [b̂]×]`` (:func:`xv_matrix`, tested against both).
- The step (eq. 23; the paper's ``X_v ε`` is a slip for ``X_vᵀ ε``) becomes
  ``Δv_full = (X_vᵀ X_v)⁻¹ X_vᵀ ε = ½ M⁻¹ (h × ĥ + ρ b × b̂)`` with
  ``M = 2 I - ĥĥᵀ - b̂b̂ᵀ``; rotated to the earth frame ``M`` becomes the constant
  ``M0 = 2 I - m mᵀ - n nᵀ`` (det ``2 sin² γ``, γ the angle between m and n), which is
  how the kernel computes it. Without a magnetometer ``M`` is singular along ``ĥ``; the
  minimum-norm step ``½ h × ĥ`` leaves the heading alone.

``ρ`` scales the magnetic residual but not its Jacobian, as eqs. 17-20 are written.
Hence the heading (seen by the magnetometer only) is corrected at rate ``ρ k`` while
tilt is corrected at rate ``k``; ``ρ → 0`` lets the heading drift, the behaviour 000
reports ("Weighted Least Squares"). (With ``ρ`` in the Jacobian too, the heading step
would not depend on ``ρ`` at all.) In the linear range the error decays like
``exp(-k t)``, so its square reaches 37 % at ``t = 1/(2k)`` (000, eq. 12).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.estimator import Estimate, Params, param
from margtrack.estimator import skeleton as kc
from margtrack.estimator.compiled import CompiledEstimator, CompiledState
from margtrack.estimator.outputs import with_output_types
from margtrack.methods import rest_null_kernel
from margtrack.methods.bachmann import kernel
from margtrack.methods.rest_null import (
    check_rows,
    rest_null_coefficients,
    rest_null_layout,
)

Array = NDArray[np.float64]

__all__ = [
    "Bachmann",
    "BachmannAccMag",
    "BachmannAccMagParams",
    "BachmannParams",
    "criterion",
    "error_vector",
    "gauss_newton_step",
    "predicted_vectors",
    "x_matrix",
    "xv_matrix",
]

#: Smallest angle between the gravity and field references, deg: below it the heading is
#: ill-defined (``det M0 = 2 sin² γ``). A given field reference closer than 5 deg to
#: vertical is refused; a measured dip is limited to ±(90 - 5) deg.
MIN_REFERENCE_ANGLE_DEG = 5.0


def _vector3(value: Any, name: str) -> tuple[float, float, float]:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or not np.linalg.norm(arr) > 0:
        raise ValueError(
            f"parameter {name} must be a finite, non-zero 3-vector (earth frame); got {value!r}"
        )
    return (float(arr[0]), float(arr[1]), float(arr[2]))


@dataclass(frozen=True)
class BachmannParams(Params):
    """Parameters of the Bachmann filter (000, Appendix A).

    gain : ``k`` (eq. 25), 1/s. Tilt errors decay like ``exp(-k t)`` (squared error to
        37 % at ``1/(2k)``, eq. 12). Raising it follows the accelerometer and magnetometer
        faster: less gyro drift (a gyro bias b leaves an error b/k), more noise and more
        error from linear acceleration and magnetic disturbances. 0 is pure gyro
        integration. Keep ``k·dt`` well below 1 (eq. 27).
    mag_weight : ``ρ`` (eq. 17). Scales the magnetic residual: heading errors decay at rate
        ``ρ k``. Lowering it resists magnetic disturbances but lets heading drift.
    correction_interval : a new drift correction every n-th sample; in between the latest
        one is reused, as in 000's 16-filter experiment.
    round_robin : False: every sensor computes its new corrections at the same samples.
        True: sensor ``s`` computes them at cycles ``c`` with
        ``(c - s) % correction_interval == 0``, so with ``correction_interval`` equal to
        the number of sensors exactly one filter corrects per cycle (000, "Reduce Rate
        Drift Correction": one correction per 100 Hz cycle shared by 16 filters).
    gyr_null_rest_s : the gyro null point (000 Appendix B step 1) is the mean rate over the
        still period that starts the recording, if it lasts at least this long, s;
        0: no null (the raw gyro, as in 000's static-stability test). See
        :mod:`margtrack.methods.rest_null`. 000 stresses that a rate bias b leaves a
        steady error of about b/k ("Rate Sensor Bias Compensation"). The null is
        calibration: a restart after a gap keeps it.
    restart_gain : after a restart (a gap longer than ``max_gap_s``) the filter starts
        again from the TRIAD orientation of one sample, whose error (linear acceleration:
        tens of degrees in fast motion) the small ``gain`` would take tens of seconds to
        remove, 1/s. From the restart the gain is ``1 / (t + 1/restart_gain)``, which
        makes the correction the mean of all measurements since the restart (the
        restart sample weighted as ``1/restart_gain`` s of them), until that falls to
        ``gain`` (after ``1/gain - 1/restart_gain`` s); ``restart_gain <= gain``: off. The
        first start after a reset is not raised: recordings start still (000), where
        TRIAD is exact. Default 10: over 1 s gaps cut into the motion of five BROAD
        trials the RMSE of the 20 s after the gap is 2.4 times that without the gap
        (6.5 times without the raised gain; 1, 3, 5, 20, 100: 3.5, 2.7, 2.5, 2.5, 2.8);
        on 90 s of simulated random motion (4 seeds, 1 and 5 s gaps) 0.95 (1.35).
    mag_dip_ref_deg (shared) : the magnetic inclination for the field reference ``n``,
        deg, positive down; the same number is the screening's reference dip. None
        (default) measures it for each sensor from its first usable sample (angle
        between accelerometer and magnetometer; 000's "determined during the calibration
        process"), limited to ±85 deg, and keeps it across restarts.
    gravity_reference : ``m`` as an earth-frame 3-vector (direction used); None: up in
        ``frame`` (what a level accelerometer reads).
    mag_reference : ``n`` as an earth-frame 3-vector (direction used), e.g. measured by a
        calibration; None: from ``mag_dip_ref_deg`` (or measured). When both are given
        ``mag_reference`` wins for the filter's reference (it is the complete statement:
        direction and heading offset); ``mag_dip_ref_deg`` then only drives the screening.
    frame : earth frame of the output, "ENU" (default) or "NED".

    The defaults of ``gain`` and ``mag_weight`` are the best single pair for all 16 BROAD
    trials of ../shared/data/broad (``margtrack tune``, k in 0.03-0.15 /s, ρ in 0.5-1, dip
    measured at the start, the gyro null from each trial's still start): mean total RMSE
    4.22 deg (heading 3.22, inclination 2.50). Without the null (``gyr_null_rest_s=0``)
    the best pair is k = 0.11, ρ = 0.8 at 5.15 deg: the larger k needed against BROAD's
    0.1-0.5 deg/s gyro biases lets in more linear acceleration.
    """

    gain: float = param(
        0.06, unit="1/s", ge=0, help="drift-correction gain k: tilt errors decay like exp(-k t)"
    )
    mag_weight: float = param(
        0.7, ge=0, help="weight rho of the magnetic residual: heading errors decay at rho k"
    )
    correction_interval: int = param(
        1, ge=1, help="a new drift correction every n-th sample (the latest one reused between)"
    )
    round_robin: bool = param(
        False, help="stagger the sensors' corrections: sensor s corrects at cycles c = s (mod n)"
    )
    gyr_null_rest_s: float = param(
        1.0,
        unit="s",
        ge=0,
        help="gyro null from a still start at least this long (0: raw gyro); kept on restarts",
    )
    restart_gain: float = param(
        10.0,
        unit="1/s",
        ge=0,
        help="gain right after a restart (gap), falling as 1/t to gain (<= gain: off)",
    )
    gravity_reference: tuple[float, float, float] | None = param(
        None, help="earth-frame gravity reference m (direction; None: up in frame)"
    )
    mag_reference: tuple[float, float, float] | None = param(
        None, help="earth-frame field reference n (direction; None: from mag_dip_ref_deg)"
    )

    def check(self) -> None:
        """Reference vectors: finite, non-zero, at least 5 deg apart."""
        super().check()
        for name in ("gravity_reference", "mag_reference"):
            value = getattr(self, name)
            if value is not None:  # stored as a tuple of floats (hashable, comparable)
                object.__setattr__(self, name, _vector3(value, name))
        field_unit = self.mag_unit()
        if field_unit is not None:
            _check_reference_angle(self.gravity_unit(), field_unit)

    def gravity_unit(self) -> Array:
        """Unit gravity reference ``m`` (3,) in ``frame``."""
        if self.gravity_reference is None:
            return frames.up(self.frame)
        g = np.array(self.gravity_reference)
        return g / np.linalg.norm(g)

    def mag_unit(self) -> Array | None:
        """Unit field reference ``n`` (3,) in ``frame``; None when measured at the start."""
        if self.mag_reference is not None:
            n = np.array(self.mag_reference)
            return n / np.linalg.norm(n)
        if self.mag_dip_ref_deg is not None:
            return frames.mag_reference(self.frame, self.mag_dip_ref_deg)
        return None


def _triad_axes(first: Array, second: Array) -> Array:
    """Orthonormal axes (columns) ``a``, ``a × b / |.|``, ``a × (a × b) / |.|``."""
    a = first / np.linalg.norm(first)
    b = np.cross(a, second)
    b /= np.linalg.norm(b)
    return np.stack([a, b, np.cross(a, b)], axis=1)


def _check_reference_angle(m: Array, n: Array) -> None:
    sine = float(np.linalg.norm(np.cross(m, n)))
    if sine < np.sin(np.radians(MIN_REFERENCE_ANGLE_DEG)):
        raise ValueError(
            f"the field reference is {np.degrees(np.arcsin(min(sine, 1.0))):.2f} deg from the "
            f"gravity reference; it must be at least {MIN_REFERENCE_ANGLE_DEG} deg away "
            "(the heading is undefined for a vertical field): check mag_dip_ref_deg or "
            "mag_reference"
        )


def _turns(p: BachmannParams) -> tuple[Array, Array]:
    """The turns onto explicit reference vectors of a start without and with a field (4,)
    each: the shortest arc from up to ``m``, and the rotation taking (up, north) onto
    (``m``, ``n``) (the TRIAD of the references; ``n`` is north at dip 0 when only ``m`` is
    given)."""
    up, m = frames.up(p.frame), p.gravity_unit()
    arc = quat.shortest_arc(up, m)
    n = p.mag_unit() if p.mag_reference is not None else frames.mag_reference(p.frame)
    std = _triad_axes(up, frames.mag_reference(p.frame))
    return arc, quat.from_matrix(_triad_axes(m, n) @ std.T)


#: outputs as they were before the compiled path: width-1 series squeezed to (…, N), and
#: their types
_OUTPUT_TYPES = {"phi": None, "new_correction": np.bool_, "degenerate": np.int8}


class Bachmann(CompiledEstimator[BachmannParams]):
    """Bachmann's quaternion complementary filter (``--method bachmann``), 000 Appendix A.

    Full MARG with ``mag``; gyroscope + accelerometer with ``mag=None`` (heading from the
    gyro alone). See :class:`BachmannAccMag` for tracking without a gyroscope. Screened
    samples: a zero accelerometer gives no correction, a zero magnetometer a gravity-only
    correction (heading from the gyro).

    Outputs (``Estimate.outputs``, leading axes as ``quat``):
    ``phi`` (N,) criterion of the correction in use (eq. 19), held between new ones;
    ``correction_rad_s`` (N, 3) the correction applied, as an earth-frame angular rate
    ``ω_ε`` with ``q̇_ε = ½ (0, ω_ε) ⊗ q̂`` (``= 2 k Δv_full`` rotated to the earth);
    ``new_correction`` (N,) bool, True where a new correction was computed;
    ``degenerate`` (N,) int8, method detail: 1 zero accelerometer (no correction; flagged
    ACC_IGNORED), 2 zero magnetometer (gravity-only correction; the screening's
    MAG_IGNORED or MAG_DISTURBED says why), 3 field reference not measured yet
    (gravity-only; flagged MAG_IGNORED), 0 otherwise;
    ``gyr_null_rad_s`` (N, 3) the gyro null subtracted (``gyr_null_rest_s``), rad/s.

    State (:class:`~margtrack.estimator.compiled.CompiledState`, ``state.get(name)``, each
    (S, width)): ``quat`` ``q̂``; ``correction_step`` the held step ``Δv_E`` (earth frame,
    rad/2); ``phi`` its criterion; ``dip_rad`` the measured field inclination (NaN: not
    yet; kept across restarts); ``field_reference`` the unit ``n`` from it;
    ``restart_elapsed_s`` time since a restart while its raised gain lasts (-1: none);
    ``awaiting_field`` 1 until a field sample sets the heading after a (re)start; ``cycle``
    samples since the reset (the correction schedule); ``gyr_bias_rad_s`` the gyro null in
    use (the still start's mean rate; 0 without one); the rest null's progress
    (``rest_null_*``). A restart after a gap starts the orientation and the correction
    afresh and keeps the rest (what is known of the sensor); after a sensor has been
    tracking (or a ``reset(q0)``) it raises the gain (``restart_gain``).
    """

    name = "bachmann"
    params_type = BachmannParams
    kernel = kernel
    state_layout: ClassVar[Mapping[str, tuple[int, int]]] = {
        "quat": (kernel.B_Q, 4),
        "correction_step": (kernel.B_STEP, 3),
        "phi": (kernel.B_PHI, 1),
        "restart_elapsed_s": (kernel.B_SINCE, 1),
        "awaiting_field": (kernel.B_AWAIT, 1),
        "cycle": (kernel.B_CYCLE, 1),
        "sensor_index": (kernel.B_INDEX, 1),
        "dip_rad": (kernel.B_DIP, 1),
        "field_reference": (kernel.B_REF, 3),
        "gyr_bias_rad_s": (kernel.B_NULL + rest_null_kernel.RN_NULL, 3),
        **rest_null_layout(kernel.B_NULL),
    }
    outputs_layout = (
        ("phi", 1),
        ("correction_rad_s", 3),
        ("new_correction", 1),
        ("degenerate", 1),
        ("gyr_null_rad_s", 3),
    )

    def _coefficients(self) -> Array:
        p = self.params
        c = np.zeros(kernel.N_COEF)
        c[kernel.C_GAIN] = p.gain
        c[kernel.C_MAG_WEIGHT] = p.mag_weight
        c[kernel.C_INTERVAL] = p.correction_interval
        c[kernel.C_ROUND_ROBIN] = 1.0 if p.round_robin else 0.0
        c[kernel.C_RESTART_GAIN] = p.restart_gain
        c[kernel.C_USE_GYR] = 1.0 if self.uses_gyr else 0.0
        m = p.gravity_unit()
        c[kernel.C_GRAV : kernel.C_GRAV + 3] = m
        fixed = p.mag_unit()
        if fixed is not None:
            c[kernel.C_FIXED_REF] = 1.0
            c[kernel.C_REF : kernel.C_REF + 3] = fixed
            usable, *minv = kernel.cofactors(*m, *fixed)
            c[kernel.C_MINV : kernel.C_MINV + 7] = minv
            c[kernel.C_HAS_REF] = 1.0 if usable else 0.0
        c[kernel.C_NED] = 1.0 if p.frame == "NED" else 0.0
        if p.gravity_reference is not None or p.mag_reference is not None:
            arc, triad = _turns(p)
            c[kernel.C_TURN] = 1.0
            c[kernel.C_TURN_ARC : kernel.C_TURN_ARC + 4] = arc
            c[kernel.C_TURN_TRIAD : kernel.C_TURN_TRIAD + 4] = triad
        c[kernel.C_NULL : kernel.C_NULL + rest_null_kernel.N_RC] = rest_null_coefficients(
            p.gyr_null_rest_s
        )
        return c

    def _new_rows(self, n_sensors: int) -> CompiledState:
        """Fresh rows, each knowing its sensor's index (its round-robin turn)."""
        state = super()._new_rows(n_sensors)
        state.rows[:, kernel.B_INDEX] = np.arange(n_sensors)
        return state

    @CompiledEstimator.state.setter  # type: ignore[attr-defined]
    def state(self, value: CompiledState | None) -> None:
        """Set the state; one whose orientation is not finite and non-zero is refused."""
        if value is not None:
            check_rows(value, kernel.N_ROW, kernel.B_Q, value.rows[:, kc.K_READY] > 0)
        CompiledEstimator.state.fset(self, value)  # type: ignore[attr-defined]

    def _run_arrays(self, *args: Any, **kwargs: Any) -> Estimate:
        return with_output_types(super()._run_arrays(*args, **kwargs), _OUTPUT_TYPES)


@dataclass(frozen=True)
class BachmannAccMagParams(BachmannParams):
    """Bachmann parameters for acc/mag-only tracking: only the default gain differs.

    gain : k, 1/s; default 40, the best single value on the 16 BROAD trials (41.7 deg
        mean total RMSE, against 86.9 deg at the gyro-aided default 0.11 and 47.8 deg for
        TRIAD): without a gyro the correction alone must follow the motion (the raised
        gain after a restart, ``restart_gain`` < ``gain``, then changes nothing).
    """

    gain: float = param(
        40.0, unit="1/s", ge=0, help="drift-correction gain k: the follower's rate, 1/s"
    )


class BachmannAccMag(Bachmann):
    """The Bachmann filter without a gyroscope (``--method bachmann-accmag``).

    000, "Accelerometer/Magnetometer Only Tracking": the filter is driven by the drift
    correction alone, ``q̂ + Δt q̇_ε`` (eq. 27 without eq. 26), a first-order follower of
    the Gauss-Newton solution with time constant ``1/k``. Gyroscope data, if given, are
    ignored; a magnetometer is required. Fine for slow motion; at high gain it overshoots
    after quick motions (linear acceleration is taken for gravity). While the field is
    ignored (zero after screening) the heading holds.
    """

    name = "bachmann-accmag"
    params_type = BachmannAccMagParams
    uses_gyr = False
    mag_optional = False
    outputs_layout = Bachmann.outputs_layout[:-1]  # no gyroscope, no gyro null
    state_layout: ClassVar[Mapping[str, tuple[int, int]]] = {
        k: v
        for k, v in Bachmann.state_layout.items()
        if k != "gyr_bias_rad_s" and not k.startswith("rest_null")
    }

    def update(
        self,
        gyr: ArrayLike | None,
        acc: ArrayLike,
        mag: ArrayLike | None = None,
        dt: float | None = None,
    ) -> Array:
        """As :meth:`Bachmann.update`; a gyroscope sample, if given, is dropped before the
        screening, as ``run`` drops the series (so it is neither used nor flagged)."""
        return super().update(None, acc, mag, dt)


# -- Appendix A written out, one sample, for reference and tests ---------------------------
def _pure(v: ArrayLike) -> Array:
    return np.concatenate([[0.0], np.asarray(v, dtype=np.float64)])


def _unit(v: ArrayLike) -> Array:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def predicted_vectors(q: ArrayLike, grav_ref: ArrayLike, mag_ref: ArrayLike) -> tuple[Array, Array]:
    """``ĥ = q* ⊗ m ⊗ q`` and ``b̂ = q* ⊗ n ⊗ q`` (eqs. 13-14), unit 3-vectors in the body."""
    qc = quat.conjugate(q)
    h = quat.multiply(quat.multiply(qc, _pure(_unit(grav_ref))), q)[1:]
    b = quat.multiply(quat.multiply(qc, _pure(_unit(mag_ref))), q)[1:]
    return _unit(h), _unit(b)


def error_vector(
    q: ArrayLike,
    acc: ArrayLike,
    mag: ArrayLike,
    grav_ref: ArrayLike,
    mag_ref: ArrayLike,
    mag_weight: float,
) -> Array:
    """``ε = [h - ĥ; ρ (b - b̂)]`` (6,) with unit measured ``h``, ``b`` (eqs. 15-18)."""
    h_hat, b_hat = predicted_vectors(q, grav_ref, mag_ref)
    return np.concatenate([_unit(acc) - h_hat, mag_weight * (_unit(mag) - b_hat)])


def criterion(
    q: ArrayLike,
    acc: ArrayLike,
    mag: ArrayLike,
    grav_ref: ArrayLike,
    mag_ref: ArrayLike,
    mag_weight: float,
) -> float:
    """``φ = εᵀ ε`` (eq. 19)."""
    e = error_vector(q, acc, mag, grav_ref, mag_ref, mag_weight)
    return float(e @ e)


def x_matrix(q: ArrayLike, grav_ref: ArrayLike, mag_ref: ArrayLike) -> Array:
    """``X`` (6, 4) as eq. 20 writes it: column j is ``∂[q*⊗m⊗q; q*⊗n⊗q]/∂q_j``, vector part.

    Row j of eq. 20 is ``(e_j* ⊗ m) ⊗ q̂ + q̂⁻¹ ⊗ (m ⊗ e_j)``, ``e_j`` = 1, i, j, k (eq. 21).
    """
    q = np.asarray(q, dtype=np.float64)
    qc = quat.conjugate(q)
    cols = []
    for e in np.eye(4):
        part = []
        for ref in (grav_ref, mag_ref):
            r = _pure(_unit(ref))
            d = quat.multiply(quat.multiply(quat.conjugate(e), r), q)
            d = d + quat.multiply(qc, quat.multiply(r, e))
            part.append(d[1:])
        cols.append(np.concatenate(part))
    return np.stack(cols, axis=1)


def xv_matrix(q: ArrayLike, grav_ref: ArrayLike, mag_ref: ArrayLike) -> Array:
    """``X_v = X [q̂⊗i, q̂⊗j, q̂⊗k]`` (6, 3) (eq. 22); equals ``2 [[ĥ]×; [b̂]×]``."""
    basis = np.stack([quat.multiply(q, e) for e in np.eye(4)[1:]], axis=1)  # (4, 3)
    return x_matrix(q, grav_ref, mag_ref) @ basis


def gauss_newton_step(
    q: ArrayLike,
    acc: ArrayLike,
    mag: ArrayLike,
    grav_ref: ArrayLike,
    mag_ref: ArrayLike,
    mag_weight: float,
) -> Array:
    """``Δv_full = (X_vᵀ X_v)⁻¹ X_vᵀ ε`` (3,), body frame (eq. 23), by a linear solve."""
    xv = xv_matrix(q, grav_ref, mag_ref)
    e = error_vector(q, acc, mag, grav_ref, mag_ref, mag_weight)
    return np.linalg.solve(xv.T @ xv, xv.T @ e)
