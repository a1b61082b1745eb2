"""The io API's small edges: estimate readers exported, DataFrames pointed to from_dataframe,
``margtrack run`` on several files with one sensor type each (issue 18)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import margtrack as mt
from margtrack import io, methods
from margtrack.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def motion() -> mt.Recording:
    """6 s of random motion at 100 Hz (ENU), with truth."""
    return mt.sim.simulate_motion("random", duration_s=6, rate_hz=100, seed=11)


def _sensor_file(path: Path, t_s: np.ndarray, xyz: np.ndarray) -> Path:
    """A per-sensor CSV of the generic layout: t (s), x, y, z (the declared units)."""
    rows = [f"{t!r},{x!r},{y!r},{z!r}" for t, (x, y, z) in
            zip(t_s.tolist(), xyz.tolist(), strict=True)]
    path.write_text("t,x,y,z\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def sensor_files(motion, tmp_path_factory) -> list[Path]:
    """Gyroscope at 100 Hz, accelerometer at 50 Hz, magnetometer at 25 Hz, one file each."""
    folder = tmp_path_factory.mktemp("files")
    return [
        _sensor_file(folder / "Gyroscope.csv", motion.t, motion.gyr),
        _sensor_file(folder / "Accelerometer.csv", motion.t[::2], motion.acc[::2]),
        _sensor_file(folder / "Magnetometer.csv", motion.t[::4], motion.mag[::4]),
    ]


def test_estimate_readers_are_exported(motion, tmp_path):
    est = methods.create("gyro").run(motion.slice(0, 50))
    io.write_estimate(est, tmp_path / "e.csv")
    io.write(motion.slice(0, 50), tmp_path / "r.csv")
    assert "read_estimate" in io.__all__ and "is_estimate_file" in io.__all__
    assert io.is_estimate_file(tmp_path / "e.csv")
    assert not io.is_estimate_file(tmp_path / "r.csv")
    np.testing.assert_array_equal(io.read_estimate(tmp_path / "e.csv").quat, est.quat)


def test_a_dataframe_is_pointed_to_from_dataframe(motion):
    pd = pytest.importorskip("pandas", reason="pandas is optional; the check needs a DataFrame")
    rec = motion.slice(0, 100)
    df = pd.DataFrame({"t": rec.t, **{f"g{a}": rec.gyr[:, k] for k, a in enumerate("xyz")},
                       **{f"a{a}": rec.acc[:, k] for k, a in enumerate("xyz")}})
    estimator = methods.create("robust")
    with pytest.raises(TypeError) as info:
        estimator.run(df)
    text = str(info.value)
    assert "\n" not in text and "margtrack.io.from_dataframe" in text
    with pytest.raises(TypeError, match="not str; for arrays use run"):
        estimator.run("walk.csv")
    with pytest.raises(TypeError, match="a list of Recordings, not list"):
        estimator.run([rec, "walk.csv"])
    # the route the message names works, and gives the Recording's own result
    converted = io.from_dataframe(df, {"t": "t", "gyr": "gx,gy,gz", "acc": "ax,ay,az"})
    got = methods.create("robust").run(converted)
    expected = methods.create("robust").run(
        mt.Recording(t=rec.t, gyr=rec.gyr, acc=rec.acc, frame="ENU"))
    np.testing.assert_allclose(got.quat, expected.quat, atol=1e-12)


def _hand_merged(motion: mt.Recording) -> mt.Recording:
    """The oracle: accelerometer and magnetometer interpolated linearly with np.interp."""
    def interp(t_src, values):
        return np.stack([np.interp(motion.t, t_src, values[:, k]) for k in range(3)], axis=1)

    return mt.Recording(t=motion.t, gyr=motion.gyr, acc=interp(motion.t[::2], motion.acc[::2]),
                        mag=interp(motion.t[::4], motion.mag[::4]), frame="ENU")


def test_run_takes_several_files_with_one_sensor_type_each(motion, sensor_files, tmp_path):
    out = tmp_path / "out.csv"
    result = runner.invoke(app, ["run", *map(str, sensor_files), "-m", "robust", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert f"robust: {motion.n_samples} samples" in result.output
    got = io.read_estimate(out)
    assert got.frame == "ENU" and got.method == "robust"
    expected = methods.create("robust").run(_hand_merged(motion))
    np.testing.assert_allclose(got.t, motion.t, atol=1e-12)
    np.testing.assert_allclose(got.quat, expected.quat, atol=1e-9)
    # the estimate is an orientation of this motion: within a few degrees of the truth
    err = mt.summarize(mt.error_series(got.quat, motion.quat_true, "ENU", "ENU"))
    assert err.total_rmse_deg < 5.0
    # the files in another order give the same result (each is named after its sensor)
    again = tmp_path / "again.csv"
    swapped = [sensor_files[2], sensor_files[0], sensor_files[1]]
    assert runner.invoke(app, ["run", *map(str, swapped), "-m", "robust", "-o",
                               str(again)]).exit_code == 0
    np.testing.assert_array_equal(io.read_estimate(again).quat, got.quat)


def test_several_files_bad_input(motion, sensor_files, tmp_path):
    def refused(*args: object) -> str:
        result = runner.invoke(app, ["run", *map(str, args)])
        assert result.exit_code == 2, result.output
        return " ".join(result.output.split())

    gyr, acc, mag = sensor_files
    out = tmp_path / "o.csv"
    twin = _sensor_file(tmp_path / "gyro.csv", motion.t, motion.gyr)
    assert "both hold gyr" in refused(gyr, twin, acc, "-o", out)
    odd = _sensor_file(tmp_path / "walk.csv", motion.t, motion.gyr)
    assert "cannot tell which sensor" in refused(gyr, acc, odd, "-o", out)
    assert "no accelerometer file" in refused(gyr, mag, "-o", out)
    assert "no such file" in refused(gyr, tmp_path / "Accelerometer.csv", "-o", out)
    before = acc.read_bytes()
    assert "input" in refused(gyr, acc, "-o", acc).lower()  # never over an input
    assert acc.read_bytes() == before
    assert not out.exists()
