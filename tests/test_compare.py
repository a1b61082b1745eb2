"""The comparison harness behind `margtrack bench broad`, and the external adapters."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import sim
from margtrack.accuracy import error_series
from margtrack.bench import external
from margtrack.bench.compare import compare, plot_comparison
from margtrack.methods.robust import Robust


def _recordings():
    a = sim.simulate_motion("random", duration_s=10, seed=1, noise=False)
    b = sim.simulate_motion("limb", duration_s=10, seed=2, noise=False)
    return [(a, ("all_trials", "undisturbed")), (b, ("all_trials", "disturbed"))]


def test_compare_scores_truth_as_zero_and_groups_means(tmp_path):
    recs = _recordings()
    truth_by_name = {r.name: r.quat_true for r, _ in recs}
    result = compare(
        recs,
        [
            ("truth", lambda rec: truth_by_name[rec.name]),
            ("robust", lambda rec: Robust().run(rec).quat),
        ],
    )
    truth, robust = result.methods
    assert truth.mean()["total_rmse_deg"] < 1e-12
    assert 0.0 < robust.mean()["total_rmse_deg"] < 0.5
    assert (
        robust.mean("undisturbed")["total_rmse_deg"]
        == robust.trial(recs[0][0].name).total_rmse_deg
    )
    with pytest.raises(ValueError, match="no trial in group 'nope'"):
        robust.mean("nope")
    rows = result.table_rows([None])
    assert rows[0][:4] == ["truth", "0.00", "0.00", "0.00"]
    png = plot_comparison(result, tmp_path / "cmp.png", ["all", "undisturbed", "disturbed"])
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("name", ["vqf", "imufusion", "madgwick"])
def test_external_adapters_return_enu_orientations(name):
    pytest.importorskip({"madgwick": "ahrs"}.get(name, name))
    rec = sim.simulate_motion("random", duration_s=20, seed=1, noise=False)
    run = external.madgwick(0.05) if name == "madgwick" else external.EXTERNAL[name]
    err = error_series(run(rec), rec.quat_true)
    # each library converges on noise-free data; a frame mix-up would show 90 or 180 deg
    assert np.degrees(np.sqrt(np.mean(err.total_rad[500:] ** 2))) < 3.0
