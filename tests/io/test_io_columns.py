"""Any table in: delimiter and decimal sniffing, column maps, bad lines, holes, DataFrames."""

from __future__ import annotations

import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

import margtrack as mt
from margtrack import io
from margtrack.estimator import Estimate, Flag
from margtrack.io.csv_layout import column_flags, guess_columns, sniff

ROWS = [  # t_ms, gx gy gz (deg/s), ax ay az (g): known values, converted by hand below
    [0.0, 180.0, 0.0, -90.0, 0.0, 0.0, 1.0],
    [10.0, 0.0, 360.0, 1.0, 0.5, 0.0, 1.0],
    [20.0, 0.5, 0.25, 0.0, 0.0, -0.5, 1.0],
    [30.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
]
HEADER = ["time", "gx", "gy", "gz", "ax", "ay", "az"]
COLS = {"t": "time", "gyr": "gx,gy,gz", "acc": ["ax", "ay", "az"]}
UNITS = {"time_unit": "ms", "gyr_unit": "deg/s", "acc_unit": "g"}


def _table(path: Path, delim: str = ",", decimal: str = ".", rows=ROWS, header=HEADER) -> Path:
    lines = [delim.join(header)]
    for row in rows:
        lines.append(delim.join(repr(float(v)).replace(".", decimal) for v in row))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _check_values(rec: mt.Recording) -> None:
    np.testing.assert_allclose(rec.t, [0.0, 0.01, 0.02, 0.03], rtol=0, atol=1e-15)
    np.testing.assert_allclose(rec.gyr[0], [np.pi, 0.0, -np.pi / 2], rtol=1e-15)
    np.testing.assert_allclose(rec.gyr[1], [0.0, 2 * np.pi, np.pi / 180], rtol=1e-15)
    np.testing.assert_allclose(rec.acc[1], [0.5 * 9.80665, 0.0, 9.80665], rtol=1e-15)


@pytest.mark.parametrize(
    ("delim", "decimal", "suffix"),
    [(",", ".", ".csv"), (";", ",", ".csv"), ("\t", ".", ".tsv"), ("\t", ",", ".txt"),
     ("   ", ".", ".txt"), (";", ".", ".csv")],
)
def test_layouts_are_detected_and_read_the_same(tmp_path, delim, decimal, suffix):
    p = _table(tmp_path / f"log{suffix}", delim, decimal)
    table = sniff(p)
    assert table.header == HEADER
    assert table.decimal == decimal
    assert table.delimiter == (None if delim.isspace() and delim != "\t" else delim)
    rec = io.read(p, columns=COLS, **UNITS)
    _check_values(rec)


def test_forced_layout_and_a_contradiction(tmp_path):
    p = _table(tmp_path / "x.csv", ";", ",")
    rec = io.read(p, columns=COLS, delimiter=";", decimal=",", **UNITS)
    _check_values(rec)
    with pytest.raises(ValueError, match="both the delimiter and the decimal separator"):
        io.read(p, columns=COLS, delimiter=",", decimal=",", **UNITS)


def test_a_malformed_line_is_named(tmp_path):
    p = _table(tmp_path / "bad.csv")
    text = p.read_text().splitlines()
    text[2] = "10.0,0.0,360.0"  # line 3 of the file lost four fields, mid-file
    p.write_text("\n".join(text) + "\n")
    with pytest.raises(ValueError, match=r"bad\.csv: line 3 has 3 fields but the header has 7"):
        io.read(p, columns=COLS, **UNITS)


def test_a_non_number_names_line_and_column(tmp_path):
    p = _table(tmp_path / "bad.csv")
    p.write_text(p.read_text().replace("360.0", "36O.0"))
    with pytest.raises(ValueError, match=r"columns \['gy'\] on line 3: '36O\.0' is not a number"):
        io.read(p, columns=COLS, **UNITS)


def test_a_truncated_last_line_is_left_out_with_a_warning(tmp_path):
    p = _table(tmp_path / "cut.csv")
    p.write_text(p.read_text() + "40.0,1.0,2")  # the logger stopped mid-line, no newline
    with pytest.warns(UserWarning, match=r"cut\.csv: line 6 is truncated \(3 of 7 fields"):
        rec = io.read(p, columns=COLS, **UNITS)
    assert rec.n_samples == 4 and rec.meta["dropped_lines"] == [6]
    _check_values(rec)


def test_an_empty_gyro_cell_is_held_and_flagged_not_fatal(tmp_path):
    p = _table(tmp_path / "hole.csv")
    lines = p.read_text().splitlines()
    lines[3] = "20.0,,0.25,0.0,0.0,-0.5,1.0"  # sample 2 (file line 4): gx empty
    p.write_text("\n".join(lines) + "\n")
    with pytest.warns(UserWarning, match=r"gyr is empty or not finite on 1 row.*sample 2.*line 4"):
        rec = io.read(p, columns=COLS, **UNITS)
    np.testing.assert_array_equal(rec.gyr[2], rec.gyr[1])  # held from the previous sample
    assert rec.meta["invalid_samples"] == {"gyr": [2]}
    est = Estimate(t=rec.t, quat=np.tile([1.0, 0, 0, 0], (4, 1)), method="x", frame="ENU",
                   params={}, flags=np.zeros(4, np.uint16))
    flagged = io.flag_invalid(est, rec)
    assert flagged.flags.tolist() == [0, 0, int(Flag.INVALID), 0]
    # a chunk starting at sample 2 of the same recording gets the flag on its first sample
    chunk = rec.slice(2, 4)
    est2 = Estimate(t=chunk.t, quat=est.quat[2:], method="x", frame="ENU", params={},
                    flags=np.zeros(2, np.uint16))
    assert io.flag_invalid(est2, chunk, start=2).flags.tolist() == [int(Flag.INVALID), 0]


def test_every_value_empty_is_refused(tmp_path):
    rows = [[r[0], np.nan, np.nan, np.nan, *r[4:]] for r in ROWS]
    p = _table(tmp_path / "nogyr.csv", rows=rows)
    with pytest.raises(ValueError, match="gyr has no usable sample"):
        io.read(p, columns=COLS, **UNITS)


def test_non_monotonic_time_names_sample_and_line(tmp_path):
    rows = [list(r) for r in ROWS]
    rows[2][0] = 5.0  # goes back from 10 ms to 5 ms at sample 2 (file line 4)
    p = _table(tmp_path / "back.csv", rows=rows)
    with pytest.raises(ValueError, match=r"non-monotonic timestamp at sample 2.*line 4 of the"):
        io.read(p, columns=COLS, **UNITS)


def test_unknown_column_lists_the_file_columns_and_the_flags(tmp_path):
    p = _table(tmp_path / "x.csv", ";", ",")
    with pytest.raises(ValueError) as info:
        io.read(p, columns={**COLS, "gyr": "gyro_x,gy,gz"}, **UNITS)
    text = str(info.value)
    assert "no column 'gyro_x'; the file has columns ['time', 'gx'" in text
    assert "columns={'t': 'time', 'acc': ['ax', 'ay', 'az'], 'gyr': ['gx', 'gy', 'gz']}" in text
    cli = info.value.cli_fix  # what the command line says instead of the Python keyword
    assert "--column gyr=gx,gy,gz" in cli and "--column t=time" in cli


def test_a_foreign_table_without_a_map_gets_the_flags_not_a_stray_brace(tmp_path):
    p = _table(tmp_path / "phone.csv", ";", ",", header=["time_ms", "gyr_x", "gyr_y", "gyr_z",
                                                         "acc_x", "acc_y", "acc_z"])
    with pytest.raises(ValueError) as info:
        io.read(p)
    text = str(info.value)
    assert "the file has columns ['time_ms', 'gyr_x'" in text  # split at ';', not one name
    assert ("--column t=time_ms --column gyr=gyr_x,gyr_y,gyr_z --column acc=acc_x,acc_y,acc_z"
            " --time-unit ms") in info.value.cli_fix
    assert "time_unit='ms'" in text
    assert "}}" not in text and "read_csv(path, columns={'t': [...]" not in text


@pytest.mark.parametrize(
    ("header", "expected"),
    [
        (["t", "gx", "gy", "gz", "ax", "ay", "az"],
         {"t": ["t"], "gyr": ["gx", "gy", "gz"], "acc": ["ax", "ay", "az"]}),
        (["timestamp", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z", "mag_x",
          "mag_y", "mag_z"],
         {"t": ["timestamp"], "gyr": ["gyro_x", "gyro_y", "gyro_z"],
          "acc": ["accel_x", "accel_y", "accel_z"], "mag": ["mag_x", "mag_y", "mag_z"]}),
        (["Time (s)", "Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)"],
         {"t": ["Time (s)"], "gyr": ["Gyroscope x (rad/s)", "Gyroscope y (rad/s)",
                                     "Gyroscope z (rad/s)"]}),
        (["GYR_X_DEG_S", "GYR_Y_DEG_S", "GYR_Z_DEG_S", "qw", "qx", "qy", "qz"],
         {"gyr": ["GYR_X_DEG_S", "GYR_Y_DEG_S", "GYR_Z_DEG_S"],
          "quat_true": ["qw", "qx", "qy", "qz"]}),
        (["a", "b", "c"], {}),
    ],
)
def test_guessed_column_maps(header, expected):
    assert guess_columns(header) == expected


def test_flags_quote_names_with_spaces():
    text = column_flags({"t": ["Time (s)"], "gyr": ["gx", "gy", "gz"]}, {"gyr": "deg/s"})
    assert text == '--column "t=Time (s)" --column gyr=gx,gy,gz --gyr-unit deg/s'


# --- truth with holes -----------------------------------------------------------------


def _truth_rec(n: int = 50) -> mt.Recording:
    rng = np.random.default_rng(4)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q[[0, 7, 8, 30]] = np.nan  # the markers were lost
    q[12, 2] = np.nan  # one component missing is a hole too
    return mt.Recording(t=np.arange(n) / 100.0, gyr=np.zeros((n, 3)),
                        acc=np.tile([0.0, 0.0, 9.81], (n, 1)), quat_true=q)


def test_truth_holes_are_accepted_and_kept(tmp_path):
    rec = _truth_rec()
    holes = ~rec.truth_valid
    assert np.flatnonzero(holes).tolist() == [0, 7, 8, 12, 30]
    assert np.isnan(rec.quat_true[12]).all()  # a partial row becomes a whole hole
    for name in ("r.h5", "r.csv"):  # margtrack's own formats keep the holes
        io.write(rec, tmp_path / name)
        back = io.read(tmp_path / name)
        np.testing.assert_array_equal(np.isnan(back.quat_true), np.isnan(rec.quat_true))
        np.testing.assert_allclose(back.quat_true[~holes], rec.quat_true[~holes], atol=1e-15)
    with h5py.File(tmp_path / "r.h5") as f:
        assert np.isnan(f["quat_true"][0]).all()


def test_infinite_truth_is_refused():
    rec = _truth_rec()
    q = rec.quat_true.copy()
    q[3, 1] = np.inf
    with pytest.raises(ValueError, match=r"quat_true has an infinite value at sample 3.*NaN"):
        mt.Recording(t=rec.t, gyr=rec.gyr, acc=rec.acc, quat_true=q)


def test_metrics_skip_truth_holes_exactly():
    rec = _truth_rec()
    rng = np.random.default_rng(5)
    est = mt.quaternion.normalize(np.nan_to_num(rec.quat_true, nan=0.5)
                                  + rng.normal(scale=0.02, size=rec.quat_true.shape))
    series = mt.error_series(est, rec.quat_true)
    assert np.isnan(series.total_rad[[0, 7, 8, 12, 30]]).all()
    known = rec.truth_valid
    oracle = mt.summarize(mt.error_series(est[known], rec.quat_true[known]))
    got = mt.summarize(series)
    assert got.n_samples == 45 == oracle.n_samples
    assert got.total_rmse_deg == pytest.approx(oracle.total_rmse_deg, rel=1e-14)
    mask = np.arange(50) % 2 == 0  # movement mask and holes together
    both = mt.summarize(series, mask)
    sub = mt.summarize(mt.error_series(est[known & mask], rec.quat_true[known & mask]))
    assert both.n_samples == int(np.sum(known & mask))
    assert both.heading_rmse_deg == pytest.approx(sub.heading_rmse_deg, rel=1e-14)
    with pytest.raises(ValueError, match="truth is missing"):
        mt.summarize(mt.error_series(est[[0]], rec.quat_true[[0]]))


def test_mapped_truth_with_empty_cells(tmp_path):
    header = [*HEADER, "qw", "qx", "qy", "qz"]
    rows = [[*r, 1.0, 0.0, 0.0, 0.0] for r in ROWS]
    rows[1][-4:] = [np.nan] * 4
    p = _table(tmp_path / "truth.csv", rows=rows, header=header)
    p.write_text(p.read_text().replace("nan", ""))  # empty cells, as a spreadsheet writes
    rec = io.read(p, columns={**COLS, "quat_true": "qw,qx,qy,qz"}, **UNITS)
    assert rec.truth_valid.tolist() == [True, False, True, True]
    assert "invalid_samples" not in rec.meta  # truth holes are not signal holes


# --- DataFrames and resample -----------------------------------------------------------


def test_from_dataframe_guesses_and_converts():
    pd = pytest.importorskip("pandas", reason="pandas is optional")
    arr = np.array(ROWS)
    df = pd.DataFrame(arr, columns=["time_ms", "gx", "gy", "gz", "ax", "ay", "az"])
    rec = io.from_dataframe(df, time_unit="ms", gyr_unit="deg/s", acc_unit="g")
    _check_values(rec)
    with pytest.raises(ValueError, match=r"gyr_unit='deg/s' to from_dataframe"):
        io.from_dataframe(df, time_unit="ms", acc_unit="g")
    df2 = df.drop(columns=["time_ms"])
    df2.index = pd.to_datetime(np.array([0, 10, 20, 30]) * 1_000_000 + 10**18, unit="ns")
    rec2 = io.from_dataframe(df2, gyr_unit="deg/s", acc_unit="g")
    np.testing.assert_allclose(rec2.t, rec.t, atol=1e-15)
    assert rec2.meta["t0_ns"] == 10**18
    with pytest.raises(ValueError, match=r"cannot tell the DataFrame's gyr and acc.*\['u', 'v'"):
        io.from_dataframe(pd.DataFrame({"u": [1.0], "v": [2.0]}))


def test_from_dataframe_nan_gyro_is_held():
    pd = pytest.importorskip("pandas", reason="pandas is optional")
    arr = np.array(ROWS)
    arr[3, 2] = np.nan
    df = pd.DataFrame(arr, columns=HEADER)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = io.from_dataframe(df, COLS, time_unit="ms", gyr_unit="deg/s", acc_unit="g")
    assert any("gyr is empty or not finite" in str(w.message) for w in caught)
    assert rec.meta["invalid_samples"] == {"gyr": [3]}
    np.testing.assert_array_equal(rec.gyr[3], rec.gyr[2])


def test_resample_is_public_and_linear():
    out = mt.resample([0.0, 1.0, 3.0], [[0.0, 10.0], [2.0, 10.0], [6.0, 0.0]],
                      [-1.0, 0.5, 2.0, 9.0])
    np.testing.assert_allclose(out, [[0.0, 10.0], [1.0, 10.0], [4.0, 5.0], [6.0, 0.0]])
    assert "resample" in mt.__all__


def test_from_dataframe_bad_input():
    pd = pytest.importorskip("pandas", reason="pandas is optional")
    df = pd.DataFrame(np.array(ROWS), columns=HEADER)
    with pytest.raises(ValueError, match=r"no column 'wx'; it has columns \['time', 'gx'"):
        io.from_dataframe(df, {**COLS, "gyr": "wx,wy,wz"}, time_unit="ms")
    back = df.copy()
    back.loc[2, "time"] = 5.0
    with pytest.raises(ValueError, match=r"DataFrame: non-monotonic timestamp at sample 2"):
        io.from_dataframe(back, COLS, time_unit="ms", gyr_unit="deg/s", acc_unit="g")
    text = df.astype(object)
    text.loc[1, "gx"] = "fast"
    with pytest.raises(ValueError, match=r"DataFrame columns \['gx', 'gy', 'gz'\] are not numeric"):
        io.from_dataframe(text, COLS, time_unit="ms", gyr_unit="deg/s", acc_unit="g")
    with pytest.raises(TypeError, match="needs a pandas DataFrame, got ndarray"):
        io.from_dataframe(np.array(ROWS))
