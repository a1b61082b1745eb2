"""robust's online hard-iron estimate written as a calibration file and reused."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from margtrack import sim
from margtrack.accuracy import error_series
from margtrack.calibration import (
    hard_iron_calibration,
    last_offset_ut,
    load_calibration,
    save_hard_iron,
)
from margtrack.io import read_estimate, write_hdf5
from margtrack.methods.robust import Robust
from margtrack.run.chunked import run_file

MAGNET = sim.attached_dipole(0.07, 0.1)  # 7 cm: 58 µT on the body x axis


def _recording(seed):
    motion = sim.random_motion(30.0, 100.0, seed, max_rate_deg_s=200.0, bandwidth_hz=2.0)
    return sim.simulate(motion, frame="ENU", mag_errors=sim.SensorErrors(noise_density=0.05),
                        mag_disturbances=[MAGNET], seed=seed, name=f"magnet-{seed}")


def _heading_rmse_deg(quat, frame, rec):
    err = error_series(quat, rec.quat_true, frame, rec.frame).heading_rad
    return math.degrees(float(np.sqrt(np.mean(err**2))))


def test_the_estimate_round_trips_through_the_file_and_corrects_another_recording(tmp_path):
    est = Robust(frame="ENU").run(_recording(0))
    offset = last_offset_ut(est)
    assert np.abs(offset - MAGNET.offset_ut).max() < 2.0
    path = save_hard_iron(est, tmp_path / "magnet.json")
    cal = load_calibration(path)
    np.testing.assert_array_equal(cal.mag.b, offset)
    np.testing.assert_array_equal(cal.mag.K, np.eye(3))
    # an existing file is kept unless forced
    with pytest.raises(FileExistsError):
        save_hard_iron(offset, path)
    assert save_hard_iron(offset, path, force=True) == path
    # another recording of the same sensor and magnet, through `margtrack run`'s path:
    # corrected from its first sample, where the online fit needs seconds of rotation
    rec = _recording(1)
    write_hdf5(rec, tmp_path / "rec.h5")
    run_file(tmp_path / "rec.h5", tmp_path / "with.h5", "robust", calibration=path,
             frame="ENU")
    run_file(tmp_path / "rec.h5", tmp_path / "without.h5", "robust", frame="ENU")
    with_cal, without = read_estimate(tmp_path / "with.h5"), read_estimate(tmp_path / "without.h5")
    assert _heading_rmse_deg(with_cal.quat, "ENU", rec) < 1.0
    assert _heading_rmse_deg(without.quat, "ENU", rec) > 5.0


def test_no_accepted_fit_or_another_method_says_what_to_do():
    rec = _recording(0)
    est = Robust(frame="ENU", hard_iron_tau_s=0.0).run(rec)  # never fits
    with pytest.raises(ValueError, match="no hard-iron fit was accepted"):
        last_offset_ut(est)

    other = SimpleNamespace(outputs={"quat6d": np.zeros((3, 4))})
    with pytest.raises(ValueError, match="--method robust"):
        last_offset_ut(other)
    # an offset no sensor has (a unit mix-up) is refused by the file's own check
    with pytest.raises(ValueError, match="exceeds"):
        hard_iron_calibration([2500.0, 0.0, 0.0])
