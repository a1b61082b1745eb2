"""Parameters of Marins' EKF (:class:`margtrack.methods.ekf.MarinsEkf`): the model, noise and fit.

Declared once here (unit, bounds, default, help beside each field); the estimator, its
model and the options are described in :mod:`margtrack.methods.ekf`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from margtrack.estimator import Params, param
from margtrack.frames import STANDARD_GRAVITY_M_S2

Array = NDArray[np.float64]
PerAxis = float | tuple[float, float, float]

__all__ = ["MarinsEkfParams", "PerAxis"]

_PER_AXIS = (
    "tau_s", "rate_noise_rad_s_sqrt_hz", "gyr_noise_rad_s_sqrt_hz", "gyr_bias_walk_rad_s_sqrt_s"
)


@dataclass(frozen=True)
class MarinsEkfParams(Params):
    """Parameters of Marins' EKF: the process model, noise densities and the fit.

    Noise is given as white-noise densities, so one set works at any sample rate: a
    sample's measurement variance is ``density² / dt``. Only ratios matter to the gains:
    raising ``quat_noise_per_sqrt_hz`` (or the acc/mag noise for approach 1) makes the
    filter trust the gyroscope longer; raising ``rate_noise_rad_s_sqrt_hz`` lets the rate
    state follow the gyroscope more closely.

    Defaults: the one set for all 16 BROAD trials (286 Hz) that
    :func:`margtrack.bench.tune.tune` found best. τ and the driving noise follow 001's rule
    (match the spectrum of the rates of normal motion): BROAD's gyroscope signals have a
    correlation time of about 0.3 s (lag 0.1 s) and an rms of 1.85 rad/s, so
    ``τ = 0.3`` s and ``σ = 1.85 √(2τ) ≈ 1.4`` rad/s/√Hz (τ in {0.15, 0.3, 0.6} s with σ
    in {0.7, 1.4, 2.8} confirmed it). Tuned on that (approach 2, gyro null from each
    trial's still start): ``quat_noise_per_sqrt_hz`` in {0.022, ..., 0.22},
    ``gyr_noise_rad_s_sqrt_hz`` in {3e-4, 1e-3}, ``mag_weight`` in {0.8, 1}: mean total
    RMSE 4.65 deg (heading 2.63, inclination 3.53); ahrs's Madgwick with one tuned β:
    4.88 deg. Without the null (``gyr_null_rest_s=0``) the best was 5.70 deg at
    ``quat_noise_per_sqrt_hz = 0.022``: a gyro bias is signal to this model, so it needs a
    stronger pull to the measured quaternion. Approach 1's ``acc_noise_m_s2_sqrt_hz`` was
    tuned with the same process parameters (grid {0.14, 0.3, 0.5}), its relative
    magnetometer noise under the input screening (grid {0.0075, 0.011, 0.015, 0.02,
    0.025, 0.034, 0.07}): 4.26 deg (5.30 with the former 1.5 µT/√Hz, i.e. 0.034 in
    BROAD's 44 µT field, before the field's unit was taken out).

    approach : 2 (001's choice: gyro + Gauss-Newton quaternion, ``H = I``) or 1 (the nine
        nonlinear outputs).
    tau_s : τ, time constant of the first-order rate model (001 eqs. 9-11), s; a number or
        one per body axis. The rate decays towards 0 with it between samples.
    rate_noise_rad_s_sqrt_hz : density of the white noise ``w_r`` driving the rate model
        (001 Fig. 1, ``ω̇ = (-ω + w_r)/τ``), rad/s/√Hz; a number or one per axis. The
        rate's stationary std is ``density / √(2τ)``.
    gyr_noise_rad_s_sqrt_hz : gyroscope measurement noise density, rad/s/√Hz; a number or
        one per axis.
    quat_noise_per_sqrt_hz : noise density of each component of the Gauss-Newton
        quaternion (approach 2), 1/√Hz (the quaternion is dimensionless; a component error
        ε is a rotation of about 2ε rad). The paper's additive 4-D form, ``R = r I₄``.
        While the field is unusable the gravity direction alone is used, with twice the
        angular noise (see :mod:`margtrack.methods.ekf.kernel`).
    acc_noise_m_s2_sqrt_hz : accelerometer noise density (approach 1), m/s²/√Hz; divided
        by ``gravity_m_s2`` for the unit gravity direction. Linear acceleration belongs
        in it.
    mag_noise_rel_sqrt_hz : magnetometer noise density (approach 1) relative to the field
        norm, 1/√Hz: the unit field direction's noise, so the results do not depend on
        the field's unit (0.02: 0.9 µT/√Hz in BROAD's 44 µT field).
    mag_weight : ρ, weight of the magnetic residual in the Gauss-Newton fit (000 eq. 17);
        1 is 001's equal weighting, lower lets the field pull less on inclination.
    gn_tolerance : Gauss-Newton stopping criterion on Q = |ε_g|² + ρ²|ε_m|² or its change
        over an update (dimensionless, unit vectors); default 1e-14, a residual of 1e-7
        (with the 1e-10 of ``gauss-newton`` the measured quaternion of ideal data stops
        ~5e-6 from the truth, which the filter then inherits).
    gn_max_iterations : cap on Gauss-Newton updates per sample. The fit starts from the
        prediction; on real data (inconsistent vectors) it converges only linearly, so the
        cap, not the tolerance, usually ends it.
    mag_dip_ref_deg (shared) : magnetic dip of the reference field, deg, positive down;
        the same number is the screening's reference dip. None (default): measured from
        each sensor's first valid sample and kept across restarts.
    gravity_m_s2 : gravity magnitude for approach 1's accelerometer noise, m/s².
    init_rate_std_rad_s : initial rate uncertainty per axis, rad/s (also after a restart).
    init_quat_std : initial uncertainty of each quaternion component (also after a
        restart: the covariance of the attitude is not kept over a gap).
    gyr_null_rest_s : the gyro null point is the mean rate over the still period that
        starts the recording, if it lasts at least this long, s; 0: raw gyro. 001's rate
        model has no bias state: a bias enters the measured rate as signal (see
        :mod:`margtrack.methods.rest_null`; 000 Appendix B step 1 calibrates the null the
        same way). A restart keeps it.
    bias_states : False (default): 001's 7-state filter as printed. True: the state is
        ``[ω, q, b]`` (10), the gyroscope measures ``ω + b``, b a random walk (003's
        augmented state; :mod:`margtrack.methods.ekf.bias_kernel`); b is what is left after the
        null, and the output ``gyr_bias_rad_s`` is null + b.
    gyr_bias_walk_rad_s_sqrt_s : density of b's random walk, rad/s/√s (= rad/s²/√Hz); a
        number or one per axis. Raising it lets the bias estimate follow faster and
        noisier.
    init_bias_std_rad_s : b's initial standard deviation per axis, rad/s (the first start
        sets b = 0; a restart keeps b and its covariance). The defaults of the two suit an
        unknown bias of up to about 1 deg/s (a simulated 1 deg/s bias is learned to 0.1
        deg/s in 2 min of motion). On BROAD (16 trials, leave-one-trial-out over walk
        {1e-6, 1e-5}, init {0.0005, 0.002}, quat noise {0.15, 0.3, 0.6}) the option
        scores 4.67 deg cross-validated (in-sample best 4.15: walk 1e-6, init 0.0005,
        quat noise 0.15) against 4.31 without it (quat noise {0.04, 0.075, 0.15});
        without the still-start null 5.94 against 5.27: BROAD's biases are small and
        the bias state takes up disturbances, so it stays off by default.
    mag_disturbance_s : correlation time of field disturbances, s (0: 001's fixed noise).
        A sample's field norm off its reference (the first usable field's, then following
        it with the screening's 60 s time constant) by a fraction d is a disturbance of
        the unit field's components with variance d² and this correlation time: its share
        of a sample, ``2 T d² / h``, enters the Gauss-Newton quaternion's covariance
        through the fit's Jacobian (:mod:`margtrack.methods.ekf.noise`), mostly on the
        heading. Raising it trusts a field off its norm less. Default 1 s: BROAD's
        in-sample best of {0.3, 1, 3} (3.23 deg with quat noise 0.0375 and mag_norm_tol
        0.15, 3.36 at the other defaults, against 3.91 as printed); cross-validated over
        the declared grid 3.34 deg against 4.28 as printed.
    acc_disturbance_s : correlation time of linear acceleration, s (0, the default: 001's
        fixed noise). The same for the accelerometer's distance from gravity's norm
        (``gravity_m_s2``), mostly on the tilt. Off: worse on BROAD at every value tried.
    """

    approach: int = param(
        2, ge=1, le=2, help="2: gyro + Gauss-Newton quaternion (H = I); 1: nine vector outputs"
    )
    tau_s: PerAxis = param(
        0.3, unit="s", gt=0, help="time constant of the rate model (one number or x, y, z)"
    )
    rate_noise_rad_s_sqrt_hz: PerAxis = param(
        1.4, unit="rad/s/√Hz", gt=0, help="density of the noise driving the rate model"
    )
    gyr_noise_rad_s_sqrt_hz: PerAxis = param(
        3e-4, unit="rad/s/√Hz", gt=0, help="gyroscope measurement noise density"
    )
    quat_noise_per_sqrt_hz: float = param(
        0.075,
        unit="1/√Hz",
        gt=0,
        help="noise density of each Gauss-Newton quaternion component (approach 2)",
    )
    acc_noise_m_s2_sqrt_hz: float = param(
        0.3, unit="m/s²/√Hz", gt=0, help="accelerometer noise density (approach 1)"
    )
    mag_noise_rel_sqrt_hz: float = param(
        0.02,
        unit="1/√Hz",
        gt=0,
        help="magnetometer noise density relative to the field norm (approach 1)",
    )
    mag_weight: float = param(
        1.0, gt=0, help="weight rho of the magnetic residual in the Gauss-Newton fit"
    )
    gn_tolerance: float = param(
        1e-14, ge=0, help="Gauss-Newton stops when the criterion or its change is below this"
    )
    gn_max_iterations: int = param(
        2, ge=1, le=1000, help="cap on Gauss-Newton updates per sample"
    )
    gravity_m_s2: float = param(
        STANDARD_GRAVITY_M_S2, unit="m/s²", gt=0, help="gravity for approach 1's acc noise"
    )
    init_rate_std_rad_s: float = param(
        1.0, unit="rad/s", gt=0, help="initial rate uncertainty per axis (and after restarts)"
    )
    init_quat_std: float = param(
        0.5, gt=0, le=2, help="initial uncertainty of each quaternion component"
    )
    gyr_null_rest_s: float = param(
        1.0,
        unit="s",
        ge=0,
        help="gyro null from a still start at least this long (0: raw gyro); kept on restarts",
    )
    bias_states: bool = param(
        False, help="add a gyro bias state b (the gyro measures rate + b; 003's augmented state)"
    )
    gyr_bias_walk_rad_s_sqrt_s: PerAxis = param(
        1e-4,
        unit="rad/s/√s",
        ge=0,
        help="random-walk density of the gyro bias state (bias_states; one number or x, y, z)",
        calibrated_by="noise.gyr_bias_walk_rad_s2_sqrt_hz",
    )
    init_bias_std_rad_s: float = param(
        0.01,
        unit="rad/s",
        gt=0,
        help="initial uncertainty of the gyro bias state per axis (bias_states; kept on restarts)",
    )
    acc_disturbance_s: float = param(
        0.0,
        unit="s",
        ge=0,
        help="correlation time of linear acceleration in the measurement noise (0: 001's fixed)",
    )
    mag_disturbance_s: float = param(
        1.0,
        unit="s",
        ge=0,
        help="correlation time of field disturbances in the measurement noise (0: 001's fixed)",
    )

    def check(self) -> None:
        """Per-axis parameters: one number or three."""
        super().check()
        for name in _PER_AXIS:
            value = getattr(self, name)
            if isinstance(value, tuple) and len(value) != 3:
                raise ValueError(
                    f"parameter {name} must be a number or three of them (one per body axis), "
                    f"got {len(value)}"
                )

    def axis_values(self, name: str) -> Array:
        """A per-axis parameter as a (3,) array."""
        return np.ascontiguousarray(
            np.broadcast_to(np.asarray(getattr(self, name), dtype=np.float64), (3,))
        )
