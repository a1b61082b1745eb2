"""Lever arms of two sensors across a joint, and the joint-centre acceleration they give.

Two rigid segments joined at a point: the joint centre. A sensor at ``r`` from the centre
(m, in the sensor's frame) measures the specific force ``a`` of its own position; the
specific force at the centre, in the same frame, is (Seel, Schauer, Raisch 2012)

    c = a - ω × (ω × r) - ω̇ × r = a - K r,    K = [ω]×² + [ω̇]×

with ω the gyroscope's rate and ω̇ its time derivative (both computed in
:func:`margtrack.joint.kernel.centre_forces`). Both sensors see the same centre,
so ``|c₁| = |c₂|`` at every sample whatever the two orientations are: the lever arms are
the least-squares solution of ``|a₁ - K₁ r₁| - |a₂ - K₂ r₂| = 0`` over the recording
(:func:`estimate_lever_arms`, scipy's Levenberg-Marquardt with the analytic Jacobian).

Sign: ``r`` points from the joint centre to the sensor. The dual-IMU dataset's ``r_12`` and
``r_21`` point the other way (sensor to centre); its reference code negates them too.

For a hinge (one degree of freedom) every point of the axis is a centre: the lever arms
along the axis are not determined by the data and their std says so; a weak prior (a 1 m
lever arm weighs as much as one sample's 0.1 m/s² residual) keeps them near the sensors,
and the relative orientation does not depend on which point of the axis is taken.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["LeverArms", "estimate_lever_arms", "read_lever_arms"]

#: residual (m/s²) that a 1 m lever arm costs: the weak prior that pins a hinge's axis
_PRIOR_M_S2_PER_M = 0.1
#: samples the fit uses at most (evenly spread): the lever arms need seconds, not hours
_MAX_FIT_SAMPLES = 20_000


@dataclass(frozen=True)
class LeverArms:
    """The two lever arms and how well the data determine them.

    r_m : (2, 3) m, joint centre to sensor, in each sensor's frame: row 0 the parent's,
        row 1 the child's.
    std_m : (2, 3) m, one standard deviation of each component (from the Jacobian at the
        solution, residuals' autocorrelation accounted for); NaN when the lever arms were
        given rather than estimated.
    source : ``"estimated"`` or ``"given"``.
    residual_m_s2 : rms of ``|c₁| - |c₂|`` at the solution over the samples used, m/s².
    samples : how many samples the fit used (0 when given).
    """

    r_m: Array
    std_m: Array
    source: str
    residual_m_s2: float = float("nan")
    samples: int = 0

    @classmethod
    def given(cls, r_m: object) -> LeverArms:
        """Lever arms known beforehand: ``r_m`` (2, 3) m, parent's row then child's."""
        r = np.array(r_m, dtype=np.float64)
        if r.shape != (2, 3):
            raise ValueError(f"lever arms must have shape (2, 3) (parent's, child's; m), "
                             f"got {r.shape}")
        if not np.all(np.isfinite(r)):
            raise ValueError(f"lever arms must be finite, got {r.tolist()}")
        return cls(r, np.full((2, 3), np.nan), "given")


def _k_matrices(gyr: Array, gyr_dot: Array) -> Array:
    """K = [ω]×² + [ω̇]× per sample, (N, 3, 3)."""
    wx, wy, wz = gyr[:, 0], gyr[:, 1], gyr[:, 2]
    ax, ay, az = gyr_dot[:, 0], gyr_dot[:, 1], gyr_dot[:, 2]
    k = np.empty((gyr.shape[0], 3, 3))
    # [ω]×² = ω ωᵀ - |ω|² I
    k[:, 0, 0] = -(wy * wy + wz * wz)
    k[:, 1, 1] = -(wx * wx + wz * wz)
    k[:, 2, 2] = -(wx * wx + wy * wy)
    k[:, 0, 1] = wx * wy - az
    k[:, 1, 0] = wx * wy + az
    k[:, 0, 2] = wx * wz + ay
    k[:, 2, 0] = wx * wz - ay
    k[:, 1, 2] = wy * wz - ax
    k[:, 2, 1] = wy * wz + ax
    return k


def estimate_lever_arms(
    t: Array, gyr: Array, acc: Array, usable: NDArray[np.bool_] | None = None
) -> LeverArms:
    """Both lever arms from the data (module docstring), with their standard deviations.

    Parameters
    ----------
    t : (N,) s, the common timestamps of both sensors.
    gyr, acc : (2, N, 3) rad/s and m/s², parent's then child's, each in its own frame.
    usable : (N,) bool, samples the fit may use (both sensors valid); default all.

    Returns
    -------
    :class:`LeverArms` with ``source="estimated"``.

    Raises
    ------
    ValueError : fewer than 50 usable samples, or too little rotation to see the lever
        arms (both sensors nearly still): the message says to record some motion or give
        the lever arms.
    """
    from scipy.optimize import least_squares

    from margtrack.joint.kernel import rate_derivative

    gyr_dot = np.stack([rate_derivative(t, np.ascontiguousarray(gyr[s])) for s in range(2)])
    mask = np.ones(t.shape[0], dtype=bool) if usable is None else np.asarray(usable, bool)
    idx = np.flatnonzero(mask)
    if idx.size < 50:
        raise ValueError(f"only {idx.size} usable samples to estimate the lever arms from "
                         "(at least 50 needed); give them instead (lever_arms=, --lever-arms)")
    if idx.size > _MAX_FIT_SAMPLES:
        idx = idx[np.linspace(0, idx.size - 1, _MAX_FIT_SAMPLES).astype(np.intp)]
    k = [_k_matrices(gyr[s, idx], gyr_dot[s, idx]) for s in range(2)]
    a = [acc[s, idx] for s in range(2)]
    motion = max(float(np.sqrt(np.mean(np.sum(k[s] ** 2, axis=(1, 2))))) for s in range(2))
    if motion < 0.5:  # rms |K| in 1/s²: below it 10 cm of lever arm is 0.05 m/s²
        raise ValueError(
            f"the sensors hardly rotate (rms |ω|² + |ω̇| about {motion:.2g} 1/s²): the lever "
            "arms cannot be estimated from this recording; record some brisk motion of "
            "both segments or give the lever arms (lever_arms=, --lever-arms)")
    prior = _PRIOR_M_S2_PER_M

    def parts(x: Array) -> tuple[list[Array], list[Array]]:
        e = [a[s] - np.einsum("nij,j->ni", k[s], x[3 * s:3 * s + 3]) for s in range(2)]
        return e, [np.linalg.norm(v, axis=1) for v in e]

    def fun(x: Array) -> Array:
        _, n = parts(x)
        return np.concatenate([n[0] - n[1], prior * x])

    def jac(x: Array) -> Array:
        e, n = parts(x)
        rows = np.empty((idx.size, 6))
        for s, sign in ((0, -1.0), (1, 1.0)):
            unit = e[s] / np.maximum(n[s], 1e-9)[:, None]
            rows[:, 3 * s:3 * s + 3] = sign * np.einsum("nij,ni->nj", k[s], unit)
        return np.vstack([rows, prior * np.eye(6)])

    sol = least_squares(fun, np.zeros(6), jac=jac, method="lm", xtol=1e-12, ftol=1e-12)
    res = sol.fun[:idx.size]
    dof = max(idx.size - 6, 1)
    var = float(res @ res) / dof
    # neighbouring residuals are correlated (smooth motion): inflate the variance by the
    # AR(1) factor (1 + ρ) / (1 - ρ) of the residuals' lag-1 correlation ρ
    rho = 0.0
    if res.size > 2 and np.std(res) > 0:
        rho = float(np.clip(np.corrcoef(res[:-1], res[1:])[0, 1], 0.0, 0.98))
    jj = sol.jac.T @ sol.jac
    cov = var * (1.0 + rho) / (1.0 - rho) * np.linalg.pinv(jj)
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None)).reshape(2, 3)
    return LeverArms(sol.x.reshape(2, 3), std, "estimated",
                     float(np.sqrt(np.mean(res**2))), int(idx.size))


def read_lever_arms(path: str | Path) -> LeverArms:
    """Lever arms from a file: JSON ``{"parent_m": [x, y, z], "child_m": [x, y, z]}`` (m,
    joint centre to sensor, each sensor's frame), or an estimate file of ``margtrack joint``
    (.h5/.hdf5/.csv), whose ``params`` state the lever arms it used (``lever_arms_m``).
    """
    import json

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such lever-arms file: {p}")
    if p.suffix.lower() == ".json":
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
            rows = [data["parent_m"], data["child_m"]]
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(
                f"{p}: expected JSON like {{\"parent_m\": [0.0, 0.1, 0.0], \"child_m\": "
                f"[0.0, -0.12, 0.0]}} (m, joint centre to sensor, sensor frames): {exc}"
            ) from None
        return LeverArms.given(rows)
    from margtrack.io import read_estimate

    params = read_estimate(p).params or {}
    if "lever_arms_m" not in params:
        raise ValueError(f"{p} states no lever_arms_m (not written by margtrack joint); give "
                         "a JSON file {\"parent_m\": [...], \"child_m\": [...]}")
    return LeverArms.given(params["lever_arms_m"])
