"""Estimate files say what they hold: frame, method, parameters and units (CSV and HDF5)."""

from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest

from margtrack import frames, io, methods, sim
from margtrack.io.estimate_csv import write_estimate_csv
from margtrack.io.estimate_writer import EstimateWriter
from margtrack.io.output_units import output_unit


@pytest.fixture(scope="module")
def run():
    """A 3 s robust run in NED (so a reader that assumed ENU would be caught)."""
    rec = sim.simulate_motion("random", duration_s=3.0, rate_hz=100.0, seed=8, frame="NED")
    est = methods.create("robust", {"frame": "NED"}).run(rec)
    assert est.frame == "NED"
    return est


def test_units_from_names_by_hand():
    expected = {
        ("t_s", np.float64): "s", ("quat", np.float64): "1", ("flags", np.uint16): "bits",
        ("gyr_bias_rad_s", np.float64): "rad/s", ("lin_acc_earth_m_s2", np.float64): "m/s^2",
        ("euler_rad", np.float64): "rad", ("gyr_bias_sd_rad_s", np.float64): "rad/s",
        ("cov_diag", np.float64): "mixed", ("new_correction", np.bool_): "0/1",
        ("iterations", np.int32): "1", ("phi", np.float64): "1",
        ("bias_var_rad2_s2", np.float64): "rad^2/s^2", ("tau_s", np.float64): "s",
        ("mystery", np.float64): "unstated",
    }
    for (name, dtype), unit in expected.items():
        assert output_unit(name, dtype) == unit, name


@pytest.mark.parametrize("frame", ["NED", "ENU"])
def test_csv_states_frame_method_params_and_units_and_reads_them_back(run, tmp_path, frame):
    est = run.in_frame(frame)
    path = tmp_path / f"{frame}.csv"
    io.write_estimate(est, path)
    lines = path.read_text().splitlines()
    assert lines[0] == f"# margtrack-estimate v1 method=robust frame={frame} " \
                       "quat=[w,x,y,z] body-to-earth"
    assert json.loads(lines[1].removeprefix("# params=")) == json.loads(json.dumps(est.params))
    assert lines[2].startswith("# units t_s=s quat_w=1 quat_x=1 quat_y=1 quat_z=1 ")
    assert "gyr_bias_rad_s_z=rad/s" in lines[2] and lines[2].endswith("flags=bits")
    got = io.read_estimate(path)
    assert got.frame == frame and got.method == "robust"
    assert got.params == json.loads(json.dumps(est.params))
    assert got.units["gyr_bias_sd_rad_s_x"] == "rad/s" and got.units["quat6d_0"] == "1"
    back = got.estimate()  # no frame needed: the file says it
    assert back.frame == frame
    np.testing.assert_array_equal(back.quat, est.quat)  # exact: repr floats
    np.testing.assert_array_equal(back.flags, est.flags)
    # the orientation really is in that frame: converting back gives the NED run
    # (q and -q are one orientation)
    dots = np.abs(np.sum(frames.convert(back.quat, frame, "NED") * run.quat, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-12)
    # plain readers read the table below the four header lines
    table = np.loadtxt(path, delimiter=",", skiprows=4)
    np.testing.assert_array_equal(table[:, 1:5], est.quat)


def test_an_old_csv_without_the_header_still_reads(run, tmp_path):
    path = tmp_path / "new.csv"
    io.write_estimate(run, path)
    old = tmp_path / "old.csv"
    old.write_text("".join(x for x in path.read_text().splitlines(keepends=True)
                           if not x.startswith("#")))
    assert io.is_estimate_file(old)
    got = io.read_estimate(old)
    assert got.frame is None and got.method is None and got.params == {} and got.units == {}
    np.testing.assert_array_equal(got.quat, run.quat)
    with pytest.raises(ValueError, match=r"does not say its earth frame.*--frame ENU"):
        got.estimate()
    assert got.estimate("NED").frame == "NED"
    with pytest.raises(ValueError, match="says its frame is NED, not ENU"):
        io.read_estimate(path).estimate("ENU")


def test_hdf5_datasets_carry_a_unit(run, tmp_path):
    streamed, direct = tmp_path / "s.h5", tmp_path / "d.h5"
    io.write_estimate(run, streamed)
    from margtrack.io.estimate_writer import estimate_fields

    outputs, attrs = estimate_fields(run)
    io.write_estimate_hdf5(direct, run.t, run.quat, outputs, attrs)
    for path in (streamed, direct):
        with h5py.File(path) as f:
            units = {k: f[k].attrs["unit"] for k in f}
        assert units == {"t": "s", "quat": "1", "quat6d": "1", "gyr_bias_rad_s": "rad/s",
                         "gyr_bias_sd_rad_s": "rad/s", "mag_offset_ut": "uT", "flags": "bits"}
        assert io.read_estimate(path).units == units


def test_bad_headers_and_names_are_refused(run, tmp_path):
    path = tmp_path / "e.csv"
    io.write_estimate(run, path)
    lines = path.read_text().splitlines(keepends=True)
    bad_params = tmp_path / "params.csv"
    bad_params.write_text(lines[0] + "# params={not json\n" + "".join(lines[2:]))
    with pytest.raises(ValueError, match=r"params\.csv: the '# params=' line is not a JSON"):
        io.read_estimate(bad_params)
    bad_frame = tmp_path / "frame.csv"
    bad_frame.write_text(lines[0].replace("frame=NED", "frame=XYZ") + "".join(lines[1:]))
    with pytest.raises(ValueError, match=r"frame\.csv: its header says frame=XYZ"):
        io.read_estimate(bad_frame)
    t, q = run.t[:3], run.quat[:3]
    with pytest.raises(ValueError, match="method name 'my filter' has a space"):
        write_estimate_csv(tmp_path / "m.csv", t, q, method="my filter")
    with pytest.raises(ValueError, match="frame must be 'NED' or 'ENU'"):
        write_estimate_csv(tmp_path / "m.csv", t, q, frame="XYZ")
    with pytest.raises(ValueError, match="without commas, spaces, '='"):
        write_estimate_csv(tmp_path / "m.csv", t, q, {"a=b": t})
    assert not (tmp_path / "m.csv").exists()


def test_chunks_of_another_run_are_refused(run, tmp_path):
    first = dataclasses.replace(
        run, t=run.t[:100], quat=run.quat[:100], flags=run.flags[:100],
        outputs={k: v[:100] for k, v in run.outputs.items()},
    )
    rest = dataclasses.replace(
        run, t=run.t[100:], quat=run.quat[100:], flags=run.flags[100:],
        outputs={k: v[100:] for k, v in run.outputs.items()},
        params={**run.params, "gain": 0.5},
    )
    out = tmp_path / "mixed.csv"
    with pytest.raises(ValueError, match="another method, frame or parameters"):
        with EstimateWriter(out) as writer:
            writer.append(first)
            writer.append(rest)
    assert not out.exists()  # nothing half-written
