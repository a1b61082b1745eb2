"""``margtrack plot``: the PNG of an estimate or a recording, its figures, and bad input."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from margtrack import io, methods, sim
from margtrack.accuracy import error_series, summarize
from margtrack.bench.plot_estimate import _break_wraps, flag_spans, plot_estimate
from margtrack.cli import app
from margtrack.estimator.flags import Flag

runner = CliRunner()
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def _ok(*args):
    result = _invoke(*args)
    assert result.exit_code == 0, result.output
    return result.output


def _refused(*args):
    result = _invoke(*args)
    assert result.exit_code == 2, result.output
    return " ".join(result.output.split())


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A 5 s simulated recording (truth in NED) and the bias-kf estimate of it (ENU)."""
    folder = tmp_path_factory.mktemp("plot")
    rec = sim.simulate_motion("random", duration_s=5.0, rate_hz=100.0, seed=3, frame="NED")
    io.write(rec, folder / "rec.h5")
    est = methods.create("bias-kf", {"frame": "ENU"}).run(rec)
    io.write_estimate(est, folder / "est.h5")
    io.write_estimate(est, folder / "est.csv")
    # a CSV as margtrack wrote it before it stated the frame: no comment lines
    text = (folder / "est.csv").read_text().splitlines(keepends=True)
    (folder / "old.csv").write_text("".join(x for x in text if not x.startswith("#")))
    return {"folder": folder, "rec": rec, "est": est}


def _is_png(path):
    return path.is_file() and path.read_bytes()[:8] == PNG_MAGIC


def test_flag_spans_by_hand():
    flags = np.array([0, 4, 4 | 16, 0, 4, 16], dtype=np.uint16)
    assert flag_spans(flags, Flag.GAP) == [(1, 3), (4, 5)]
    assert flag_spans(flags, Flag.ACC_IGNORED) == [(2, 3), (5, 6)]
    assert flag_spans(flags, Flag.REST) == []


def test_euler_lines_break_at_the_wrap_and_nowhere_else():
    t = np.arange(4.0)
    yaw = np.array([[170.0], [179.0], [-179.0], [-170.0]])
    t_out, y_out = _break_wraps(t, yaw)
    assert np.isnan(t_out[2]) and np.isnan(y_out[2, 0])
    np.testing.assert_array_equal(y_out[[0, 1, 3, 4], 0], yaw[:, 0])
    same_t, same = _break_wraps(t, np.array([[0.0], [90.0], [179.0], [100.0]]))
    assert same.shape == (4, 1) and not np.any(np.isnan(same_t))


def test_plot_of_an_estimate_with_truth_prints_the_run_figures(files):
    out = files["folder"] / "est.png"
    text = _ok("plot", files["folder"] / "est.h5", "--truth", files["folder"] / "rec.h5",
               "-o", out)
    assert _is_png(out)
    rec, est = files["rec"], files["est"]
    oracle = summarize(error_series(est.quat, rec.quat_true, est.frame, rec.frame), rec.movement)
    assert (f"total {oracle.total_rmse_deg:.2f} deg, heading {oracle.heading_rmse_deg:.2f} deg, "
            f"inclination {oracle.inclination_rmse_deg:.2f} deg") in text
    assert "gyroscope bias" in text and "error against the truth" in text
    assert "faults: 0 of 501" in " ".join(text.split())


def test_plot_function_reports_rmse_and_panels(files, tmp_path):
    rec, est = files["rec"], files["est"]
    drawn = plot_estimate(tmp_path / "a.png", est, rec)
    oracle = summarize(error_series(est.quat, rec.quat_true, est.frame, rec.frame), rec.movement)
    assert drawn.rmse_deg["total"] == pytest.approx(oracle.total_rmse_deg, rel=1e-12)
    assert drawn.rmse_deg["heading"] == pytest.approx(oracle.heading_rmse_deg, rel=1e-12)
    assert drawn.panels[1].startswith("gyroscope bias")
    # without truth: no error panel, no RMSE; without a bias output: no bias panel
    bare = dataclasses.replace(est, outputs={})
    drawn = plot_estimate(tmp_path / "b.png", bare)
    assert drawn.rmse_deg is None and len(drawn.panels) == 2 and _is_png(tmp_path / "b.png")


def test_truth_holes_are_left_out_of_the_error(files, tmp_path):
    rec, est = files["rec"], files["est"]
    q = rec.quat_true.copy()
    q[100:150] = np.nan  # an optical system lost the markers
    holed = dataclasses.replace(rec, quat_true=q)
    drawn = plot_estimate(tmp_path / "h.png", est, holed)
    keep = np.ones(rec.n_samples, bool)
    keep[100:150] = False
    mask = keep if rec.movement is None else keep & rec.movement
    oracle = summarize(error_series(est.quat[keep], rec.quat_true[keep], est.frame, rec.frame),
                       mask[keep])
    assert drawn.rmse_deg["total"] == pytest.approx(oracle.total_rmse_deg, rel=1e-12)


def test_plot_of_a_recording_runs_the_method_and_counts_flags(files, tmp_path):
    rec = files["rec"]
    keep = np.r_[0:200, 260:rec.n_samples]  # 0.6 s lost: a GAP flag at sample 200, not fatal
    fields = {k: getattr(rec, k)[keep] for k in ("t", "gyr", "acc", "mag", "quat_true",
                                                   "movement") if getattr(rec, k) is not None}
    gapped = dataclasses.replace(rec, **fields)
    path = tmp_path / "gap.h5"
    io.write(gapped, path)
    out = tmp_path / "gap.png"
    text = " ".join(_ok("plot", path, "-o", out, "-m", "gyro").split())
    assert _is_png(out)
    assert "GAP 1 (first at sample 200)" in text
    assert "gyroscope bias" not in text and "error against the truth" in text
    expected = methods.create("gyro").run(gapped)
    drawn = plot_estimate(tmp_path / "g2.png", expected, gapped)
    assert drawn.flag_counts["GAP"] == 1
    assert f"total {drawn.rmse_deg['total']:.2f} deg" in text


def test_csv_estimate_needs_its_frame_for_the_truth(files, tmp_path):
    # what margtrack writes states its frame: no --frame needed, the same figures as HDF5
    from_csv = _ok("plot", files["folder"] / "est.csv", "--truth", files["folder"] / "rec.h5",
                   "-o", tmp_path / "new.png")
    from_h5 = _ok("plot", files["folder"] / "est.h5", "--truth", files["folder"] / "rec.h5",
                  "-o", tmp_path / "h5.png")
    figures = [x for x in from_csv.splitlines() if x.startswith("against the truth")]
    assert figures and figures == [
        x for x in from_h5.splitlines() if x.startswith("against the truth")]
    csv = files["folder"] / "old.csv"  # an older CSV without the frame: --frame declares it
    message = _refused("plot", csv, "--truth", files["folder"] / "rec.h5", "-o",
                       tmp_path / "c.png")
    assert "does not say its earth frame" in message and "--frame ENU" in message
    text = _ok("plot", csv, "--truth", files["folder"] / "rec.h5", "--frame", "ENU", "-o",
               tmp_path / "c.png")
    assert "against the truth" in text and _is_png(tmp_path / "c.png")
    stated = tmp_path / "stated.csv"
    stated.write_text("# margtrack-estimate v1 method=bias-kf frame=ENU\n" + csv.read_text())
    contradicted = _refused("plot", stated, "--frame", "NED", "-o", tmp_path / "d.png")
    assert "says its frame is ENU, not NED" in contradicted


def test_outputs_are_safe(files, tmp_path):
    est = files["folder"] / "est.h5"
    out = tmp_path / "p.png"
    out.write_bytes(b"keep me")
    message = _refused("plot", est, "-o", out)
    assert "already exists" in message and "--force" in message
    assert out.read_bytes() == b"keep me"
    _ok("plot", est, "-o", out, "--force")
    assert _is_png(out)
    assert "PNG" in _refused("plot", est, "-o", est)  # never over the input
    assert "PNG" in _refused("plot", est, "-o", tmp_path / "p.jpg")
    assert "does not exist" in _refused("plot", est, "-o", tmp_path / "missing" / "p.png")
    assert not list(tmp_path.glob(".*tmp*"))


def test_truth_must_be_the_same_samples(files, tmp_path):
    rec = files["rec"]
    short = tmp_path / "short.h5"
    io.write(rec.slice(0, 400), short)
    message = _refused("plot", files["folder"] / "est.h5", "--truth", short, "-o",
                       tmp_path / "s.png")
    assert "400 samples, the estimate 501" in message
    shifted = tmp_path / "shifted.h5"
    io.write(dataclasses.replace(rec, t=rec.t + 0.5), shifted)
    message = _refused("plot", files["folder"] / "est.h5", "--truth", shifted, "-o",
                       tmp_path / "s.png")
    assert "time at sample 0" in message
    plain = tmp_path / "plain.h5"
    io.write(dataclasses.replace(rec, quat_true=None, movement=None), plain)
    assert "no truth" in _refused("plot", files["folder"] / "est.h5", "--truth", plain, "-o",
                                  tmp_path / "s.png")


def test_bad_estimate_files_name_the_line_or_sample(files, tmp_path):
    lines = (files["folder"] / "est.csv").read_text().splitlines()
    truncated = tmp_path / "truncated.csv"
    truncated.write_text("\n".join(lines[:50] + [lines[50][:20]]) + "\n")
    assert "line 51" in _refused("plot", truncated, "--frame", "ENU", "-o", tmp_path / "t.png")
    garbled = tmp_path / "garbled.csv"
    garbled.write_text("\n".join(lines[:10] + [lines[10].replace(",", ",x", 1)] + lines[11:]))
    assert "line 11" in _refused("plot", garbled, "--frame", "ENU", "-o", tmp_path / "g.png")
    for name, change, expected in (
        ("nan.h5", lambda q, t: q.__setitem__(7, np.nan), "not finite at sample 7"),
        ("norm.h5", lambda q, t: q.__setitem__(9, 2 * q[9]), "sample 9 has norm 2"),
        ("clock.h5", lambda q, t: t.__setitem__(12, t[11]), "does not increase at sample 12"),
    ):
        bad = tmp_path / name
        with h5py.File(files["folder"] / "est.h5") as src, h5py.File(bad, "w") as dst:
            for key, value in src.attrs.items():
                dst.attrs[key] = value
            q, t = src["quat"][()], src["t"][()]
            change(q, t)
            dst["quat"], dst["t"] = q, t
        assert expected in _refused("plot", bad, "-o", tmp_path / f"{name}.png")
    assert "not a readable HDF5" in _refused(
        "plot", _truncate(files["folder"] / "est.h5", tmp_path / "cut.h5"), "-o",
        tmp_path / "cut.png")


def _truncate(src, dst):
    data = src.read_bytes()
    dst.write_bytes(data[: len(data) // 2])
    return dst


def test_show_without_a_viewer_warns_and_keeps_the_png(files, tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))  # no xdg-open / open on the PATH
    out = tmp_path / "shown.png"
    result = _invoke("plot", files["folder"] / "est.h5", "-o", out, "--show")
    assert result.exit_code == 0, result.output
    assert "could not open a viewer" in " ".join(result.output.split()) and _is_png(out)


def test_plot_reads_any_csv_through_the_column_options(tmp_path):
    # a mapped CSV's truth is taken as ENU (io.read_csv's default): simulate it in ENU
    rec = sim.simulate_motion("random", duration_s=5.0, rate_hz=100.0, seed=5, frame="ENU")
    table = np.column_stack([rec.t * 1e3, np.degrees(rec.gyr), rec.acc / 9.80665, rec.mag,
                             rec.quat_true])
    phone = tmp_path / "phone.csv"
    header = "time_ms,gx,gy,gz,ax,ay,az,mx,my,mz,qw,qx,qy,qz"
    np.savetxt(phone, table, delimiter=",", header=header, comments="", fmt="%.17g")
    text = " ".join(_ok(
        "plot", phone, "-o", tmp_path / "phone.png", "-m", "gyro", "--column", "t=time_ms",
        "--column", "gyr=gx,gy,gz", "--column", "acc=ax,ay,az", "--column", "mag=mx,my,mz",
        "--column", "quat_true=qw,qx,qy,qz", "--time-unit", "ms", "--gyr-unit", "deg/s",
        "--acc-unit", "g").split())
    direct = plot_estimate(tmp_path / "direct.png", methods.create("gyro").run(rec),
                           dataclasses.replace(rec, movement=None))
    assert f"total {direct.rmse_deg['total']:.2f} deg" in text
    assert _is_png(tmp_path / "phone.png")
