"""002's low-pass tracking (Figs. 4-6) and 001's hand rotations (Figs. 9-10), simulated."""

from __future__ import annotations

import numpy as np

from margtrack.bench.experiments.tilt_table import (
    EXPERIMENTS,
    tilt_table_recording,
)


def test_tilt_table_shakes_the_accelerometer_only_while_it_turns():
    # while moving: gravity, the lever arm's acceleration and the motor's 2 m/s² vibration
    # per axis; still: gravity and sensor noise only
    rec, moving = tilt_table_recording(cycles=1)
    rough = np.linalg.norm(np.diff(rec.acc, axis=0), axis=1)
    inside = moving[1:] & moving[:-1]
    outside = ~moving[1:] & ~moving[:-1]
    assert np.median(rough[inside]) > 10 * np.median(rough[outside])
    assert abs(np.mean(np.linalg.norm(rec.acc[~moving], axis=1)) - 9.80665) < 0.2


def test_lowpass_makes_fqa_and_quest_track_during_the_turns(tmp_path):
    result = EXPERIMENTS["lowpass-tracking"](tmp_path, True)
    f = result.figures
    for name in ("fqa", "quest"):
        raw = f[f"{name} raw moving_rms_deg"]
        filtered = f[f"{name} acc+mag 5 Hz moving_rms_deg"]
        assert raw > 10.0  # 002 Fig. 4: no tracking during the motion from raw data
        assert filtered < raw / 3.0  # Fig. 6: tracking once low-passed
        # filtering the field too keeps the vectors in step: better than the acc alone
        assert filtered < f[f"{name} acc 5 Hz moving_rms_deg"]
        # at rest the prefilter changes little
        assert abs(f[f"{name} acc+mag 5 Hz still_rms_deg"] - f[f"{name} raw still_rms_deg"]) < 1
    assert result.plots[0].is_file()


def test_ekf_follows_the_hand_rotations_about_x_y_z(tmp_path):
    f = EXPERIMENTS["ekf-hand-rotations"](tmp_path, True).figures
    holds = [k for k in f if k.endswith("error_deg")]
    assert len(holds) == 4
    assert max(f[k] for k in holds) < 4.0
    # each turn shows on its own axis at its 90 deg/s, the rates are near zero at rest
    np.testing.assert_allclose(f["turning peak_rate_deg_s"], 90.0, atol=5.0)
    assert f["still max_rate_deg_s"] < 1.0
    assert f["hold 3 true_quat"] == [0.0, 0.707, 0.0, 0.707]
