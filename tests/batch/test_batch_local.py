"""margtrack batch in this process and on an embedded LocalCluster of 2 worker processes.

The oracle is the one runner on the whole recording: every output must hold exactly what
``methods.create(...).run(recording)`` gives, and every summary row its figures.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from margtrack import io, methods, sim
from margtrack.batch import BatchConfig, Pool, open_pool, run_batch
from margtrack.batch.cluster import mapper_of
from margtrack.batch.summary import COLUMNS, read_summary_csv
from margtrack.bench.runner import evaluate
from margtrack.bench.tune import tune
from margtrack.cli import app
from margtrack.estimator.flags import FAULT_FLAGS, Flag

runner = CliRunner()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """Three short simulated recordings (one with a gap), two bad files."""
    root = tmp_path_factory.mktemp("inputs")
    a = sim.simulate_motion("random", duration_s=8, rate_hz=100, seed=1)
    b = sim.simulate_motion("limb", duration_s=6, rate_hz=100, seed=2)
    c = sim.simulate_motion("random", duration_s=5, rate_hz=100, seed=3)
    t = c.t.copy()
    t[300:] += 2.0  # a 2 s gap
    c = dataclasses.replace(c, t=t, name="c")
    io.write(a, root / "a.h5")
    io.write(b, root / "b.csv")
    (root / "sub").mkdir()
    io.write(c, root / "sub" / "c.h5")
    (root / "corrupt.h5").write_bytes((root / "a.h5").read_bytes()[:3000])  # truncated
    (root / "foreign.csv").write_text("time,x,y\n1,2,3\n")  # not a margtrack CSV
    lines = (root / "b.csv").read_text().splitlines()
    lines[50], lines[51] = lines[51], lines[50]  # a clock going back
    (root / "clock.csv").write_text("\n".join(lines) + "\n")
    return root


def _args(root: Path) -> list[str]:
    return [str(root / "a.h5"), str(root / "b.csv"), str(root / "sub"),
            str(root / "corrupt.h5"), str(root / "foreign.csv"), str(root / "clock.csv")]


def _read_out(path: str) -> tuple[np.ndarray, np.ndarray]:
    with h5py.File(path) as f:
        return f["quat"][:], f["flags"][:]


def _check_against_the_runner(result, root: Path, method: str = "robust") -> None:
    rows = {Path(r["file"]).name: r for r in result.rows}
    for name in ("a.h5", "b.csv", "c.h5"):
        row = rows[name]
        assert row["status"] == "done", row
        rec = io.read(next(root.rglob(name)))
        est = methods.create(method).run(rec)
        quat, flags = _read_out(row["output"])
        np.testing.assert_allclose(quat, est.quat, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(flags, est.flags)
        trial = evaluate(methods.create(method), rec)
        assert row["total_rmse_deg"] == pytest.approx(trial.total_rmse_deg, rel=1e-9)
        assert row["heading_rmse_deg"] == pytest.approx(trial.heading_rmse_deg, rel=1e-9)
        assert row["samples"] == rec.n_samples
        assert row["fault_samples"] == np.count_nonzero(est.flags & FAULT_FLAGS)
        assert row["rest_samples"] == np.count_nonzero(est.flags & Flag.REST)
        assert row["gaps"] == np.count_nonzero(est.flags & Flag.GAP)
    assert rows["c.h5"]["gaps"] == 1 and rows["c.h5"]["fault_samples"] >= 1
    assert rows["corrupt.h5"]["status"] == "failed"
    assert "corrupt.h5" in rows["corrupt.h5"]["error"]
    assert rows["corrupt.h5"]["method"] == method  # "default" resolved
    assert rows["foreign.csv"]["status"] == "failed"
    assert "not a margtrack CSV" in rows["foreign.csv"]["error"]
    assert rows["clock.csv"]["status"] == "failed"
    assert "clock.csv: non-monotonic timestamp at sample" in rows["clock.csv"]["error"]


def test_in_process_batch_equals_the_runner_and_reruns_skip(inputs, tmp_path):
    out = tmp_path / "out"
    seen = []
    result = run_batch(_args(inputs), out, progress=lambda row, k, n: seen.append((k, n)))
    assert result.where == "in-process"
    assert seen == [(k, 6) for k in range(1, 7)]
    assert result.counts() == {"done": 3, "skipped": 0, "failed": 3}
    _check_against_the_runner(result, inputs)
    # the summary files hold the same rows, in input order, every column
    assert read_summary_csv(result.summary_csv) == [
        {c: r.get(c) for c in COLUMNS} for r in result.rows
    ]
    import pyarrow.parquet as pq

    table = pq.read_table(result.summary_parquet).to_pylist()
    assert [r["status"] for r in table] == ["done"] * 3 + ["failed"] * 3
    assert table[0]["total_rmse_deg"] == result.rows[0]["total_rmse_deg"]

    outputs = sorted(p.name for p in out.glob("*.h5"))
    assert outputs == ["a.h5", "b.h5", "c.h5"]
    mtimes = {p: p.stat().st_mtime_ns for p in out.glob("*.h5")}
    again = run_batch(_args(inputs), out)
    assert again.counts() == {"done": 0, "skipped": 3, "failed": 3}
    assert {p: p.stat().st_mtime_ns for p in out.glob("*.h5")} == mtimes  # nothing rewritten
    skipped = {Path(r["file"]).name: r for r in again.rows}
    assert skipped["a.h5"]["total_rmse_deg"] == result.rows[0]["total_rmse_deg"]

    # other parameters: every output is redone; --force: redone even when current
    other = run_batch(_args(inputs), out, BatchConfig(params=("tau_acc_s=2",)))
    assert other.counts()["done"] == 3
    assert run_batch(_args(inputs), out, BatchConfig(params=("tau_acc_s=2",)), force=True
                     ).counts()["done"] == 3


def test_a_changed_input_is_redone_and_a_foreign_output_is_kept(inputs, tmp_path):
    root = tmp_path / "in"
    root.mkdir()
    rec = sim.simulate_motion("random", duration_s=4, rate_hz=100, seed=5)
    io.write(rec, root / "x.h5")
    io.write(rec.slice(0, 200), root / "y.h5")
    out = tmp_path / "out"
    out.mkdir()
    (out / "y.h5").write_text("someone else's file")
    result = run_batch([root], out)
    rows = {Path(r["file"]).name: r for r in result.rows}
    assert rows["x.h5"]["status"] == "done"
    assert rows["y.h5"]["status"] == "failed"
    assert "was kept: pass --force" in rows["y.h5"]["error"]
    assert (out / "y.h5").read_text() == "someone else's file"
    # the input changes (rewritten): only it is redone, and a killed writer's temp goes
    io.write(rec.slice(0, 300), root / "x.h5")
    (out / ".x.h5.tmp-0badf00d").write_text("half a file")
    again = run_batch([root], out, force=False)
    assert [r["status"] for r in again.rows] == ["done", "failed"]
    assert again.rows[0]["samples"] == 300
    assert not (out / ".x.h5.tmp-0badf00d").exists()
    forced = run_batch([root], out, force=True)
    assert [r["status"] for r in forced.rows] == ["done", "done"]
    record = json.loads((out / ".margtrack-batch" / "y.h5.json").read_text())
    assert record["status"] == "done" and len(record["key"]) == 64


def test_usage_errors_come_before_any_work(inputs, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(ValueError, match="unknown method 'nope'"):
        run_batch(_args(inputs), out, BatchConfig(method="nope"))
    with pytest.raises(ValueError, match="unknown parameter"):
        run_batch(_args(inputs), out, BatchConfig(params=("nope=1",)))
    with pytest.raises(ValueError, match="frame"):
        run_batch(_args(inputs), out, BatchConfig(frame="XYZ"))
    (tmp_path / "cal.json").write_text('{"x": 1')
    with pytest.raises(ValueError, match=r"cal\.json is not valid JSON"):
        run_batch(_args(inputs), out, BatchConfig(calibration=str(tmp_path / "cal.json")))
    with pytest.raises(ValueError, match="chunk_samples must be 1 or more"):
        run_batch(_args(inputs), out, BatchConfig(chunk_samples=0))
    assert not out.exists()
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match="is a file"):
        run_batch(_args(inputs), tmp_path / "file")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        run_batch(_args(inputs), tmp_path / "no" / "such")
    with pytest.raises(ValueError, match="workers must be 1 or more"), open_pool(0):
        pass
    with pytest.raises(ValueError, match="--workers applies to the embedded cluster"), \
            open_pool(2, "tcp://127.0.0.1:1"):
        pass


def test_cli_exit_codes_and_summary_line(inputs, tmp_path):
    out = tmp_path / "out"
    result = runner.invoke(app, ["batch", *_args(inputs), "-o", str(out), "--workers", "1"])
    assert result.exit_code == 1, result.output
    assert "6 recordings: 3 done, 0 skipped, 3 failed" in result.output
    assert "3 of 6 recordings failed" in result.output
    good = [str(inputs / "a.h5"), str(inputs / "sub")]
    result = runner.invoke(app, ["batch", *good, "-o", str(out), "--workers", "1"])
    assert result.exit_code == 0, result.output
    assert "2 recordings: 0 done, 2 skipped, 0 failed" in result.output
    result = runner.invoke(app, ["batch", str(inputs / "nothing*.h5"), "-o", str(out)])
    assert result.exit_code == 2
    assert "matched no file" in result.output
    result = runner.invoke(app, ["batch", *good, "-o", str(out), "-m", "nope"])
    assert result.exit_code == 2 and "unknown method 'nope'" in result.output
    # tune takes the same --workers / --scheduler
    tune_args = ["tune", str(inputs / "a.h5"), "-m", "robust", "-g", "tau_acc_s=1,4"]
    result = runner.invoke(app, [*tune_args, "--workers", "1"])
    assert result.exit_code == 0, result.output
    assert "best 2 of 2" in result.output
    result = runner.invoke(app, [*tune_args, "--workers", "2", "--scheduler", "tcp://x:1"])
    assert result.exit_code == 2 and "--workers applies to the embedded cluster" in result.output


def test_pool_in_process_reports_errors_per_job():
    def job(shared, item):
        if item == 2:
            raise RuntimeError("two")
        return shared + item

    got = list(Pool(None, "in-process").map(job, [1, 2, 3], 10))
    assert [(i, r) for i, r, e in got] == [(0, 11), (1, None), (2, 13)]
    assert str(got[1][2]) == "two"


def test_embedded_local_cluster_equals_in_process(inputs, tmp_path):
    here = run_batch(_args(inputs), tmp_path / "here")
    recs = [(io.read(inputs / "a.h5"), ("all",)), (io.read(inputs / "b.csv"), ("all",))]
    grid = {"tau_acc_s": ["0.5", "2", "8"]}
    tuned_here = tune("robust", grid, recs)
    with open_pool(2) as pool:
        assert pool.description == "local Dask cluster, 2 worker processes"
        assert pool.n_workers == 2
        there = run_batch(_args(inputs), tmp_path / "there", pool=pool)
        # margtrack tune's grid on the same workers: the same ranking and figures
        told = []
        tuned_there = tune("robust", grid, recs, mapper=mapper_of(pool), progress=told.append)
    assert sorted(told) == ["tau_acc_s=0.5", "tau_acc_s=2", "tau_acc_s=8"]
    assert [r.params for r in tuned_there.results] == [r.params for r in tuned_here.results]
    assert [r.mean() for r in tuned_there.results] == [r.mean() for r in tuned_here.results]
    assert [r["status"] for r in there.rows] == [r["status"] for r in here.rows]
    for a, b in zip(here.rows, there.rows, strict=True):
        if a["status"] != "done":
            assert a["error"] == b["error"]
            continue
        qa, fa = _read_out(a["output"])
        qb, fb = _read_out(b["output"])
        np.testing.assert_allclose(qb, qa, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(fb, fa)
        assert b["total_rmse_deg"] == pytest.approx(a["total_rmse_deg"], rel=1e-12)


def test_summary_without_pyarrow_says_how_to_get_parquet(inputs, tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "pyarrow", None)  # import pyarrow raises ImportError
    result = run_batch([inputs / "a.h5"], tmp_path / "out")
    assert result.summary_parquet is None
    assert "pip install margtrack[parquet]" in result.note
    assert not (tmp_path / "out" / "summary.parquet").exists()
    assert read_summary_csv(result.summary_csv)[0]["status"] == "done"


def test_a_broken_record_is_redone_not_trusted(inputs, tmp_path):
    out = tmp_path / "out"
    run_batch([inputs / "a.h5"], out)
    (out / ".margtrack-batch" / "a.h5.json").write_text('{"key": "')  # a crash mid-write
    assert run_batch([inputs / "a.h5"], out).rows[0]["status"] == "done"
    assert run_batch([inputs / "a.h5"], out).rows[0]["status"] == "skipped"


def test_a_column_map_applies_to_the_tables_only(inputs, tmp_path):
    rec = io.read(inputs / "a.h5")
    table = tmp_path / "logger.csv"
    np.savetxt(table, np.column_stack([rec.t, rec.gyr, rec.acc]), delimiter=",",
               header="time_s,gx,gy,gz,ax,ay,az", comments="")
    out = tmp_path / "out"
    args = ["batch", str(table), str(inputs / "a.h5"), "-o", str(out), "--workers", "1",
            "-m", "gyro", "--column", "t=time_s", "--column", "gyr=gx,gy,gz",
            "--column", "acc=ax,ay,az"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    rows = read_summary_csv(out / "summary.csv")
    assert [r["status"] for r in rows] == ["done", "done"]
    quat, _ = _read_out(rows[0]["output"])
    expected = methods.create("gyro").run(rec.without_mag()).quat
    np.testing.assert_allclose(quat, expected, rtol=0, atol=1e-12)
    result = runner.invoke(app, args)
    assert result.exit_code == 0 and "0 done, 2 skipped" in result.output
    # the table with another column map is another job (the HDF5 file is not a table)
    swapped = [*args[:-1], "acc=ay,ax,az"]
    result = runner.invoke(app, swapped)
    assert result.exit_code == 0 and "1 done, 1 skipped" in result.output
