"""The declared tuning grid of each method: the parameters whose defaults were chosen on BROAD.

A method's figures on BROAD are in-sample when its defaults were picked on the same 16
trials; :mod:`margtrack.bench.cv` measures how much of that is fitting by choosing a point
of this grid without each trial and scoring the trial with it. Each grid names the
parameters that were tuned on BROAD (their docstrings and commits say so) with 3-5
candidates around the default, the default among them, each with a one-line reason.

``margtrack tune FOLDER -m METHOD --cv`` without ``-g`` and ``margtrack bench broad`` read
these grids; nothing else should declare them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["GRIDS", "GridParam", "declared_grid", "has_grid"]


@dataclass(frozen=True)
class GridParam:
    """Candidate values of one parameter and why that parameter is in the grid."""

    values: tuple[float | int | str, ...]
    reason: str


#: method -> {parameter: GridParam}; the default of every parameter is one of its values
GRIDS: Mapping[str, Mapping[str, GridParam]] = {
    "robust": {
        "tau_acc_s": GridParam(
            (2.0, 3.0, 4.5), "inclination time constant, set by hand against BROAD's errors"
        ),
        "tau_mag_s": GridParam(
            (10.0, 20.0, 40.0), "heading time constant, set by hand against BROAD's errors"
        ),
        "mag_new_reference_s": GridParam(
            (10.0, 20.0, 40.0), "when a new steady field is trusted: fitted to the magnet trials"
        ),
    },
    "gradient": {
        "beta": GridParam(
            (0.0125, 0.018, 0.025, 0.035, 0.05),
            "Madgwick's step: the best single value on BROAD (DEFAULT_BETA)",
        ),
        "mag_norm_tol": GridParam(
            (0.15, 0.25, 0.4), "the screening's field-norm gate, most of its gain on BROAD"
        ),
    },
    "bachmann": {
        "gain": GridParam((0.03, 0.06, 0.12), "drift-correction gain k, tuned on BROAD"),
        "mag_weight": GridParam((0.5, 0.7, 1.0), "magnetic weight rho, tuned on BROAD"),
        "mag_norm_tol": GridParam(
            (0.15, 0.25, 0.4), "the screening's field-norm gate, most of its gain on BROAD"
        ),
    },
    "ekf": {
        "quat_noise_per_sqrt_hz": GridParam(
            (0.0375, 0.075, 0.15), "Gauss-Newton measurement noise, tuned on BROAD"
        ),
        "tau_s": GridParam((0.15, 0.3, 0.6), "rate-model time constant, confirmed on BROAD"),
        "mag_norm_tol": GridParam(
            (0.15, 0.25, 0.4), "the screening's field-norm gate, most of its gain on BROAD"
        ),
        "mag_disturbance_s": GridParam(
            (0.3, 1.0, 3.0), "correlation time of field disturbances in the quaternion's noise"
        ),
    },
    "bias-kf": {
        "acc_motion_fraction": GridParam(
            (0.01, 0.02, 0.04), "body acceleration as noise: coordinate search on BROAD"
        ),
        "tilt_gate": GridParam((10.0, 20.0, 40.0), "soft tilt gate: coordinate search on BROAD"),
        "mag_dip_correlation_s": GridParam(
            (0.25, 0.5, 1.0), "field noise from the dip: coordinate search on BROAD"
        ),
    },
}


def has_grid(method: str) -> bool:
    """True if ``method`` has a declared grid."""
    return method in GRIDS


def declared_grid(method: str) -> dict[str, list[float | int | str]]:
    """The declared grid of ``method`` as ``{parameter: [values]}`` (for :func:`tune`).

    Raises ``ValueError`` naming the methods that have one when ``method`` has none.
    """
    if method not in GRIDS:
        raise ValueError(
            f"method {method!r} has no declared tuning grid; give one with -g name=v1,v2,... "
            f"(declared: {', '.join(sorted(GRIDS))})"
        )
    return {name: list(p.values) for name, p in GRIDS[method].items()}
