"""``calibrate_app`` (mounted by the lead as ``margtrack calibrate``), through typer's runner."""

import json
import math

import matplotlib.image
import numpy as np
import pytest
from typer.testing import CliRunner

from margtrack import io
from margtrack.calibration import load_calibration, run_guided
from margtrack.calibration.simulate_procedure import error_profile
from margtrack.cli.calibrate import calibrate_app

runner = CliRunner()


def invoke(*args):
    result = runner.invoke(calibrate_app, [str(a) for a in args])
    return result


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("calibrate")
    for kind, seed, extra in (("procedure", 1, ()), ("tumble", 2, ("--duration", 40)),
                              ("still", 3, ("--duration", 120))):
        out = folder / f"{kind}.h5"
        result = invoke("simulate", "-o", out, "--kind", kind, "--profile", "raw", "--seed",
                        seed, *extra)
        assert result.exit_code == 0, result.output
    return folder


def test_guided_writes_the_library_result(files):
    out = files / "guided.json"
    result = invoke("guided", "--source", files / "procedure.h5", "-o", out)
    assert result.exit_code == 0, result.output
    assert "step 18: gravity" in result.output and "calibration complete" in result.output
    saved = load_calibration(out)
    expected = run_guided(io.read(files / "procedure.h5")).calibration
    assert saved.gyr == expected.gyr and saved.acc == expected.acc and saved.mag == expected.mag
    gyr, acc, _ = error_profile("raw")
    np.testing.assert_allclose(saved.acc.b, acc.bias, atol=0.01)
    # the printed table carries the recovered figures: the gyro scale errors in %
    row = next(line for line in result.output.splitlines() if "gyr scale error (%)" in line)
    printed = [float(v) for v in row.replace("│", " ").split()[-3:]]
    np.testing.assert_allclose(printed, 100 * np.array(gyr.scale), atol=0.2 * 0.1)


def test_accel_mag_gyro_allan_fill_one_file(files):
    out = files / "parts.json"
    r = invoke("accel", files / "procedure.h5", "-o", out)
    assert r.exit_code == 0, r.output
    assert "12-parameter" in r.output and "wrote" in r.output
    r = invoke("mag", files / "tumble.h5", "-o", out)
    assert r.exit_code == 0, r.output
    assert "sphere coverage" in r.output and "updated" in r.output
    r = invoke("gyro", files / "procedure.h5", "--angle-deg", 90, "-o", out)
    assert r.exit_code == 0, r.output
    assert "known turns (000 eq. 5)" in r.output
    png = files / "allan.png"
    r = invoke("allan", files / "still.h5", "--png", png, "-o", out)
    assert r.exit_code == 0, r.output
    assert "gyr_noise_density_rad_s_sqrt_hz" in r.output
    image = matplotlib.image.imread(png)
    assert image.shape[1] > image.shape[0] > 300  # two panels side by side
    assert image[..., :3].std() > 0.05  # something is drawn
    cal = load_calibration(out)
    gyr, acc, mag = error_profile("raw")
    np.testing.assert_allclose(cal.acc.b, acc.bias, atol=0.01)
    assert np.linalg.norm(cal.mag.b - np.array(mag.bias)) < 0.5  # 1 % of 50 µT
    np.testing.assert_allclose(cal.gyr.b, gyr.bias, atol=math.radians(0.02))
    np.testing.assert_allclose(1.0 / np.diag(cal.gyr.K), 1.0 / np.diag(gyr.matrix()), rtol=2e-3)
    # two minutes are too short for the walk, but the white noise is already within 10 %
    assert cal.noise.gyr_noise_density_rad_s_sqrt_hz == pytest.approx(gyr.noise_density, rel=0.1)
    doc = json.loads(out.read_text())
    assert doc["noise"] is not None and doc["mag"]["unit"] == "uT"


def test_apply_and_show(files):
    cal = files / "guided.json"
    if not cal.is_file():
        assert invoke("guided", "--source", files / "procedure.h5", "-o", cal,
                      "--quiet").exit_code == 0
    out = files / "calibrated.h5"
    r = invoke("apply", files / "tumble.h5", "-c", cal, "-o", out)
    assert r.exit_code == 0, r.output
    rec = io.read(out)
    np.testing.assert_allclose(rec.acc, load_calibration(cal).acc.correct(
        io.read(files / "tumble.h5").acc))
    r = invoke("show", cal)
    assert r.exit_code == 0 and "dip" in r.output


def test_errors_are_one_line_with_exit_code_2(files):
    r = invoke("mag", files / "still.h5")
    assert r.exit_code == 2 and "too little rotation" in r.output
    r = invoke("simulate", "-o", files / "x.h5", "--kind", "dance")
    assert r.exit_code == 2 and "kind must be procedure, still or tumble" in r.output
    r = invoke("guided", "--source", files / "tumble.h5", "-o", files / "no.json")
    assert r.exit_code == 2 and "still waiting for step" in r.output
