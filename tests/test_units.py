"""Declared units: the unit table, Recording.with_units, the magnitude check, io.read units."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from margtrack import io
from margtrack.recording import Recording
from margtrack.units import (
    ACC_UNITS,
    GYR_UNITS,
    MAG_UNITS,
    TIME_UNITS,
    UnitError,
    check_unit_magnitudes,
    convert_unit,
    unit_factor,
    unit_fix_api,
    unit_fix_keyword,
)


def _recording(n: int = 200, *, mag: bool = True) -> Recording:
    """A seeded recording at 100 Hz in SI units: gyr up to ~3 rad/s, acc ~9.8 m/s², mag ~50 µT."""
    rng = np.random.default_rng(42)
    q = rng.normal(size=(n, 4))
    return Recording(
        t=np.arange(n) / 100.0,
        gyr=rng.uniform(-3.0, 3.0, (n, 3)),
        acc=np.array([0.0, 0.0, 9.81]) + rng.normal(scale=0.2, size=(n, 3)),
        mag=np.array([20.0, 0.0, -45.0]) + rng.normal(scale=0.5, size=(n, 3)) if mag else None,
        quat_true=q / np.linalg.norm(q, axis=1)[:, None],
        movement=rng.random(n) < 0.7,
        name="units", meta={"k": "v"},
    )


# --- the table ------------------------------------------------------------------------------


def test_gyr_factors() -> None:
    assert GYR_UNITS["rad/s"] == 1.0
    assert unit_factor("gyr", "deg/s") == np.pi / 180.0
    np.testing.assert_array_equal(
        convert_unit([180.0, 90.0, -360.0, 0.0], "gyr", "deg/s"),
        [np.pi, np.pi / 2, -2 * np.pi, 0.0],
    )


def test_acc_factors_and_aliases() -> None:
    assert convert_unit(1.0, "acc", "g") == 9.80665  # standard gravity, exactly
    assert convert_unit(-0.5, "acc", "g") == -4.903325
    for alias in ("m/s2", "m/s^2", "m/s²"):
        assert ACC_UNITS[alias] == 1.0
        assert convert_unit(9.81, "acc", alias) == 9.81


def test_mag_factors_to_microtesla() -> None:
    # 50 µT (a typical field) in every declared unit
    in_units = {"uT": 50.0, "µT": 50.0, "nT": 50_000.0, "mT": 0.05, "T": 5e-5, "G": 0.5,
                "mG": 500.0}
    assert set(in_units) == set(MAG_UNITS)
    for unit, value in in_units.items():
        assert convert_unit(value, "mag", unit) == 50.0, unit
    assert (MAG_UNITS["nT"], MAG_UNITS["G"], MAG_UNITS["mG"], MAG_UNITS["T"]) == (
        1e-3, 100.0, 0.1, 1e6
    )


def test_time_factors_to_seconds() -> None:
    assert convert_unit(1500.0, "time", "ms") == 1.5
    assert convert_unit(2_500_000.0, "time", "us") == 2.5
    assert convert_unit(2_500_000.0, "time", "µs") == 2.5
    assert convert_unit(3e9, "time", "ns") == 3.0
    assert convert_unit(7.25, "time", "s") == 7.25
    assert dict(TIME_UNITS) == {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}


def test_sub_units_divide_by_the_exact_power_of_ten() -> None:
    # t_ms / 1e3 is one rounding; t_ms * 1e-3 would be two and miss the written seconds
    t_s = np.arange(100_000) / 286.0
    t_ms = t_s * 1e3
    exact = t_ms / 1e3
    np.testing.assert_array_equal(convert_unit(t_ms, "time", "ms"), exact)
    assert np.any(t_ms * 1e-3 != exact)  # the naive product differs somewhere


@pytest.mark.parametrize(
    ("signal", "unit", "valid"),
    [
        ("gyr", "rpm", r"\['deg/s', 'rad/s'\]"),
        ("acc", "ft/s2", r"\['g', 'm/s2', 'm/s\^2', 'm/s²'\]"),
        ("mag", "gauss", r"\['G', 'T', 'mG', 'mT', 'nT', 'uT', 'µT'\]"),
        ("time", "min", r"\['ms', 'ns', 's', 'us', 'µs'\]"),
    ],
)
def test_unknown_units_list_the_valid_ones(signal: str, unit: str, valid: str) -> None:
    with pytest.raises(ValueError, match=rf"{signal}_unit must be one of {valid}, got '{unit}'"):
        unit_factor(signal, unit)
    with pytest.raises(ValueError, match=rf"{signal}_unit must be one of {valid}"):
        _recording().with_units(**{signal: unit})


def test_unknown_signal() -> None:
    with pytest.raises(ValueError, match=r"signal must be one of \['acc', 'gyr', 'mag', 'time'\]"):
        unit_factor("temp", "C")


# --- Recording.with_units ---------------------------------------------------------------------


def test_with_units_round_trips_every_signal() -> None:
    rec = _recording()
    foreign = dataclasses.replace(
        rec,
        t=rec.t * 1e3,
        gyr=np.degrees(rec.gyr),
        acc=rec.acc / 9.80665,
        mag=rec.mag * 1e3,
    )
    back = foreign.with_units(gyr="deg/s", acc="g", mag="nT", time="ms")
    np.testing.assert_allclose(back.gyr, rec.gyr, rtol=1e-15, atol=0)
    np.testing.assert_allclose(back.acc, rec.acc, rtol=1e-15, atol=0)
    np.testing.assert_allclose(back.mag, rec.mag, rtol=1e-15, atol=0)
    np.testing.assert_allclose(back.t, rec.t, rtol=1e-15, atol=0)
    assert back.meta["units_converted"] == {"gyr": "deg/s", "acc": "g", "mag": "nT", "time": "ms"}
    assert back.meta["k"] == "v" and "units_converted" not in foreign.meta
    # what has no unit is kept as it is
    np.testing.assert_array_equal(back.quat_true, rec.quat_true)
    np.testing.assert_array_equal(back.movement, rec.movement)
    assert (back.frame, back.name) == (rec.frame, rec.name)
    # the source is a new, untouched object
    assert back is not foreign
    np.testing.assert_array_equal(foreign.gyr, np.degrees(rec.gyr))


def test_with_units_in_si_changes_nothing() -> None:
    rec = _recording()
    for same in (rec.with_units(), rec.with_units(gyr="rad/s", acc="m/s²", mag="µT", time="s")):
        assert same is not rec
        for name in ("t", "gyr", "acc", "mag"):
            np.testing.assert_array_equal(getattr(same, name), getattr(rec, name))
        assert "units_converted" not in same.meta


def test_with_units_only_touches_the_declared_signal() -> None:
    rec = _recording()
    out = rec.with_units(acc="g")
    np.testing.assert_array_equal(out.acc, rec.acc * 9.80665)
    np.testing.assert_array_equal(out.gyr, rec.gyr)
    np.testing.assert_array_equal(out.t, rec.t)
    assert out.meta["units_converted"] == {"acc": "g"}


def test_mag_unit_without_magnetometer_is_ignored() -> None:
    rec = _recording(mag=False).with_units(mag="nT", gyr="deg/s")
    assert rec.mag is None
    assert rec.meta["units_converted"] == {"gyr": "deg/s"}


def test_converting_twice_is_refused() -> None:
    once = _recording().with_units(gyr="deg/s")
    with pytest.raises(ValueError, match=r"gyr was already converted from deg/s.*twice"):
        once.with_units(gyr="deg/s")
    # another signal, or an SI declaration, is fine; the record accumulates
    twice = once.with_units(acc="g", gyr="rad/s")
    assert twice.meta["units_converted"] == {"gyr": "deg/s", "acc": "g"}


def test_time_conversion_keeps_timestamps_validated() -> None:
    rec = _recording(5)
    ns = dataclasses.replace(rec, t=np.array([0.0, 1.0, 2.0, 3.0, 4.0]))
    np.testing.assert_array_equal(ns.with_units(time="ns").t, [0.0, 1e-9, 2e-9, 3e-9, 4e-9])


# --- the magnitude check ----------------------------------------------------------------------


def _gyr_deg_s(n: int = 20, first: int = 7, value: float = -120.0) -> np.ndarray:
    """A turn at 120 deg/s about y from sample ``first`` on, mistaken for rad/s."""
    gyr = np.zeros((n, 3))
    gyr[first:, 1] = value
    return gyr


def test_gyr_check_default_fix_names_the_python_api() -> None:
    acc = np.tile([0.0, 0.0, 9.81], (20, 1))
    with pytest.raises(UnitError) as info:
        check_unit_magnitudes(_gyr_deg_s(), acc)
    message = str(info.value)
    assert message.startswith("gyr ")
    assert "120.0" in message and "sample 7" in message and "sample 6" not in message
    assert message.endswith(
        "the data is probably in deg/s: pass gyr_unit='deg/s' to run() or convert with "
        "Recording.with_units(gyr='deg/s')"
    )
    assert (info.value.signal, info.value.suspected) == ("gyr", "deg/s")
    assert isinstance(info.value, ValueError)


def test_acc_check_default_fix_names_the_median_norm() -> None:
    acc = np.tile([0.0, 0.6, 0.8], (30, 1))  # norm 1: one g
    with pytest.raises(
        UnitError,
        match=r"acc has a median norm of 1\.000, about 1 g.*probably in g: pass acc_unit='g' "
        r"to run\(\) or convert with Recording\.with_units\(acc='g'\)$",
    ) as info:
        check_unit_magnitudes(np.zeros((30, 3)), acc)
    assert (info.value.signal, info.value.suspected) == ("acc", "g")


def test_cli_fix_names_the_options() -> None:
    from margtrack.cli import cli_unit_fix

    acc = np.tile([0.0, 0.0, 9.81], (20, 1))
    with pytest.raises(
        UnitError, match=r"sample 7\b.*deg/s: declare the file's unit with --gyr-unit deg/s$"
    ):
        check_unit_magnitudes(_gyr_deg_s(), acc, fix=cli_unit_fix)
    with pytest.raises(UnitError, match=r"median norm of 1\.000.*with --acc-unit g$"):
        check_unit_magnitudes(np.zeros((20, 3)), acc / 9.81, fix=cli_unit_fix)


def test_fix_is_called_with_signal_and_suspected_unit() -> None:
    calls = []

    def fix(signal: str, suspected: str) -> str:
        calls.append((signal, suspected))
        return "FIX"

    with pytest.raises(UnitError, match=r"deg/s: FIX$"):
        check_unit_magnitudes(_gyr_deg_s(), np.zeros((20, 3)), fix=fix)
    with pytest.raises(UnitError, match=r"in g: FIX$"):
        check_unit_magnitudes(np.zeros((3, 3)), np.tile([0.0, 0.0, 1.0], (3, 1)), fix=fix)
    assert calls == [("gyr", "deg/s"), ("acc", "g")]


def test_several_sensors_are_judged_each_and_the_message_names_the_sensor() -> None:
    """(S, N, 3): one call decides for each sensor what a call per sensor decides, and names
    the first sensor refused."""
    rng = np.random.default_rng(3)
    n = 900
    acc = np.tile([0.0, 0.0, 9.81], (4, n, 1)) + rng.normal(0.0, 0.3, (4, n, 3))
    gyr = rng.normal(0.0, 1.0, (4, n, 3))
    gyr[0, 100] = 300.0  # one spike on sensor 0: a glitch, not a unit
    gyr[2, 40:] *= 180.0 / np.pi  # sensor 2 in deg/s, its turn of 57 deg/s on from sample 40
    gyr[2, 40:45, 1] = 80.0
    check_unit_magnitudes(gyr[[0, 1, 3]], acc[[0, 1, 3]])
    with pytest.raises(UnitError, match=r"^sensor 2: gyr reaches .* at sample \d+ and exceeds 40 "
                       r"rad/s on \d+ of 900 samples \(first at sample 4[0-4]\)"):
        check_unit_magnitudes(gyr, acc)
    acc[1] /= 9.81  # sensor 1 in g
    acc[3, ::2] = np.nan  # half of sensor 3 missing: judged on the other half
    with pytest.raises(UnitError, match=r"^sensor 1: acc has a median norm of 1\.0\d\d, about 1 g"):
        check_unit_magnitudes(np.zeros((4, n, 3)), acc)
    for s in range(4):  # the same decisions, one sensor at a time
        refused = s in (1, 2)
        try:
            check_unit_magnitudes(gyr[s] if s != 1 else np.zeros((n, 3)), acc[s])
        except UnitError as exc:
            assert refused and not str(exc).startswith("sensor"), exc
        else:
            assert not refused


def test_acc_in_g_with_missing_samples_is_still_refused() -> None:
    """Dropped samples (nan) are left out of the median, not a reason to skip the check; a
    sensor with no finite sample at all is no evidence."""
    acc = np.tile([0.0, 0.6, 0.8], (3, 500, 1))  # 1 g: in g
    acc[0, 7] = np.nan  # one dropped sample
    acc[1, ::3] = np.nan  # a third dropped
    acc[2] = np.nan  # nothing
    with pytest.raises(UnitError, match=r"^sensor 0: acc has a median norm of 1\.000"):
        check_unit_magnitudes(np.zeros((3, 500, 3)), acc)
    with pytest.raises(UnitError, match=r"^sensor 0: acc has a median norm of 1\.000"):
        check_unit_magnitudes(np.zeros((2, 500, 3)), acc[1:])  # the third dropped
    with pytest.raises(UnitError, match=r"^acc has a median norm of 1\.000"):
        check_unit_magnitudes(np.zeros((500, 3)), acc[0])
    check_unit_magnitudes(np.zeros((500, 3)), acc[2])


def test_run_on_several_sensors_names_the_sensor_in_deg_s() -> None:
    from margtrack import methods

    n = 600
    t = np.arange(n) / 100.0
    acc = np.tile([0.0, 0.0, 9.81], (3, n, 1))
    gyr = np.zeros((3, n, 3))
    gyr[1, 50:, 2] = 90.0  # sensor 1: a 90 deg/s turn given as rad/s
    with pytest.raises(UnitError, match=r"^sensor 1: gyr .*pass gyr_unit='deg/s' to run\(\)"):
        methods.create("gyro").run(gyr=gyr, acc=acc, t=t)
    est = methods.create("gyro").run(gyr=gyr, acc=acc, t=t, gyr_unit="deg/s")
    assert est.quat.shape == (3, n, 4)


def test_fix_sentences() -> None:
    assert unit_fix_api("gyr", "deg/s") == (
        "pass gyr_unit='deg/s' to run() or convert with Recording.with_units(gyr='deg/s')"
    )
    assert unit_fix_api("acc", "g") == (
        "pass acc_unit='g' to run() or convert with Recording.with_units(acc='g')"
    )
    assert unit_fix_keyword("read_csv")("acc", "g") == (
        "pass acc_unit='g' to read_csv (or check_units=False if it really is m/s2)"
    )


def test_check_thresholds() -> None:
    acc_si = np.tile([0.0, 0.0, 9.81], (4, 1))
    check_unit_magnitudes(np.full((4, 3), 40.0), acc_si)  # 40 rad/s is the limit, not over it
    with pytest.raises(UnitError, match=r"sample 0\b.*40\.1|40\.1.*sample 0\b"):
        check_unit_magnitudes(np.full((4, 3), 40.1), acc_si)
    # free fall (norm ~0) and a hard shake (norm 25) are not taken for g
    check_unit_magnitudes(np.zeros((4, 3)), np.zeros((4, 3)))
    check_unit_magnitudes(np.zeros((4, 3)), np.full((4, 3), 25.0 / np.sqrt(3)))
    check_unit_magnitudes(np.zeros((0, 3)), np.zeros((0, 3)))


def test_from_arrays_names_its_own_keyword() -> None:
    with pytest.raises(UnitError, match=r"pass gyr_unit='deg/s' to from_arrays \(or check_units"):
        Recording.from_arrays(_gyr_deg_s(), np.tile([0.0, 0.0, 9.81], (20, 1)), rate_hz=10.0)


# --- io.read with declared units --------------------------------------------------------------


def test_read_applies_declared_units_to_margtrack_files(tmp_path: Path) -> None:
    rec = _recording()
    foreign = dataclasses.replace(
        rec, t=rec.t * 1e3, gyr=np.degrees(rec.gyr), acc=rec.acc / 9.80665, mag=rec.mag * 1e3
    )
    for name in ("r.h5", "r.csv"):
        io.write(foreign, tmp_path / name)
        back = io.read(tmp_path / name, gyr_unit="deg/s", acc_unit="g", mag_unit="nT",
                       time_unit="ms")
        np.testing.assert_allclose(back.gyr, rec.gyr, rtol=1e-15, atol=0)
        np.testing.assert_allclose(back.acc, rec.acc, rtol=1e-15, atol=0)
        np.testing.assert_allclose(back.mag, rec.mag, rtol=1e-15, atol=0)
        np.testing.assert_allclose(back.t, rec.t, rtol=1e-15, atol=0)
        assert back.meta["units_converted"] == {
            "gyr": "deg/s", "acc": "g", "mag": "nT", "time": "ms"
        }


def test_read_does_not_check_magnitudes(tmp_path: Path) -> None:
    rec = _recording()
    io.write(dataclasses.replace(rec, gyr=np.degrees(rec.gyr), acc=rec.acc / 9.81),
             tmp_path / "r.h5")
    back = io.read(tmp_path / "r.h5")  # the caller checks, with the fix on its own path
    np.testing.assert_array_equal(back.gyr, np.degrees(rec.gyr))


def test_read_refuses_unknown_units_before_reading(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"mag_unit must be one of .*got 'gauss'"):
        io.read(tmp_path / "absent.h5", mag_unit="gauss")


def test_read_refuses_a_second_conversion_of_a_converted_file(tmp_path: Path) -> None:
    rec = _recording()
    converted = dataclasses.replace(rec, gyr=np.degrees(rec.gyr)).with_units(gyr="deg/s")
    io.write(converted, tmp_path / "r.h5")  # SI now, and its meta says so
    with pytest.raises(ValueError, match=r"r\.h5: gyr was already converted from deg/s"):
        io.read(tmp_path / "r.h5", gyr_unit="deg/s")
    np.testing.assert_array_equal(io.read(tmp_path / "r.h5").gyr, converted.gyr)


def test_read_passes_units_to_a_mapped_csv(tmp_path: Path) -> None:
    p = tmp_path / "log.csv"
    p.write_text(
        "time_ms,gx,gy,gz,ax,ay,az,mx,my,mz\n"
        "0,180,0,0,0,0,1,20000,0,-40000\n"
        "10,0,90,0,0,0,1,21000,0,-41000\n"
    )
    columns = {"t": "time_ms", "gyr": ["gx", "gy", "gz"], "acc": ["ax", "ay", "az"],
               "mag": ["mx", "my", "mz"]}
    rec = io.read(p, columns=columns, gyr_unit="deg/s", acc_unit="g", mag_unit="nT",
                  time_unit="ms")
    np.testing.assert_array_equal(rec.t, [0.0, 0.01])
    np.testing.assert_array_equal(rec.gyr[:, :2], [[np.pi, 0.0], [0.0, np.pi / 2]])
    np.testing.assert_array_equal(rec.acc[:, 2], [9.80665, 9.80665])
    np.testing.assert_array_equal(rec.mag, [[20.0, 0.0, -40.0], [21.0, 0.0, -41.0]])
    assert rec.meta["units"] == {"gyr": "deg/s", "acc": "g", "t": "ms", "mag": "nT"}
    assert rec.meta["units_converted"] == {"gyr": "deg/s", "acc": "g", "time": "ms", "mag": "nT"}
    # undeclared, the values come back as read (no magnitude check in io.read)
    raw = io.read(p, columns=columns)
    np.testing.assert_array_equal(raw.gyr[0], [180.0, 0.0, 0.0])
    # read_csv itself still checks, naming its keyword
    with pytest.raises(
        UnitError, match=r"log\.csv: gyr .*180\.0.*deg/s: pass gyr_unit='deg/s' to read_csv"
    ):
        io.read_csv(p, columns=columns)


XIO_HEADER = ("Timestamp (us),Gyroscope X (deg/s),Gyroscope Y (deg/s),Gyroscope Z (deg/s),"
              "Accelerometer X (g),Accelerometer Y (g),Accelerometer Z (g)")


def _xio_sensor(folder: Path) -> Path:
    folder.mkdir(parents=True)
    rows = [f"{20000 * i},{90 * i},0,0,0,0,1" for i in range(4)]
    (folder / "Inertial.csv").write_text("\n".join([XIO_HEADER, *rows]) + "\n")
    mag = [f"{20000 * i},0.2,0,-0.4" for i in range(4)]
    (folder / "Magnetometer.csv").write_text(
        "\n".join(["Timestamp (us),X (a.u.),Y (a.u.),Z (a.u.)", *mag]) + "\n")
    (folder / "Command.json").write_text(json.dumps([{"ping": {"name": "s1", "sn": "1"}}]))
    return folder


def test_xio_declarations_replace_the_defaults(tmp_path: Path) -> None:
    folder = _xio_sensor(tmp_path / "s")
    default = io.read(folder)
    np.testing.assert_array_equal(default.gyr[:, 0], [0.0, np.pi / 2, np.pi, 3 * np.pi / 2])
    np.testing.assert_array_equal(default.acc[:, 2], 9.80665)
    np.testing.assert_array_equal(default.t, [0.0, 0.02, 0.04, 0.06])
    assert default.meta["units_converted"] == {"gyr": "deg/s", "acc": "g", "time": "us"}
    # declaring the export's own units converts once, not twice
    same = io.read(folder, gyr_unit="deg/s", acc_unit="g", time_unit="us")
    np.testing.assert_array_equal(same.gyr, default.gyr)
    np.testing.assert_array_equal(same.acc, default.acc)
    np.testing.assert_array_equal(same.t, default.t)
    # another declaration replaces the default for the raw column
    other = io.read(folder, gyr_unit="rad/s", mag_unit="G")
    np.testing.assert_array_equal(other.gyr[:, 0], [0.0, 90.0, 180.0, 270.0])
    np.testing.assert_array_equal(other.mag[0], [20.0, 0.0, -40.0])
    assert other.meta["units"] == {"t": "us", "gyr": "rad/s", "acc": "g", "mag": "G"}
    assert other.meta["units_converted"] == {"acc": "g", "time": "us", "mag": "G"}
    # the Recording knows it was converted: a second conversion is refused
    with pytest.raises(ValueError, match="gyr was already converted from deg/s"):
        default.with_units(gyr="deg/s")
    # the reader used directly still checks what it converted, naming its keyword
    with pytest.raises(UnitError, match=r"deg/s: pass gyr_unit='deg/s' to read_xio_sensor"):
        io.read_xio_sensor(folder, gyr_unit="rad/s")


def test_read_any_declares_units_for_every_recording(tmp_path: Path) -> None:
    _xio_sensor(tmp_path / "body" / "a")
    _xio_sensor(tmp_path / "body" / "b")
    recs = io.read_any(tmp_path / "body", acc_unit="m/s2")
    assert [r.name for r in recs] == ["s1", "s1"]
    for r in recs:
        np.testing.assert_array_equal(r.acc[:, 2], 1.0)
        np.testing.assert_array_equal(r.gyr[1, 0], np.pi / 2)
