"""Sensor calibration and noise identification (000 eqs. 1-5 and Appendix B; 003 section III).

One model for every triad, ``y = K x + b`` (measured ``y``, true ``x``), corrected by
``x̂ = K⁻¹ (y - b)``: see :mod:`~margtrack.calibration.calibration_file`.

- :mod:`~margtrack.calibration.static`: still segments found from the data;
- :mod:`~margtrack.calibration.accelerometer`: six-position (eqs. 1-2), 12-parameter and
  norm least squares;
- :mod:`~margtrack.calibration.magnetometer`: min/max (eqs. 3-4), ellipsoid fit, axes
  aligned to gravity;
- :mod:`~margtrack.calibration.gyroscope`: null, scale from known turns (eq. 5);
- :mod:`~margtrack.calibration.reference`: gravity and field in the reference pose (step 18);
- :mod:`~margtrack.calibration.allan`: Allan deviation and noise densities (003 III-B);
- :mod:`~margtrack.calibration.guided`: the 18-step procedure as a state machine;
- :mod:`~margtrack.calibration.simulate_procedure`: a simulated recording of it.

Example::

    from margtrack.calibration import load_calibration
    calibrated = load_calibration("sensor.json").apply(recording)
"""

from margtrack.calibration.accelerometer import (
    AccelFit,
    SixPosition,
    fit_known_directions,
    fit_norm,
    nearest_axes,
    six_position,
)
from margtrack.calibration.allan import (
    AllanDeviation,
    NoiseDensities,
    NoiseTerms,
    allan_deviation,
    identify_noise,
    noise_densities,
    plot_allan,
)
from margtrack.calibration.calibration_file import (
    Calibration,
    TriadCalibration,
    load_calibration,
    save_calibration,
)
from margtrack.calibration.guided import (
    Event,
    GuidedCalibration,
    GuidedSettings,
    run_guided,
)
from margtrack.calibration.gyroscope import (
    GyroNull,
    GyroScale,
    RotationEstimate,
    fit_gyro_matrix,
    gyro_null,
    gyro_scale,
    integrate_rotation,
    rotation_estimate,
)
from margtrack.calibration.magnetometer import (
    EllipsoidFit,
    MinMax,
    align_to_gravity,
    fit_ellipsoid,
    min_max,
    sphere_coverage,
)
from margtrack.calibration.online_hard_iron import (
    hard_iron_calibration,
    last_offset_ut,
    save_hard_iron,
)
from margtrack.calibration.procedure_result import GuidedResult
from margtrack.calibration.reference import ReferenceVectors, reference_vectors
from margtrack.calibration.simulate_procedure import simulate_procedure
from margtrack.calibration.static import (
    StillnessDetector,
    StillnessSettings,
    segment_means,
    static_segments,
    still_mask,
)

__all__ = [
    "AccelFit",
    "AllanDeviation",
    "Calibration",
    "EllipsoidFit",
    "Event",
    "GuidedCalibration",
    "GuidedResult",
    "GuidedSettings",
    "GyroNull",
    "GyroScale",
    "MinMax",
    "NoiseDensities",
    "NoiseTerms",
    "ReferenceVectors",
    "RotationEstimate",
    "SixPosition",
    "StillnessDetector",
    "StillnessSettings",
    "TriadCalibration",
    "align_to_gravity",
    "allan_deviation",
    "fit_ellipsoid",
    "fit_gyro_matrix",
    "fit_known_directions",
    "fit_norm",
    "gyro_null",
    "gyro_scale",
    "hard_iron_calibration",
    "identify_noise",
    "integrate_rotation",
    "last_offset_ut",
    "load_calibration",
    "min_max",
    "nearest_axes",
    "noise_densities",
    "plot_allan",
    "reference_vectors",
    "rotation_estimate",
    "run_guided",
    "save_calibration",
    "save_hard_iron",
    "segment_means",
    "simulate_procedure",
    "six_position",
    "sphere_coverage",
    "static_segments",
    "still_mask",
]
