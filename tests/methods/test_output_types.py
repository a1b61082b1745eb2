"""The typed width-1 outputs of Bachmann, the EKF and the bias filter: computed on first read.

Each is a column of the kernel's float outputs, squeezed and converted (``degenerate`` int8,
``iterations`` int32, ``new_correction`` bool) only when read (``Outputs``' deferred values).
"""

from __future__ import annotations

import numpy as np
import pytest

from margtrack import methods
from margtrack.estimator.triad_kernel import OK, ZERO_MAG

S, N, ZEROED = 2, 300, 150


def _run(name: str):
    rng = np.random.default_rng(0)
    gyr = rng.normal(0.0, 0.05, (S, N, 3))
    acc = rng.normal(0.0, 0.05, (S, N, 3)) + [0.0, 0.0, 9.81]
    mag = rng.normal(0.0, 0.5, (S, N, 3)) + [20.0, 0.0, -40.0]
    mag[1, ZEROED] = 0.0  # no field at one sample: the kernel's ZERO_MAG code there
    return methods.create(name).run(gyr=gyr, acc=acc, mag=mag, t=np.arange(N) / 100.0)


@pytest.mark.parametrize(
    ("name", "typed"),
    [
        ("bachmann", {"degenerate": np.int8, "new_correction": np.bool_, "phi": np.float64}),
        ("ekf", {"degenerate": np.int8, "iterations": np.int32}),
        ("bias-kf", {"degenerate": np.int8}),
    ],
)
def test_typed_outputs_are_made_on_first_read_from_the_right_column(name, typed):
    est = _run(name)
    assert sorted(est.outputs.pending()) == sorted(typed)
    for key, dtype in typed.items():
        value = est.outputs[key]
        assert value.dtype == dtype and value.shape == (S, N)
    assert est.outputs.pending() == []
    code = est.outputs["degenerate"]
    assert code[1, ZEROED] == ZERO_MAG
    code[1, ZEROED] = OK
    assert not code.any()  # every other sample had both vectors
    if name == "ekf":  # two Gauss-Newton updates a sample (the cap), none without a field
        its = est.outputs["iterations"]
        assert its[1, ZEROED] == 0
        assert (its[:, 1:] == 2).sum() == S * (N - 1) - 1
