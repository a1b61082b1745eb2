"""Parameters of the joint estimators, declared once per field (unit, bounds, default, help).

One set serves both estimators: the online filter (:mod:`margtrack.joint.kernel`) and the
offline MAP (:mod:`margtrack.joint.offline`) use the same noise model, so the offline
estimate is the smoothed solution of the very model the filter runs forward.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from margtrack.estimator.params import param, specs

__all__ = ["JointParams"]


@dataclass(frozen=True)
class JointParams:
    """Noise model and input policy of :func:`margtrack.joint.relative_orientation`.

    The model (docs/joint.md): each sensor's orientation follows its gyroscope with white
    rate noise of density ``gyr_noise_rad_s_sqrt_hz`` (per axis, earth frame); the two
    sensors see the same joint-centre acceleration, so their joint-centre specific forces
    rotated to the earth frame differ by noise of std ``link_noise_m_s2`` per axis; the
    mean of the two is gravity plus the joint's own acceleration, whose horizontal part is
    taken as noise of std ``sqrt(incl_noise_m_s2² + incl_norm_gain · (|mean| - g)²)``, so
    the inclination is trusted less while the joint accelerates.

    Only ratios matter to the estimate: raising ``link_noise_m_s2`` makes the estimate
    follow the gyroscopes longer and correct the relative orientation more slowly; raising
    ``gyr_noise_rad_s_sqrt_hz`` does the opposite.
    """

    gyr_noise_rad_s_sqrt_hz: float = param(
        0.01, unit="rad/s/√Hz", gt=0,
        help="gyroscope rate noise density (white noise and unmodelled errors), per axis")
    link_noise_m_s2: float = param(
        0.5, unit="m/s²", gt=0,
        help="std per axis of the difference of the two joint-centre accelerations")
    incl_noise_m_s2: float = param(
        1.0, unit="m/s²", gt=0,
        help="std per horizontal axis of the mean joint-centre specific force at rest")
    incl_norm_gain: float = param(
        1.0, ge=0,
        help="inclination variance added per (m/s²)² of the mean's norm away from gravity")
    init_heading_std_deg: float = param(
        60.0, unit="deg", gt=0, le=180,
        help="std of the first guess of the relative heading (unobservable at rest)")
    init_incl_std_deg: float = param(
        6.0, unit="deg", gt=0, le=90,
        help="std of each sensor's first inclination, taken from its accelerometer")
    gyr_timing: str = param(
        "instant", choices=("instant", "interval"),
        help="what a gyroscope sample is: the rate at its timestamp (integrated by the "
        "trapezoid rule) or the mean rate since the previous sample")
    gravity_m_s2: float = param(9.81, unit="m/s²", gt=0, help="gravity magnitude")
    gyr_range_deg_s: float = param(
        2000.0, unit="deg/s", gt=0,
        help="gyroscope range: a rate at or beyond it is flagged and the last good one used")
    acc_range_g: float = param(
        16.0, unit="g", gt=0,
        help="accelerometer range: a sample at or beyond it is flagged and not used")
    max_gap_s: float = param(
        0.25, unit="s", gt=0,
        help="longest interval integrated over; a longer gap restarts the relative heading")
    max_iterations: int = param(
        10, ge=1, help="offline: most Gauss-Newton iterations of the MAP")
    tolerance_rad: float = param(
        1e-3, unit="rad", gt=0,
        help="offline: stop when the largest orientation update is below it")

    def __post_init__(self) -> None:
        for spec in specs(self):
            object.__setattr__(self, spec.name, spec.check(getattr(self, spec.name)))

    def as_dict(self) -> dict[str, Any]:
        """The parameters as a plain dict (for outputs and reports)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}
