"""Phone logger exports (Sensor Logger, phyphox) and per-sensor files merged on the gyro clock.

The fixtures are written from the apps' documented formats, with a simulated motion (and its
truth) as the values:

- Sensor Logger (Kelvin Choi): github.com/tszheichoi/awesome-sensor-logger, UNITS.md ("time is
  in nanoseconds since epoch", "seconds_elapsed is in seconds", accelerometer m/s² *without*
  gravity and TotalAcceleration with it on Android, gyroscope rad/s, magnetometer µT),
  COORDINATES.md (iOS and Android differ by a sign on all three acceleration axes; gravity
  points to -z on iOS, +z on Android for a phone flat on a table) and the README (one CSV
  per sensor in the zip export, columns ``time,seconds_elapsed,z,y,x``; ``Metadata.csv`` with
  ``platform``).
- phyphox: the ``<export>`` sets of its experiment files in phyphox/phyphox-android
  (app/src/main/assets/experiments/gyroscope.phyphox: ``Time (s)``, ``Gyroscope x (rad/s)``...;
  accelerometer ``Acceleration x (m/s^2)``; magnetometer ``Magnetic field x (µT)``), exported
  as CSV with quoted names.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import margtrack as mt
from margtrack import io

T0_NS = 1_698_501_144_401_773_000  # an epoch time in ns, as in the Sensor Logger README


@pytest.fixture(scope="module")
def motion() -> mt.Recording:
    return mt.sim.simulate_motion("random", duration_s=6, rate_hz=100, seed=7)


def _sensor_logger_file(path: Path, t_s: np.ndarray, xyz: np.ndarray) -> Path:
    """One Sensor Logger CSV: time (ns since the epoch), seconds_elapsed, z, y, x."""
    lines = ["time,seconds_elapsed,z,y,x"]
    for t, (x, y, z) in zip(np.asarray(t_s).tolist(), np.asarray(xyz).tolist(), strict=True):
        lines.append(f"{T0_NS + round(t * 1e9)},{t!r},{z!r},{y!r},{x!r}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _phyphox_file(path: Path, t_s, blocks: dict[str, np.ndarray], delim: str = ",") -> Path:
    """A phyphox CSV export: quoted names with units, one row per sample."""
    names = {"gyr": "Gyroscope {} (rad/s)", "acc": "Acceleration {} (m/s^2)",
             "mag": "Magnetic field {} (µT)"}
    header = ['"Time (s)"'] + [f'"{names[k].format(a)}"' for k in blocks for a in "xyz"]
    lines = [delim.join(header)]
    for i, t in enumerate(t_s):
        values = [t, *(v for k in blocks for v in blocks[k][i])]
        lines.append(delim.join(f"{v:.9E}" for v in values))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _android_folder(folder: Path, rec: mt.Recording, total: bool = True) -> Path:
    """Gyroscope at 100 Hz, (Total)Acceleration at 50 Hz, Magnetometer at 25 Hz."""
    folder.mkdir()
    _sensor_logger_file(folder / "Gyroscope.csv", rec.t, rec.gyr)
    if total:
        _sensor_logger_file(folder / "TotalAcceleration.csv", rec.t[::2], rec.acc[::2])
        _sensor_logger_file(folder / "Accelerometer.csv", rec.t[::2], rec.acc[::2] * 0.0)
    _sensor_logger_file(folder / "Magnetometer.csv", rec.t[1::4], rec.mag[1::4])
    (folder / "Metadata.csv").write_text(
        "version,device name,recording time,platform\n3,Pixel,2023-10-28_13-52-24,android\n"
    )
    return folder


def test_sensor_logger_android_folder_is_merged_on_the_gyro_clock(tmp_path, motion):
    rec = io.read(_android_folder(tmp_path / "walk", motion))
    np.testing.assert_allclose(rec.t - rec.t[0], motion.t, atol=3e-7)  # ns text, float64 s
    assert rec.t[0] == pytest.approx(T0_NS / 1e9, abs=1e-6)
    np.testing.assert_array_equal(rec.gyr, motion.gyr)
    # acc at 50 Hz interpolated linearly (004) onto the 100 Hz gyro stamps: the oracle
    t_acc = (T0_NS + np.round(motion.t[::2] * 1e9)) / 1e9
    for k in range(3):
        np.testing.assert_allclose(rec.acc[:, k], np.interp(rec.t, t_acc, motion.acc[::2, k]),
                                   atol=1e-9)
    np.testing.assert_allclose(rec.acc[::2], motion.acc[::2], atol=1e-9)  # acc's own samples
    np.testing.assert_allclose(rec.mag[1::4], motion.mag[1::4], atol=1e-9)
    files = rec.meta["sensor_files"]
    assert files["acc"]["file"] == "TotalAcceleration.csv"  # not the gravity-free one
    assert files["gyr"]["layout"] == "sensor-logger" and files["gyr"]["units"]["time"] == "ns"
    # 601 gyro samples; mag from sample 1 to 597: samples 0 and 598-600 hold its nearest one
    assert motion.n_samples == 601
    assert rec.meta["held_outside_span"] == {"mag": 4}
    est = mt.create("default").run(rec)
    err = mt.summarize(mt.error_series(est.quat, motion.quat_true, est.frame, motion.frame))
    assert err.total_rmse_deg < 4.0


def test_sensor_logger_ios_accelerometer_plus_gravity_gives_specific_force(tmp_path, motion):
    folder = tmp_path / "ios"
    folder.mkdir()
    gravity = np.tile([0.0, 0.0, 9.80665], (motion.n_samples, 1))  # a made-up split
    user = motion.acc - gravity
    _sensor_logger_file(folder / "Gyroscope.csv", motion.t, motion.gyr)
    # iOS reports inertial force: both files carry the opposite sign to Android's
    _sensor_logger_file(folder / "Accelerometer.csv", motion.t, -user)
    _sensor_logger_file(folder / "Gravity.csv", motion.t, -gravity)
    (folder / "Metadata.csv").write_text("version,device name,platform\n3,iPhone,iOS\n")
    rec = io.read(folder)
    np.testing.assert_allclose(rec.acc, motion.acc, atol=1e-9)
    assert rec.meta["acc_from"] == "Accelerometer + Gravity (ios)"
    (folder / "Metadata.csv").write_text("version,device name,platform\n3,Pixel,android\n")
    np.testing.assert_allclose(io.read(folder).acc, -motion.acc, atol=1e-9)
    (folder / "Metadata.csv").unlink()
    with pytest.raises(ValueError, match=r"opposite signs on iOS and Android.*Metadata\.csv"):
        io.read(folder)
    (folder / "Gravity.csv").unlink()
    with pytest.raises(ValueError, match=r"acceleration without gravity.*TotalAcceleration"):
        io.read(folder)


def test_sensor_logger_repeated_rows_are_dropped_and_a_clock_going_back_is_named(tmp_path,
                                                                                motion):
    folder = _android_folder(tmp_path / "rep", motion)
    gyr = folder / "Gyroscope.csv"
    lines = gyr.read_text().splitlines()
    lines.insert(11, lines[10])  # a re-sent buffered sample: line 12 repeats line 11
    gyr.write_text("\n".join(lines) + "\n")
    rec = io.read(folder)
    assert rec.meta["sensor_files"]["gyr"]["repeated_rows_dropped"] == 1
    np.testing.assert_array_equal(rec.gyr, motion.gyr)
    lines[21], lines[22] = lines[22], lines[21]
    gyr.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"Gyroscope\.csv: the timestamp on line 23 .* on line "
                                         r"22 .*timestamps must increase"):
        io.read(folder)


def test_one_sensor_file_alone_points_to_the_folder(tmp_path, motion):
    folder = _android_folder(tmp_path / "one", motion)
    with pytest.raises(ValueError, match=r"one sensor of a phone logger export.*one"):
        io.read(folder / "Gyroscope.csv")


def test_phyphox_folder_and_list_of_files(tmp_path, motion):
    folder = tmp_path / "phyphox"
    folder.mkdir()
    _phyphox_file(folder / "Gyroscope.csv", motion.t, {"gyr": motion.gyr})
    _phyphox_file(folder / "Accelerometer.csv", motion.t[::2], {"acc": motion.acc[::2]})
    _phyphox_file(folder / "Magnetometer.csv", motion.t[::5], {"mag": motion.mag[::5]})
    _phyphox_file(folder / "Linear Acceleration.csv", motion.t, {"acc": motion.acc * 0})
    rec = io.read(folder)
    np.testing.assert_allclose(rec.t, motion.t, atol=1e-9)
    np.testing.assert_allclose(rec.gyr, motion.gyr, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(rec.acc[::2], motion.acc[::2], rtol=1e-8)
    assert rec.meta["sensor_files"]["acc"]["layout"] == "phyphox"
    assert rec.meta["sensor_files"]["mag"]["units"]["mag"] == "uT"
    both = io.read([folder / "Gyroscope.csv", folder / "Accelerometer.csv"])
    np.testing.assert_array_equal(both.acc, rec.acc)
    assert both.mag is None


def test_phyphox_single_table_with_several_sensors_is_recognised(tmp_path, motion):
    p = _phyphox_file(tmp_path / "Raw Data.csv", motion.t,
                      {"acc": motion.acc, "gyr": motion.gyr}, delim="\t")
    rec = io.read(p)
    np.testing.assert_allclose(rec.gyr, motion.gyr, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(rec.acc, motion.acc, rtol=1e-8)
    assert rec.meta["layout_name"] == "phyphox" and rec.mag is None


def test_generic_per_sensor_files_take_the_declared_units(tmp_path, motion):
    folder = tmp_path / "lab"
    folder.mkdir()
    for name, values, scale in (("gyr.csv", motion.gyr, 180 / np.pi), ("acc.csv", motion.acc,
                                                                        1 / 9.80665)):
        lines = ["timestamp,x,y,z"] + [
            f"{t * 1e3!r},{x * scale!r},{y * scale!r},{z * scale!r}"
            for t, (x, y, z) in zip(motion.t.tolist(), values.tolist(), strict=True)
        ]
        (folder / name).write_text("\n".join(lines) + "\n")
    rec = io.read(folder, gyr_unit="deg/s", acc_unit="g", time_unit="ms")
    np.testing.assert_allclose(rec.gyr, motion.gyr, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(rec.acc, motion.acc, rtol=1e-13)
    np.testing.assert_allclose(rec.t, motion.t, atol=1e-12)


def test_folder_and_file_errors(tmp_path, motion):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match=r"an x-IMU3 export \(Inertial\.csv\) or per-sensor "
                       r"files"):
        io.read(empty)
    onlygyr = tmp_path / "g"
    onlygyr.mkdir()
    _sensor_logger_file(onlygyr / "Gyroscope.csv", motion.t, motion.gyr)
    with pytest.raises(ValueError, match=r"no accelerometer file .*found \['Gyroscope\.csv'\]"):
        io.read(onlygyr)
    with pytest.raises(ValueError, match="cannot tell which sensor this file holds"):
        io.read([onlygyr / "Gyroscope.csv", _sensor_logger_file(tmp_path / "x.csv", motion.t,
                                                                 motion.acc)])


def test_holes_and_a_cut_last_line_in_a_sensor_file(tmp_path, motion):
    folder = _android_folder(tmp_path / "holes", motion)
    acc = folder / "TotalAcceleration.csv"
    lines = acc.read_text().splitlines()
    fields = lines[20].split(",")
    fields[2] = ""  # z empty on line 21 (acc sample 19, t = 0.38 s)
    lines[20] = ",".join(fields)
    acc.write_text("\n".join(lines) + "\n" + lines[-1][:12])  # and a last line cut short
    with pytest.warns(UserWarning) as caught:
        rec = io.read(folder)
    text = " ".join(str(w.message) for w in caught)
    assert "line 303 is truncated" in text and "1 row(s) with an empty" in text
    assert "first on line 21" in text
    info = rec.meta["sensor_files"]["acc"]
    assert info["rows_with_holes"] == 1 and info["dropped_lines"] == [303]
    # the hole is bridged by interpolating its neighbours (samples 36 and 40 of the gyro)
    i = 38
    np.testing.assert_allclose(rec.acc[i], 0.5 * (motion.acc[36] + motion.acc[40]), atol=1e-9)
    assert np.isfinite(rec.acc).all()
