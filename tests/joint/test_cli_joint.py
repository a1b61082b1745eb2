"""`margtrack joint PARENT CHILD -o OUT` on small files written here, good and bad."""

from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest
from chain_sim import angle_deg, simulate_chain
from typer.testing import CliRunner

from margtrack import io
from margtrack.cli import app
from margtrack.estimator.flags import Flag

pytestmark = pytest.mark.kernel

runner = CliRunner()


def _invoke(*args):
    return runner.invoke(app, ["joint", *(str(a) for a in args)], env={"COLUMNS": "200"})


@pytest.fixture(scope="module")
def chain():
    return simulate_chain(duration_s=20, rate_hz=100, seed=4)


@pytest.fixture(scope="module")
def files(chain, tmp_path_factory):
    folder = tmp_path_factory.mktemp("joint")
    parent, child = folder / "thigh.h5", folder / "shank.csv"
    io.write(chain.parent, parent)
    io.write(chain.child, child)
    return parent, child


def test_joint_writes_the_relative_orientation_and_lever_arms_to_hdf5(files, chain, tmp_path):
    out = tmp_path / "knee.h5"
    result = _invoke(*files, "-o", out, "--offline")
    assert result.exit_code == 0, result.output
    assert "joint_offline: 2001 samples" in result.output
    assert "lever arm parent (estimated)" in result.output and "faults: 0 of" in result.output
    est = io.read_estimate(out)
    assert est.method == "joint_offline" and est.quat.shape == (2001, 4)
    np.testing.assert_allclose(est.t, chain.parent.t)
    assert np.sqrt(np.mean(angle_deg(est.quat, chain.q_rel) ** 2)) < 1.5
    arms = np.array(est.params["lever_arms_m"])
    assert np.abs(arms - chain.lever_arms_m).max() < 0.005
    assert est.params["lever_arms_source"] == "estimated"
    with h5py.File(out) as f:
        assert f["quat"].attrs["unit"] == "1" and f["flags"].dtype == np.uint16


def test_joint_writes_csv_and_takes_lever_arms_from_json(files, chain, tmp_path):
    arms = tmp_path / "arms.json"
    arms.write_text(json.dumps({"parent_m": chain.lever_arms_m[0].tolist(),
                                "child_m": chain.lever_arms_m[1].tolist()}))
    out = tmp_path / "knee.csv"
    result = _invoke(*files, "-o", out, "--lever-arms", arms)
    assert result.exit_code == 0, result.output
    assert "lever arm child (given): -10.0, 40.0, -150.0 mm" in result.output
    est = io.read_estimate(out)
    assert est.method == "joint_online" and est.flags.shape == (2001,)
    assert est.params["lever_arms_m"] == chain.lever_arms_m.tolist()
    assert np.sqrt(np.mean(angle_deg(est.quat, chain.q_rel)[500:] ** 2)) < 3.0
    # an earlier output gives its lever arms too
    again = _invoke(*files, "-o", tmp_path / "again.h5", "--lever-arms", out)
    assert again.exit_code == 0, again.output
    assert "lever arm parent (given): 20.0, -30.0, 180.0 mm" in again.output


def test_a_missing_file_is_named(files, tmp_path):
    result = _invoke(files[0], tmp_path / "nowhere.csv", "-o", tmp_path / "out.h5")
    assert result.exit_code == 2
    assert "no such file" in result.output and "nowhere.csv" in result.output
    assert not (tmp_path / "out.h5").exists()


def _plain_csv(rec, path, nan_rows=()):
    """A logger's table (time,gx,...,az), read through --column; ``nan_rows``: gyro lost."""
    table = np.column_stack([rec.t, rec.gyr, rec.acc])
    table[list(nan_rows), 1:4] = np.nan
    np.savetxt(path, table, delimiter=",", header="time,gx,gy,gz,ax,ay,az", comments="")


COLUMNS = ["--column", "t=time", "--column", "gyr=gx,gy,gz", "--column", "acc=ax,ay,az"]


def test_nan_rows_are_held_flagged_and_the_output_stays_aligned(chain, tmp_path):
    parent, child = tmp_path / "thigh.csv", tmp_path / "shank.csv"
    _plain_csv(chain.parent, parent)
    _plain_csv(chain.child, child, nan_rows=(300, 301))
    out = tmp_path / "knee.h5"
    result = _invoke(parent, child, "-o", out, *COLUMNS)
    assert result.exit_code == 0, result.output
    assert "not finite on 2 row(s), first at sample 300" in result.output
    assert "INVALID 2 (first at sample 300)" in result.output
    est = io.read_estimate(out)
    assert est.quat.shape == (2001, 4) and np.isfinite(est.quat).all()
    assert est.flags[300] & Flag.INVALID and est.flags[301] & Flag.INVALID
    assert np.sqrt(np.mean(angle_deg(est.quat, chain.q_rel)[500:] ** 2)) < 3.0


def test_nan_in_a_margtrack_file_is_refused_naming_the_sample(files, tmp_path):
    lines = files[1].read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("t"))
    cells = lines[header + 1 + 300].split(",")
    cells[1] = "nan"
    lines[header + 1 + 300] = ",".join(cells)
    broken = tmp_path / "shank_nan.csv"
    broken.write_text("\n".join(lines) + "\n")
    result = _invoke(files[0], broken, "-o", tmp_path / "out.h5")
    assert result.exit_code == 2 and "non-finite value (NaN or inf) at sample 300" in result.output


def test_a_gyroscope_in_deg_per_s_is_refused_with_the_option_to_declare_it(chain, tmp_path):
    wrong = tmp_path / "degs.h5"
    io.write(dataclasses.replace(chain.child, gyr=np.degrees(chain.child.gyr)), wrong)
    parent = tmp_path / "p.h5"
    io.write(chain.parent, parent)
    result = _invoke(parent, wrong, "-o", tmp_path / "out.h5")
    assert result.exit_code == 2
    assert "degs.h5" in result.output and "--gyr-unit deg/s" in result.output


def test_an_existing_output_is_kept_without_force(files, tmp_path):
    out = tmp_path / "knee.h5"
    out.write_text("keep me")
    result = _invoke(*files, "-o", out)
    assert result.exit_code == 2 and "already exists" in result.output
    assert "--force" in result.output and out.read_text() == "keep me"
    forced = _invoke(*files, "-o", out, "--force")
    assert forced.exit_code == 0, forced.output
    assert io.read_estimate(out).quat.shape == (2001, 4)


def test_the_output_may_not_be_an_input(files):
    result = _invoke(*files, "-o", files[1], "--force")
    assert result.exit_code == 2 and "would destroy the recording" in result.output


def test_a_clock_going_back_is_refused_with_its_sample(files, tmp_path):
    lines = files[1].read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("t"))
    row = lines[header + 1 + 50].split(",")
    row[0] = "0.2"  # sample 50 at 0.2 s, after 0.49 s
    lines[header + 1 + 50] = ",".join(row)
    back = tmp_path / "back.csv"
    back.write_text("\n".join(lines) + "\n")
    result = _invoke(files[0], back, "-o", tmp_path / "out.h5")
    assert result.exit_code == 2 and "non-monotonic timestamp at sample 50" in result.output


def test_recordings_that_do_not_overlap_are_refused_with_the_fix(chain, tmp_path):
    later = tmp_path / "later.h5"
    io.write(dataclasses.replace(chain.child, t=chain.child.t + 60.0), later)
    parent = tmp_path / "p.h5"
    io.write(chain.parent, parent)
    result = _invoke(parent, later, "-o", tmp_path / "out.h5")
    assert result.exit_code == 2
    assert "share no common time span" in result.output and "--align-start" in result.output
    ok = _invoke(parent, later, "-o", tmp_path / "out.h5", "--align-start")
    assert ok.exit_code == 0, ok.output


def test_a_shorter_child_is_cropped_with_a_note(chain, tmp_path):
    short = tmp_path / "short.h5"
    io.write(chain.child.slice(0, 1200), short)
    parent = tmp_path / "p.h5"
    io.write(chain.parent, parent)
    result = _invoke(parent, short, "-o", tmp_path / "out.h5")
    assert result.exit_code == 0, result.output
    assert "left out: parent 8.01 s" in result.output
    assert io.read_estimate(tmp_path / "out.h5").quat.shape == (1200, 4)


def test_bad_parameters_name_the_valid_ones(files, tmp_path):
    result = _invoke(*files, "-o", tmp_path / "out.h5", "-p", "gain=3")
    assert result.exit_code == 2 and "link_noise_m_s2" in result.output
    fine = _invoke(*files, "-o", tmp_path / "out.h5", "-p", "link_noise_m_s2=0.8")
    assert fine.exit_code == 0, fine.output
    assert io.read_estimate(tmp_path / "out.h5").params["link_noise_m_s2"] == 0.8
