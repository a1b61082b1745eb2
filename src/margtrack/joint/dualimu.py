"""One trial of the dual-IMU dataset (Weygers & Kok 2020) as two margtrack Recordings.

The dataset (``../shared/data/dualimu``, see its README) holds MATLAB files with both
sensors' accelerometers and gyroscopes at 50 Hz (``sensorData``), each sensor's optical
reference orientation (``ref``) and the measured lever arms (``r_12``, ``r_21``: sensor to
joint centre, so their negatives are margtrack's joint centre to sensor).

The dataset's own reference code scores ``conj(q₁) ⊗ q₂`` against the reference relative
orientation one sample earlier (the estimate at sample ``k + 1`` against the reference at
``k``), with no alignment between the optical and the sensor frames; :func:`score` does the
same. :func:`score_aligned` also fits the two constant optical-to-sensor rotations by least
squares first (a check of how much of an error is alignment).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack import quaternion as qt
from margtrack.recording import Recording

Array = NDArray[np.float64]

__all__ = ["DualImuTrial", "read_dualimu", "relative_error_deg", "score", "score_aligned"]


@dataclass(frozen=True)
class DualImuTrial:
    """One trial: the two sensors, their reference and the measured lever arms.

    parent, child : sensor 1 and sensor 2 (t from 0 at ``rate``; gyr rad/s, acc m/s²).
    ref_parent, ref_child : (N, 4) optical reference orientations ``[w, x, y, z]``.
    lever_arms_m : (2, 3) m, joint centre to each sensor (``-r_12``, ``-r_21``), measured.
    name : the file's stem (``data_2D_03``).
    """

    parent: Recording
    child: Recording
    ref_parent: Array
    ref_child: Array
    lever_arms_m: Array
    name: str

    @property
    def reference(self) -> Array:
        """(N, 4) reference relative orientation ``conj(ref_parent) ⊗ ref_child``."""
        return qt.multiply(qt.conjugate(self.ref_parent), self.ref_child)


def read_dualimu(path: str | Path) -> DualImuTrial:
    """Read one ``data_*.mat`` trial of the dual-IMU dataset (module docstring)."""
    from scipy.io import loadmat

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such file: {p}")
    data = loadmat(p, squeeze_me=True, struct_as_record=False)["data"]
    rate = float(data.rate)
    s = np.asarray(data.sensorData, dtype=np.float64)
    t = np.arange(s.shape[0]) / rate
    ref = np.asarray(data.ref, dtype=np.float64)
    parent = Recording(t=t, gyr=s[:, 3:6], acc=s[:, 0:3], name=f"{p.stem}:1",
                       meta={"source": str(p)})
    child = Recording(t=t, gyr=s[:, 9:12], acc=s[:, 6:9], name=f"{p.stem}:2",
                      meta={"source": str(p)})
    arms = -np.stack([np.ravel(data.r_12), np.ravel(data.r_21)]).astype(np.float64)
    return DualImuTrial(parent, child, qt.normalize(ref[:, 0:4]), qt.normalize(ref[:, 4:8]),
                        arms, p.stem)


def relative_error_deg(quat: ArrayLike, reference: ArrayLike, shift: int = 1) -> Array:
    """Angle (deg) between ``quat[k + shift]`` and ``reference[k]`` for every ``k``."""
    q = np.asarray(quat, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    n = min(r.shape[0], q.shape[0] - shift)
    e = qt.multiply(qt.conjugate(r[:n]), q[shift:shift + n])
    return np.degrees(2.0 * np.arccos(np.clip(np.abs(e[:, 0]), 0.0, 1.0)))


def score(quat: ArrayLike, trial: DualImuTrial, shift: int = 1) -> float:
    """RMSE (deg) of a relative orientation against the trial's reference (module docstring)."""
    return float(np.sqrt(np.mean(relative_error_deg(quat, trial.reference, shift) ** 2)))


def score_aligned(quat: ArrayLike, trial: DualImuTrial, shift: int = 1) -> float:
    """RMSE (deg) after fitting constant rotations ``A``, ``B`` with
    ``reference ≈ A ⊗ quat ⊗ B`` (the optical-to-sensor misalignments) by least squares.
    """
    from scipy.optimize import least_squares

    q = np.asarray(quat, dtype=np.float64)
    ref = trial.reference
    n = min(ref.shape[0], q.shape[0] - shift)
    est, r = q[shift:shift + n], ref[:n]

    def residual(x: Array) -> Array:
        a, b = qt.from_rotvec(x[:3]), qt.from_rotvec(x[3:])
        fit = qt.multiply(qt.multiply(a, est), b)
        return qt.to_rotvec(qt.multiply(qt.conjugate(r), fit)).ravel()

    sol = least_squares(residual, np.zeros(6), loss="soft_l1", f_scale=0.1)
    a, b = qt.from_rotvec(sol.x[:3]), qt.from_rotvec(sol.x[3:])
    fit = qt.multiply(qt.multiply(a, q), b)
    return score(fit, trial, shift)
