"""The robust filter's online hard-iron estimate as a calibration file.

``robust`` estimates the offset of a magnet carried by the sensor while it runs (output
``mag_offset_ut``, body axes, nan until a fit is accepted; ``methods/robust/hard_iron.py``).
Written in the calibration file's model ``y = K x + b`` with ``K = I`` and ``b`` the
offset, ``margtrack run --calibration FILE`` removes it from another recording of the same
sensor and magnet from its first sample, before any fit would have been accepted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.calibration.calibration_file import Calibration, TriadCalibration
from margtrack.io.safe_output import atomic_output, check_output

Array = NDArray[np.float64]

__all__ = ["hard_iron_calibration", "last_offset_ut", "save_hard_iron"]

METHOD = "online sphere fit (robust's hard-iron estimate)"


def last_offset_ut(estimate: Any, sensor: int = 0) -> Array:
    """The last accepted offset (3,), µT, of an estimate with ``mag_offset_ut`` (robust's).

    ``sensor`` picks one of a many-sensor estimate. Raises ``ValueError`` when the
    estimate has no such output (another method) or none was ever accepted (too little
    rotation seen, or no field), naming the fix.
    """
    outputs = getattr(estimate, "outputs", {})
    if "mag_offset_ut" not in outputs:
        raise ValueError(
            "the estimate has no 'mag_offset_ut' output: run the recording with "
            "--method robust (hard_iron_tau_s > 0) to estimate the magnet's offset"
        )
    offsets = np.asarray(outputs["mag_offset_ut"], dtype=np.float64)
    if offsets.ndim == 3:
        offsets = offsets[sensor]
    accepted = np.flatnonzero(np.isfinite(offsets).all(axis=1))
    if accepted.size == 0:
        raise ValueError(
            "no hard-iron fit was accepted in this recording: turn the sensor about every "
            "axis (some ±10° at least) for a few seconds in an undisturbed field, or "
            "calibrate the magnetometer offline (margtrack calibrate)"
        )
    return offsets[accepted[-1]].copy()


def hard_iron_calibration(offset_ut: ArrayLike, source: str = "") -> Calibration:
    """A calibration whose magnetometer model is the offset alone (``K = I``, ``b`` =
    ``offset_ut`` (3,), µT); gyroscope and accelerometer uncorrected. Offsets beyond the
    file's plausible range (2000 µT per axis) raise ``ValueError``."""
    mag = TriadCalibration("mag", bias=tuple(np.asarray(offset_ut, dtype=np.float64)),
                           unit="uT", method=METHOD)
    return Calibration(mag=mag, source=source or METHOD,
                       notes=("hard-iron offset only: soft iron and scale not estimated",))


def save_hard_iron(estimate_or_offset: Any, path: str | Path, *, sensor: int = 0,
                   force: bool = False, source: str = "") -> Path:
    """Write the offset (an estimate's last accepted one, or a (3,) µT array) as a
    calibration file at ``path``, atomically; an existing file only with ``force``."""
    if hasattr(estimate_or_offset, "outputs"):
        offset = last_offset_ut(estimate_or_offset, sensor)
    else:
        offset = np.asarray(estimate_or_offset, dtype=np.float64)
    calibration = hard_iron_calibration(offset, source)
    out = Path(path)
    check_output(out, force=force)
    with atomic_output(out) as tmp:
        tmp.write_text(calibration.to_json(), encoding="utf-8")
    return out
