"""Other libraries' filters behind one adapter shape, for comparisons in the same run.

Each library is a function of a :class:`Recording` returning quaternions (N, 4)
``[w, x, y, z]`` of the body in ENU, wrapped as a :class:`~margtrack.bench.runner.Adapter`
so the one runner runs it like a margtrack method (``run(recording) -> Estimate``; calling
the adapter gives the bare quaternions). The libraries are optional (the ``dev`` extra)
and imported on first use:

- ``vqf``: VQF (Laidig & Seel 2023), C++ batch ``VQF.updateBatch``, default parameters;
  its 9-D output is ENU with margtrack's meaning (docs/conventions.md).
- ``vqf-offline``: VQF's offline (acausal) variant ``vqf.offlineVQF``, default parameters,
  the peer of ``smoother``; same output convention as ``vqf``.
- ``imufusion``: x-io's Fusion, per-sample C updates from Python, ENU convention,
  default gain; it takes deg/s and g.
- ``madgwick``: ``ahrs.filters.Madgwick`` (pure Python), MARG, output in NWU, rotated to
  ENU by ``q_z(+90 deg) ⊗ q``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from margtrack import quaternion as quat
from margtrack.bench.runner import Adapter
from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.recording import Recording

Array = NDArray[np.float64]

__all__ = ["EXTERNAL", "madgwick", "run_imufusion", "run_vqf", "run_vqf_offline"]

# NWU (x north, y west, z up) to ENU: a quarter turn about the vertical
_NWU_TO_ENU = np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])


def _arrays(rec: Recording) -> tuple[Array, Array, Array]:
    if rec.mag is None:
        raise ValueError(f"recording {rec.name!r} has no magnetometer; the comparison is 9-D")
    return (np.ascontiguousarray(x) for x in (rec.gyr, rec.acc, rec.mag))  # type: ignore[return-value]


def run_vqf(rec: Recording) -> Array:
    """VQF with default parameters (C++ batch), ENU."""
    from vqf import VQF

    gyr, acc, mag = _arrays(rec)
    return np.asarray(VQF(1.0 / rec.rate_hz).updateBatch(gyr, acc, mag)["quat9D"])


def run_vqf_offline(rec: Recording) -> Array:
    """VQF's offline variant (``vqf.offlineVQF``: acausal, the whole series at once) with
    default parameters, ENU."""
    from vqf import offlineVQF

    gyr, acc, mag = _arrays(rec)
    return np.asarray(offlineVQF(gyr, acc, mag, 1.0 / rec.rate_hz)["quat9D"])


def run_imufusion(rec: Recording) -> Array:
    """imufusion's AHRS with default gain, ENU convention (a Python loop over C updates)."""
    import imufusion

    gyr, acc, mag = _arrays(rec)
    ahrs = imufusion.Ahrs()
    # set as attributes: imufusion 1.3.3's AhrsSettings(convention=...) keyword is ignored
    settings = imufusion.AhrsSettings()
    settings.sample_rate = rec.rate_hz
    settings.convention = imufusion.CONVENTION_ENU
    ahrs.set_settings(settings)
    gyr_deg_s = np.degrees(gyr)
    acc_g = acc / STANDARD_GRAVITY_M_S2
    out = np.empty((rec.n_samples, 4))
    dt = np.diff(rec.t, prepend=rec.t[0] - 1.0 / rec.rate_hz)
    for i in range(rec.n_samples):
        ahrs.set_sample_period(float(dt[i]))
        ahrs.update(gyr_deg_s[i], acc_g[i], mag[i])
        out[i] = ahrs.get_quaternion()
    return out


def madgwick(beta: float) -> Adapter:
    """``ahrs.filters.Madgwick`` with gain ``beta`` (MARG), converted from NWU to ENU."""

    def run(rec: Recording) -> Array:
        from ahrs.filters import Madgwick

        gyr, acc, mag = _arrays(rec)
        q = Madgwick(gyr=gyr, acc=acc, mag=mag, frequency=rec.rate_hz, gain=beta).Q
        return quat.multiply(_NWU_TO_ENU, q)

    return Adapter(run, f"ahrs madgwick (beta {beta:g})", {"beta": beta})


#: Adapters by name (``madgwick`` takes its gain: :func:`madgwick`).
EXTERNAL: dict[str, Adapter] = {
    "vqf": Adapter(run_vqf, "vqf"),
    "vqf-offline": Adapter(run_vqf_offline, "vqf-offline"),
    "imufusion": Adapter(run_imufusion, "imufusion"),
}
