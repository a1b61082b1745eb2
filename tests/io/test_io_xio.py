"""x-IMU3 reader: the real lower-body recording (units, rates, mag alignment) and edge cases."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from margtrack.io import read_xio_body, read_xio_quaternion, read_xio_sensor

SENSORS = {
    "left_foot": "Left Foot", "left_lower_leg": "Left Lower Leg",
    "left_upper_leg": "Left Upper Leg", "pelvis": "Pelvis", "right_foot": "Right Foot",
    "right_lower_leg": "Right Lower Leg", "right_upper_leg": "Right Upper Leg",
}


@pytest.fixture(scope="module")
def xio_dir(xio_folder: Path) -> Path:
    return xio_folder


@pytest.fixture(scope="module")
def pelvis(xio_dir: Path):
    return read_xio_sensor(xio_dir / "pelvis")


def _raw(path: Path) -> np.ndarray:
    return np.loadtxt(path, delimiter=",", skiprows=1)


def test_pelvis_units_and_timestamps(pelvis, xio_dir: Path) -> None:
    raw = _raw(xio_dir / "pelvis" / "Inertial.csv")
    assert pelvis.n_samples == raw.shape[0] == 900
    assert pelvis.t[0] == 917.418209  # absolute device seconds from 917418209 us
    np.testing.assert_array_equal(pelvis.t, raw[:, 0] / 1e6)
    np.testing.assert_allclose(pelvis.gyr[0], np.radians([1.013036, 0.755306, 0.729441]),
                               rtol=1e-15)
    np.testing.assert_allclose(pelvis.acc[0], 9.80665 * np.array([0.903545, -0.036132, 0.439224]),
                               rtol=1e-15)
    assert 49.0 < pelvis.rate_hz < 51.0
    assert pelvis.duration_s == pytest.approx(18.6, abs=0.1)


def test_pelvis_standing_start_reads_one_g(pelvis) -> None:
    norms = np.linalg.norm(pelvis.acc[:25], axis=1)
    assert norms.mean() == pytest.approx(9.81, abs=0.15)
    assert np.abs(pelvis.gyr[:25]).max() < np.radians(5.0)  # standing still


def test_pelvis_name_and_meta(pelvis) -> None:
    assert pelvis.name == "Pelvis"
    assert pelvis.meta["serial_number"] == "64F0EDBF"
    assert pelvis.meta["units"] == {"t": "us", "gyr": "deg/s", "acc": "g", "mag": "a.u."}
    assert 19.0 < pelvis.meta["mag_rate_hz"] < 22.0
    assert pelvis.meta["mag_held_samples"] == 1  # the last inertial sample is after the last mag
    assert pelvis.meta["inertial_gaps"] == pelvis.gaps().size == 27
    assert pelvis.quat_true is None


def test_pelvis_mag_is_interpolated_between_raw_samples(pelvis, xio_dir: Path) -> None:
    raw = _raw(xio_dir / "pelvis" / "Magnetometer.csv")
    t_mag = raw[:, 0] / 1e6
    for k in (0, 1, 100, 451, 898):
        j = int(np.searchsorted(t_mag, pelvis.t[k])) - 1  # raw samples j, j+1 bracket t[k]
        w = (pelvis.t[k] - t_mag[j]) / (t_mag[j + 1] - t_mag[j])
        assert 0.0 <= w <= 1.0
        np.testing.assert_allclose(pelvis.mag[k], (1 - w) * raw[j, 1:] + w * raw[j + 1, 1:],
                                   rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(pelvis.mag[-1], raw[-1, 1:])  # held after the last raw one


def test_device_quaternion(pelvis, xio_dir: Path) -> None:
    t, q = read_xio_quaternion(xio_dir / "pelvis")
    np.testing.assert_array_equal(t, pelvis.t)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, rtol=0, atol=1e-14)
    first = np.array([0.850093, -0.040743, -0.524145, -0.034592])  # first row of the file
    assert np.linalg.norm(first) == pytest.approx(1.000122, abs=1e-6)  # why it is normalised
    np.testing.assert_allclose(q[0], first / np.linalg.norm(first), rtol=1e-15)


def test_body_reads_all_sensors(xio_dir: Path) -> None:
    body = read_xio_body(xio_dir)
    assert list(body) == sorted(SENSORS)
    for folder, rec in body.items():
        assert rec.name == SENSORS[folder]
        assert 49.0 < rec.rate_hz < 51.0
        assert np.linalg.norm(rec.acc[:10], axis=1).mean() == pytest.approx(9.81, abs=0.2)
        assert rec.mag.shape == rec.acc.shape


# --- synthetic folders ----------------------------------------------------------------------

INERTIAL_HEADER = ("Timestamp (us),Gyroscope X (deg/s),Gyroscope Y (deg/s),Gyroscope Z (deg/s),"
                   "Accelerometer X (g),Accelerometer Y (g),Accelerometer Z (g)")


def _sensor(folder: Path, t_us: list[int], t_mag_us: list[int] | None = None) -> Path:
    folder.mkdir(parents=True)
    rows = [f"{t},{i},0,-{i},0,0,1" for i, t in enumerate(t_us)]
    (folder / "Inertial.csv").write_text("\n".join([INERTIAL_HEADER, *rows]) + "\n")
    if t_mag_us is not None:
        mag = [f"{t},{10 * i},{-i},0.5" for i, t in enumerate(t_mag_us)]
        (folder / "Magnetometer.csv").write_text(
            "\n".join(["Timestamp (us),X (a.u.),Y (a.u.),Z (a.u.)", *mag]) + "\n")
    return folder


def test_mag_equals_raw_at_shared_timestamps(tmp_path: Path) -> None:
    folder = _sensor(tmp_path / "s", [1000, 21000, 41000, 61000, 81000], [1000, 41000, 81000])
    rec = read_xio_sensor(folder)
    np.testing.assert_array_equal(rec.mag[[0, 2, 4]], [[0, 0, 0.5], [10, -1, 0.5], [20, -2, 0.5]])
    np.testing.assert_allclose(rec.mag[1], [5.0, -0.5, 0.5], rtol=1e-12)
    np.testing.assert_allclose(rec.gyr[:, 0], np.radians([0, 1, 2, 3, 4]), rtol=1e-15)
    assert rec.meta["mag_rate_hz"] == pytest.approx(25.0)
    assert rec.name == "s" and rec.meta["serial_number"] is None  # no Command.json


def test_without_magnetometer_file(tmp_path: Path) -> None:
    rec = read_xio_sensor(_sensor(tmp_path / "s", [0, 20000, 40000]))
    assert rec.mag is None and rec.meta["mag_rate_hz"] is None


def test_command_json_gives_name_and_serial(tmp_path: Path) -> None:
    folder = _sensor(tmp_path / "s", [0, 20000])
    (folder / "Command.json").write_text(json.dumps(
        [{"ping": {"interface": "UDP", "name": "Knee", "sn": "ABC"}}, {"time": "x"}]))
    rec = read_xio_sensor(folder)
    assert (rec.name, rec.meta["serial_number"]) == ("Knee", "ABC")


def test_duplicate_and_backwards_timestamps_are_errors(tmp_path: Path) -> None:
    folder = _sensor(tmp_path / "dup", [0, 20000, 20000, 60000])
    with pytest.raises(ValueError, match=r"Inertial\.csv: duplicate timestamp at sample 2") as err:
        read_xio_sensor(folder)
    assert "(line 4): 20000 us then 20000 us" in str(err.value)
    folder = _sensor(tmp_path / "back", [0, 20000, 40000, 60000], [0, 50000, 40000])
    with pytest.raises(ValueError, match=r"Magnetometer\.csv: backwards .* at sample 2 \(line 4\)"):
        read_xio_sensor(folder)


def test_missing_pieces(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"x-IMU3 folder .*nowhere does not exist"):
        read_xio_sensor(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match=r"no such file: .*Inertial\.csv"):
        read_xio_sensor(tmp_path / "empty")
    with pytest.raises(FileNotFoundError, match=r"no sensor subfolder with an Inertial\.csv"):
        read_xio_body(tmp_path / "empty")
    folder = tmp_path / "odd"
    folder.mkdir()
    (folder / "Inertial.csv").write_text("Timestamp (us),Gyroscope X (rad/s)\n0,1\n")
    with pytest.raises(ValueError, match=r"no column 'Gyroscope X \(deg/s\)'.*x-IMU3 export"):
        read_xio_sensor(folder)
