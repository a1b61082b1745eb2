"""BROAD reader: real trial facts (size, rate, convention, truth gaps) and synthetic edge cases."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from margtrack import quaternion as quat
from margtrack.io import BroadTrial, broad_trials, read_broad

TRIAL_01 = "01_undisturbed_slow_rotation_A"


@pytest.fixture(scope="module")
def broad_dir(broad_folder: Path) -> Path:
    return broad_folder


@pytest.fixture(scope="module")
def trial01(broad_dir: Path):
    return read_broad(broad_dir / f"{TRIAL_01}.hdf5")


@pytest.fixture(scope="module")
def raw01(broad_dir: Path) -> dict[str, np.ndarray]:
    with h5py.File(broad_dir / f"{TRIAL_01}.hdf5") as f:
        return {k: f[k][()] for k in ("opt_quat", "movement", "imu_gyr")}


def test_trial01_size_rate_and_labels(trial01) -> None:
    assert trial01.n_samples == 56940
    assert trial01.meta["sampling_rate"] == pytest.approx(285.714, abs=1e-3)
    assert trial01.rate_hz == pytest.approx(285.714, abs=1e-3)
    assert trial01.t[0] == 0.0
    assert trial01.t[-1] == pytest.approx(56939 / 285.7142857142857, rel=1e-12)
    assert (trial01.frame, trial01.name) == ("ENU", TRIAL_01)
    assert trial01.meta["source"].endswith(f"{TRIAL_01}.hdf5")
    assert "Berlin Robust Orientation Estimation" in trial01.meta["info"]
    assert trial01.mag is not None


def test_trial01_imu_is_read_unchanged(trial01, raw01) -> None:
    np.testing.assert_array_equal(trial01.gyr, raw01["imu_gyr"])


def test_trial01_truth_is_unit_and_movement_partial(trial01) -> None:
    norms = np.linalg.norm(trial01.quat_true, axis=1)
    np.testing.assert_allclose(norms, 1.0, rtol=0, atol=1e-12)
    fraction = trial01.movement.mean()
    assert 0.0 < fraction < 1.0
    assert fraction == pytest.approx(0.6297, abs=1e-3)


def test_trial01_truth_gaps_are_filled_and_masked(trial01, raw01) -> None:
    nan = np.isnan(raw01["opt_quat"]).any(axis=1)
    assert trial01.meta["truth_nan_samples"] == int(nan.sum()) == 162
    assert trial01.meta["truth_nan_movement_cleared"] == 152
    np.testing.assert_array_equal(trial01.movement, raw01["movement"] & ~nan)
    first = int(np.flatnonzero(nan)[0])
    assert first == 7749
    run_end = first + int(np.argmax(~nan[first:]))  # first valid sample after the gap
    q = raw01["opt_quat"]
    np.testing.assert_allclose(trial01.quat_true[first], q[first - 1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(trial01.quat_true[run_end - 1], q[run_end], rtol=0, atol=1e-15)
    valid = ~nan
    np.testing.assert_allclose(trial01.quat_true[valid], q[valid], rtol=0, atol=1e-15)


def test_gravity_at_rest_points_up_in_enu(trial01) -> None:
    """Convention check: q rotates body vectors to ENU, the accelerometer reads +g (up)."""
    rest = trial01.slice(0, 100)
    assert not rest.movement.any()
    up = quat.rotate(rest.quat_true, rest.acc)
    tilt_deg = np.degrees(np.arccos(up[:, 2] / np.linalg.norm(up, axis=1)))
    assert tilt_deg.max() < 3.0
    assert np.linalg.norm(rest.acc, axis=1).mean() == pytest.approx(9.81, abs=0.2)


def test_magnetic_field_dips_down_in_enu(trial01) -> None:
    """Second convention check: in Berlin the field points down by about 68 degrees."""
    rest = trial01.slice(0, 100)
    m = quat.rotate(rest.quat_true, rest.mag).mean(axis=0)
    dip_deg = np.degrees(np.arctan2(-m[2], np.hypot(m[0], m[1])))
    assert 60.0 < dip_deg < 80.0


def test_broad_trials_lists_shipped_trials(broad_dir: Path) -> None:
    trials = broad_trials(broad_dir)
    assert len(trials) == 16
    assert [t.name for t in trials] == sorted(t.name for t in trials)
    first = trials[0]
    assert first == BroadTrial(
        TRIAL_01, broad_dir / f"{TRIAL_01}.hdf5",
        "slow rotation movements without translation, no breaks",
        ("all_trials", "undisturbed", "rotation", "slow", "no_breaks"),
    )
    tapping = next(t for t in trials if t.name == "24_disturbed_tapping_A")
    assert "disturbed" in tapping.groups and "tapping" in tapping.groups
    assert sum("undisturbed" in t.groups for t in trials) == 9


# --- synthetic files ----------------------------------------------------------------------


def _broad_file(path: Path, quat_rows: np.ndarray, **replace: np.ndarray) -> Path:
    n = quat_rows.shape[0]
    data = {
        "imu_gyr": np.zeros((n, 3)), "imu_acc": np.tile([0.0, 0.0, 9.81], (n, 1)),
        "imu_mag": np.tile([0.0, 20.0, -40.0], (n, 1)), "opt_quat": quat_rows,
        "opt_pos": np.zeros((n, 3)), "movement": np.ones(n, dtype=bool), **replace,
    }
    with h5py.File(path, "w") as f:
        for key, value in data.items():
            f[key] = value
        f.attrs["sampling_rate"] = 100.0
        f.attrs["info"] = "synthetic"
    return path


def test_truth_gaps_take_nearest_valid_sample(tmp_path: Path) -> None:
    angles = np.arange(10) * 0.1
    q = quat.from_axis_angle([0.0, 0.0, 1.0], angles)
    nan = np.array([1, 1, 0, 0, 1, 1, 1, 0, 1, 1], dtype=bool)
    q[nan] = np.nan
    rec = read_broad(_broad_file(tmp_path / "gaps.hdf5", q))
    # nearest valid sample of each index; 5 is equally far from 3 and 7 and takes the earlier
    source = [2, 2, 2, 3, 3, 3, 7, 7, 7, 7]
    np.testing.assert_allclose(rec.quat_true, q[source], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(rec.movement, ~nan)
    assert rec.meta["truth_nan_samples"] == 7
    assert rec.meta["truth_nan_movement_cleared"] == 7
    np.testing.assert_array_equal(rec.t, np.arange(10) / 100.0)


def test_imu_nan_is_an_error_naming_sample(tmp_path: Path) -> None:
    q = np.tile([1.0, 0, 0, 0], (6, 1))
    gyr = np.zeros((6, 3))
    gyr[4, 0] = np.nan
    path = _broad_file(tmp_path / "bad.hdf5", q, imu_gyr=gyr)
    with pytest.raises(ValueError, match=r"bad\.hdf5: gyr has a non-finite value .* at sample 4"):
        read_broad(path)


def test_unusable_files_are_refused(tmp_path: Path) -> None:
    q = np.full((4, 4), np.nan)
    with pytest.raises(ValueError, match="opt_quat has no valid sample"):
        read_broad(_broad_file(tmp_path / "nan.hdf5", q))
    with h5py.File(tmp_path / "other.hdf5", "w") as f:
        f["imu_gyr"] = np.zeros((2, 3))
    with pytest.raises(ValueError, match="not a BROAD trial: no dataset 'imu_acc'"):
        read_broad(tmp_path / "other.hdf5")
    with pytest.raises(FileNotFoundError, match=r"no such file: .*absent\.hdf5"):
        read_broad(tmp_path / "absent.hdf5")


def test_broad_trials_folder_cases(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"BROAD folder .*missing does not exist"):
        broad_trials(tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match=r"neither trials\.json nor any \.hdf5"):
        broad_trials(tmp_path)
    q = np.tile([1.0, 0, 0, 0], (3, 1))
    _broad_file(tmp_path / "b.hdf5", q)
    _broad_file(tmp_path / "a.hdf5", q)
    listed = broad_trials(tmp_path)
    assert [(t.name, t.groups, t.description) for t in listed] == [
        ("a", ("all_trials",), ""), ("b", ("all_trials",), "")]
    index = {"trials": {"b": {"description": "B", "groups": ["all_trials", "fast"]},
                        "c": {"description": "no file", "groups": ["all_trials"]}}}
    (tmp_path / "trials.json").write_text(json.dumps(index), encoding="utf-8")
    expected = BroadTrial("b", tmp_path / "b.hdf5", "B", ("all_trials", "fast"))
    assert broad_trials(tmp_path) == [expected]
    (tmp_path / "trials.json").write_text("[]", encoding="utf-8")
    with pytest.raises(ValueError, match=r"is not a BROAD trials\.json"):
        broad_trials(tmp_path)
