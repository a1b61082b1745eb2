"""Relative orientation across a joint: :func:`relative_orientation` and its result.

The online estimate is the filter of :mod:`.kernel` run once forward; the offline one refines
a forward-then-backward filter pass into the MAP of the whole recording (:mod:`.offline`).
Both need the lever arms (:mod:`.lever_arms`): given, or estimated from the same data.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as qt
from margtrack.estimator.flags import Flag
from margtrack.joint.lever_arms import LeverArms, estimate_lever_arms
from margtrack.joint.pair import JointInputs, pair_inputs
from margtrack.joint.params import JointParams
from margtrack.recording import Recording

Array = NDArray[np.float64]

__all__ = ["JointEstimate", "relative_orientation"]


@dataclass(frozen=True)
class JointEstimate:
    """The orientation of the child sensor relative to the parent sensor, per sample.

    Attributes
    ----------
    t : (N,) s, the common time base of the two sensors.
    quat : (N, 4) ``[w, x, y, z]``, ``conj(q_parent) ⊗ q_child``: the child's frame in the
        parent's frame (``v_parent = quat ⊗ v_child ⊗ quat*``). It does not depend on an
        earth frame.
    quat_parent, quat_child : (N, 4) each sensor's orientation in a common ENU earth frame
        whose heading is arbitrary (no magnetometer): only their inclinations and their
        relative heading are estimated.
    lever_arms : the lever arms used (:class:`~margtrack.joint.lever_arms.LeverArms`).
    flags : (N,) uint16 bits of :class:`~margtrack.estimator.flags.Flag` (either sensor):
        ``INVALID``, ``GAP``, ``GYR_CLIPPED``, ``ACC_IGNORED``, and ``INITIALISING`` before
        the online filter's first usable sample.
    method : ``"joint_online"`` or ``"joint_offline"``.
    params : the parameters used (:class:`~margtrack.joint.params.JointParams`).
    notes : what was done to the inputs (cropping, resampling), and the offline solver's
        iterations.
    """

    t: Array
    quat: Array
    quat_parent: Array
    quat_child: Array
    lever_arms: LeverArms
    flags: NDArray[np.uint16]
    method: str
    params: JointParams
    notes: tuple[str, ...] = ()
    frame: None = field(default=None, init=False)

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.shape[0])

    @property
    def outputs(self) -> Mapping[str, Array]:
        """Per-sample series an estimate file holds besides ``t``, ``quat`` and ``flags``."""
        return {}

    def file_params(self) -> dict[str, Any]:
        """What an estimate file states about the run: parameters and lever arms."""
        arms = self.lever_arms
        return {
            **self.params.as_dict(),
            "lever_arms_m": np.round(arms.r_m, 6).tolist(),
            "lever_arms_std_m": [[None if np.isnan(v) else round(float(v), 6) for v in row]
                                 for row in arms.std_m],
            "lever_arms_source": arms.source,
            "lever_arms_frame": "joint centre to sensor, each sensor's frame; "
                                "row 0 parent, row 1 child",
        }

    def write(self, path: str | Path) -> None:
        """Write ``t``, ``quat`` and ``flags`` with the parameters and lever arms (attribute
        or comment line ``params``) in ``margtrack run``'s estimate format (.h5/.hdf5 or
        .csv by the extension), atomically (:func:`margtrack.io.write_estimate`); an
        existing file is replaced: check first with
        :func:`margtrack.io.safe_output.check_output`.
        """
        from margtrack import io

        view = SimpleNamespace(t=self.t, quat=self.quat, outputs=self.outputs,
                               flags=self.flags, method=self.method, frame=None,
                               params=self.file_params())
        io.write_estimate(view, path)


@functools.cache
def _default_params() -> JointParams:
    return JointParams()


def _coefficients(p: JointParams) -> Array:
    from margtrack.joint import kernel

    coeffs = np.empty(kernel.N_COEFFS)
    coeffs[kernel.C_GYR_VAR] = p.gyr_noise_rad_s_sqrt_hz**2
    coeffs[kernel.C_LINK_VAR] = p.link_noise_m_s2**2
    coeffs[kernel.C_INCL_VAR] = p.incl_noise_m_s2**2
    coeffs[kernel.C_INCL_GAIN] = p.incl_norm_gain
    coeffs[kernel.C_GRAVITY] = p.gravity_m_s2
    coeffs[kernel.C_P0_INCL] = np.radians(p.init_incl_std_deg) ** 2
    coeffs[kernel.C_P0_HEADING] = np.radians(p.init_heading_std_deg) ** 2
    coeffs[kernel.C_GYR_PREV] = 0.5 if p.gyr_timing == "instant" else 0.0
    return coeffs


def _lever_arms(given: ArrayLike | LeverArms | None, inputs: JointInputs) -> LeverArms:
    if isinstance(given, LeverArms):
        return given
    if given is not None:
        return LeverArms.given(given)
    return estimate_lever_arms(inputs.t, inputs.gyr, inputs.acc, inputs.meas_ok)


def _run_filter(
    inputs: JointInputs, c: Array, coeffs: Array, offline: bool
) -> tuple[Array, Array, int]:
    """The online estimate ``(q, rel, first)``, or the backward pass that starts the
    offline one."""
    from margtrack.joint.kernel import filter_pass

    g, ok, restart = inputs.gyr, inputs.meas_ok, inputs.restart
    q, rel, p_end, first = filter_pass(inputs.t, g, c, ok, restart,
                                       np.tile([1.0, 0, 0, 0], (2, 1)), np.zeros((5, 5)),
                                       False, coeffs)
    if first >= inputs.n_samples:
        raise ValueError("no sample has both accelerometers usable (every one is flagged); "
                         "nothing to estimate the orientations from")
    if not offline:
        return q, rel, first
    back_restart = np.zeros_like(restart)
    back_restart[1:] = restart[::-1][:-1]
    qb, relb, _, _ = filter_pass(-inputs.t[::-1], np.ascontiguousarray(-g[:, ::-1]),
                                 np.ascontiguousarray(c[:, ::-1]), ok[::-1], back_restart,
                                 np.ascontiguousarray(q[:, -1]), p_end, True, coeffs)
    return np.ascontiguousarray(qb[:, ::-1]), relb[::-1], 0


def relative_orientation(
    parent: Recording,
    child: Recording,
    *,
    offline: bool = False,
    lever_arms: ArrayLike | LeverArms | None = None,
    params: JointParams | Mapping[str, Any] | None = None,
    rate_hz: float | None = None,
    align_start: bool = False,
) -> JointEstimate:
    """Orientation of the child sensor relative to the parent across a joint, no magnetometer.

    Parameters
    ----------
    parent, child : the two sensors' recordings (:class:`~margtrack.recording.Recording`, SI
        units: rad/s, m/s²); a magnetometer is ignored. Different timestamps are brought onto
        one time base (:mod:`margtrack.joint.pair`).
    offline : False: the online filter (each output uses the samples up to two after it);
        True: the MAP over the whole recording (each output uses every sample).
    lever_arms : (2, 3) m, joint centre to the parent's sensor (row 0) and to the child's
        (row 1), each in its sensor's frame; None (default): estimated from the recording
        (:func:`~margtrack.joint.lever_arms.estimate_lever_arms`).
    params : :class:`~margtrack.joint.params.JointParams` or a dict of its fields.
    rate_hz : the common rate when the timestamps differ, Hz (default: the slower sensor's).
    align_start : re-time both recordings from their first sample.

    Returns
    -------
    :class:`JointEstimate` (``quat = conj(q_parent) ⊗ q_child``).

    Raises
    ------
    ValueError : bad parameters, units that look like deg/s or g, recordings without a
        common time span, too little motion to estimate the lever arms (give them), or no
        usable sample; each message says what to fix.
    """
    from margtrack.joint.kernel import centre_forces
    from margtrack.joint.offline import map_refine

    p = params if isinstance(params, JointParams) else (
        JointParams(**dict(params)) if params else _default_params())
    inputs = pair_inputs(parent, child, max_gap_s=p.max_gap_s,
                         gyr_range_deg_s=p.gyr_range_deg_s, acc_range_g=p.acc_range_g,
                         rate_hz=rate_hz, align_start=align_start)
    arms = _lever_arms(lever_arms, inputs)
    c = centre_forces(inputs.t, inputs.gyr, inputs.acc, arms.r_m)
    coeffs = _coefficients(p)
    q, rel, first = _run_filter(inputs, c, coeffs, offline)
    notes = list(inputs.notes)
    flags = inputs.flags.copy()
    if offline:
        q, iterations, last = map_refine(inputs.t, inputs.gyr, c, inputs.meas_ok,
                                         inputs.restart, q, coeffs, p.max_iterations,
                                         p.tolerance_rad)
        rel = qt.multiply(qt.conjugate(q[0]), q[1])
        if last >= p.tolerance_rad:
            notes.append(f"offline solver stopped after {iterations} iterations (largest last "
                         f"update {last:.2g} rad, tolerance {p.tolerance_rad:g}); raise "
                         "max_iterations for a tighter fit")
    else:
        flags[:first] |= np.uint16(Flag.INITIALISING)
    return JointEstimate(inputs.t, rel, q[0], q[1], arms, flags,
                         "joint_offline" if offline else "joint_online", p, tuple(notes))
