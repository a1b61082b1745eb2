"""Relative orientation across a joint from two gyroscopes and accelerometers, no magnetometer.

Two sensors on two rigid segments joined at a point see the same joint-centre acceleration;
through their lever arms that ties their orientations together, so the relative orientation
(heading included) stays drift-free where two independent 6-D filters let the relative
heading drift (Weygers & Kok 2020; lever arms after Seel, Schauer & Raisch 2012).

- :func:`relative_orientation`: the estimate, online (a multiplicative EKF over both
  orientations) or offline (the MAP of the whole recording), as a :class:`JointEstimate`;
- :func:`estimate_lever_arms` / :class:`LeverArms`: the lever arms from the data, with
  their standard deviations;
- :class:`JointParams`: the noise model and input policy, declared once per field;
- :func:`read_dualimu`: one trial of the dual-IMU dataset as two Recordings and its
  optical reference.

See docs/joint.md for the model, the command ``margtrack joint`` and the benchmark.
"""

from __future__ import annotations

from margtrack.lazy import lazy_names

_WHERE = {
    "DualImuTrial": "dualimu",
    "JointEstimate": "relative",
    "JointInputs": "pair",
    "JointParams": "params",
    "LeverArms": "lever_arms",
    "estimate_lever_arms": "lever_arms",
    "pair_inputs": "pair",
    "read_dualimu": "dualimu",
    "relative_orientation": "relative",
}

__all__ = sorted(_WHERE)

__getattr__, __dir__ = lazy_names(__name__, _WHERE)
