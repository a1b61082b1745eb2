"""Recording: validation messages, unit conversion and heuristics, slicing, gaps, resampling."""

from __future__ import annotations

import numpy as np
import pytest

from margtrack.frames import STANDARD_GRAVITY_M_S2
from margtrack.recording import Recording, resample
from margtrack.units import check_unit_magnitudes

N = 10


def _arrays(n: int = N) -> dict[str, np.ndarray]:
    """Valid fields for an n-sample Recording at 100 Hz with distinct, known values."""
    rng = np.random.default_rng(7)
    q = rng.normal(size=(n, 4))
    return {
        "t": np.arange(n) / 100.0,
        "gyr": rng.normal(scale=0.5, size=(n, 3)),
        "acc": np.array([0.0, 0.0, 9.81]) + rng.normal(scale=0.1, size=(n, 3)),
        "mag": rng.normal(scale=40.0, size=(n, 3)),
        "quat_true": q / np.linalg.norm(q, axis=1)[:, None],
        "movement": np.arange(n) % 3 == 0,
    }


# --- validation: finiteness -----------------------------------------------------------


# quat_true may have NaN holes (issue 18; tests/io/test_io_columns.py), inf is refused there
@pytest.mark.parametrize(("field", "row"), [("gyr", 3), ("acc", 0), ("mag", 9)])
def test_nan_names_field_and_sample(field: str, row: int) -> None:
    fields = _arrays()
    fields[field][row, 1] = np.nan
    with pytest.raises(ValueError, match=rf"{field} has a non-finite value .* at sample {row}:"):
        Recording(**fields)


def test_inf_in_acc_names_sample() -> None:
    fields = _arrays()
    fields["acc"][6, 2] = np.inf
    with pytest.raises(ValueError, match=r"acc has a non-finite value \(NaN or inf\) at sample 6"):
        Recording(**fields)


def test_nan_timestamp_names_sample() -> None:
    fields = _arrays()
    fields["t"][2] = np.nan
    with pytest.raises(ValueError, match=r"t has a non-finite value .* at sample 2"):
        Recording(**fields)


def test_non_numeric_is_refused() -> None:
    fields = _arrays(1)
    fields["gyr"] = [["a", "b", "c"]]
    with pytest.raises(ValueError, match="gyr must be numeric"):
        Recording(**fields)


# --- validation: shapes ---------------------------------------------------------------


def test_wrong_width_is_refused() -> None:
    fields = _arrays()
    fields["gyr"] = fields["gyr"][:, :2]
    with pytest.raises(ValueError, match=r"gyr must have shape \(N, 3\) .*got \(10, 2\)"):
        Recording(**fields)


def test_transposed_signal_is_refused() -> None:
    fields = _arrays()
    fields["acc"] = fields["acc"].T
    with pytest.raises(ValueError, match=r"acc must have shape \(N, 3\) with samples as rows"):
        Recording(**fields)


def test_length_mismatch_is_refused() -> None:
    fields = _arrays()
    fields["mag"] = fields["mag"][:-1]
    with pytest.raises(ValueError, match="mag has 9 samples but t has 10"):
        Recording(**fields)


def test_quat_true_width_and_t_ndim() -> None:
    fields = _arrays()
    fields["quat_true"] = fields["quat_true"][:, :3]
    with pytest.raises(ValueError, match=r"quat_true must have shape \(N, 4\)"):
        Recording(**fields)
    fields = _arrays()
    fields["t"] = fields["t"][:, None]
    with pytest.raises(ValueError, match=r"t must have shape \(N,\)"):
        Recording(**fields)


def test_movement_shape_is_checked() -> None:
    fields = _arrays()
    fields["movement"] = fields["movement"][:5]
    with pytest.raises(ValueError, match=r"movement must have shape \(10,\), got \(5,\)"):
        Recording(**fields)


def test_empty_recording_is_refused() -> None:
    with pytest.raises(ValueError, match="at least one sample, got 0"):
        Recording(t=np.zeros(0), gyr=np.zeros((0, 3)), acc=np.zeros((0, 3)))


def test_quat_true_must_be_unit_and_is_renormalised() -> None:
    fields = _arrays()
    fields["quat_true"][2] *= 1.1
    with pytest.raises(ValueError, match=r"not a unit quaternion at sample 2 \(norm 1.1"):
        Recording(**fields)
    fields = _arrays()
    fields["quat_true"][5] = [1.0 + 1e-4, 0.0, 0.0, 0.0]
    rec = Recording(**fields)
    np.testing.assert_array_equal(rec.quat_true[5], [1.0, 0.0, 0.0, 0.0])


def test_frame_is_checked_and_upper_cased() -> None:
    assert Recording(**_arrays(), frame="ned").frame == "NED"
    with pytest.raises(ValueError, match="frame must be 'NED' or 'ENU', got 'NWU'"):
        Recording(**_arrays(), frame="NWU")


# --- validation: timestamps -----------------------------------------------------------


def test_non_monotonic_timestamp_names_sample() -> None:
    fields = _arrays()
    fields["t"][4] = 0.025
    with pytest.raises(ValueError, match=r"non-monotonic timestamp at sample 4: t\[3\] = 0.03"):
        Recording(**fields)


def test_duplicate_timestamp_names_sample() -> None:
    fields = _arrays()
    fields["t"][7] = fields["t"][6]
    with pytest.raises(ValueError, match=r"duplicate timestamp at sample 7: t\[6\] = 0.06"):
        Recording(**fields)


# --- units ----------------------------------------------------------------------------


def test_gyr_in_deg_s_is_detected_with_sample() -> None:
    fields = _arrays()
    gyr = fields["gyr"].copy()
    gyr[7] = [0.0, -120.0, 3.0]
    with pytest.raises(ValueError, match=r"120.0 rad/s at sample 7.*gyr_unit='deg/s'"):
        Recording.from_arrays(gyr, fields["acc"], t=fields["t"])


def test_acc_in_g_is_detected() -> None:
    fields = _arrays()
    with pytest.raises(ValueError, match=r"median norm of (0.99|1.00)\d, about 1 g.*acc_unit='g'"):
        Recording.from_arrays(fields["gyr"], fields["acc"] / 9.81, t=fields["t"])


def test_check_units_false_accepts_suspicious_magnitudes() -> None:
    gyr = np.array([[100.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    acc = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    rec = Recording.from_arrays(gyr, acc, rate_hz=10.0, check_units=False)
    np.testing.assert_array_equal(rec.gyr, gyr)
    np.testing.assert_array_equal(rec.acc, acc)


def test_unit_conversion_gives_si() -> None:
    gyr_deg_s = np.array([[90.0, 180.0, -45.0], [0.0, 360.0, 1.0]])
    acc_g = np.array([[0.0, 0.0, 1.0], [0.5, -1.0, 0.25]])
    rec = Recording.from_arrays(gyr_deg_s, acc_g, t=[0.0, 0.5], gyr_unit="deg/s", acc_unit="g")
    np.testing.assert_allclose(
        rec.gyr, [[np.pi / 2, np.pi, -np.pi / 4], [0.0, 2 * np.pi, np.pi / 180]], rtol=1e-15
    )
    np.testing.assert_allclose(
        rec.acc, [[0.0, 0.0, 9.80665], [4.903325, -9.80665, 2.4516625]], rtol=1e-15
    )
    assert STANDARD_GRAVITY_M_S2 == 9.80665


def test_unknown_units_are_refused() -> None:
    f = _arrays()
    with pytest.raises(ValueError, match=r"gyr_unit must be one of \['deg/s', 'rad/s'\]"):
        Recording.from_arrays(f["gyr"], f["acc"], t=f["t"], gyr_unit="rpm")
    with pytest.raises(ValueError, match="acc_unit must be one of"):
        Recording.from_arrays(f["gyr"], f["acc"], t=f["t"], acc_unit="ft/s2")


def test_no_rate_is_assumed() -> None:
    f = _arrays()
    with pytest.raises(ValueError, match=r"exactly one of t .* or rate_hz; no rate is assumed"):
        Recording.from_arrays(f["gyr"], f["acc"])
    with pytest.raises(ValueError, match="give exactly one of t"):
        Recording.from_arrays(f["gyr"], f["acc"], t=f["t"], rate_hz=100.0)
    for bad in (0.0, -5.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="rate_hz must be a finite number > 0"):
            Recording.from_arrays(f["gyr"], f["acc"], rate_hz=bad)


def test_rate_hz_builds_timestamps() -> None:
    f = _arrays(4)
    rec = Recording.from_arrays(f["gyr"], f["acc"], f["mag"], rate_hz=250.0, name="x")
    np.testing.assert_array_equal(rec.t, [0.0, 0.004, 0.008, 0.012])
    np.testing.assert_array_equal(rec.mag, f["mag"])
    assert rec.name == "x"


def test_check_unit_magnitudes_directly() -> None:
    check_unit_magnitudes(np.full((3, 3), 39.0), np.full((3, 3), 5.7))  # 34.9 rad/s is real
    with pytest.raises(ValueError, match="at sample 1"):
        check_unit_magnitudes(np.array([[0.0, 0, 0], [0, 0, -41.0]]), np.zeros((2, 3)))


# --- properties and derived views -------------------------------------------------------


def test_rate_duration_dt() -> None:
    rec = Recording(t=np.arange(5) / 200.0 + 3.0, gyr=np.zeros((5, 3)), acc=np.zeros((5, 3)))
    assert rec.rate_hz == pytest.approx(200.0, rel=1e-12)
    assert rec.duration_s == pytest.approx(0.02, rel=1e-12)
    assert rec.n_samples == 5
    np.testing.assert_allclose(rec.dt, np.full(4, 0.005), rtol=1e-9)
    single = Recording(t=[1.0], gyr=np.zeros((1, 3)), acc=np.zeros((1, 3)))
    assert np.isnan(single.rate_hz)
    assert single.duration_s == 0.0


def test_slice_keeps_timestamps_and_all_fields() -> None:
    f = _arrays()
    rec = Recording(**f, frame="NED", name="s", meta={"k": 1})
    part = rec.slice(2, 5)
    np.testing.assert_array_equal(part.t, [0.02, 0.03, 0.04])
    for key in ("gyr", "acc", "mag", "movement"):
        np.testing.assert_array_equal(getattr(part, key), f[key][2:5])
    np.testing.assert_allclose(part.quat_true, f["quat_true"][2:5], rtol=0, atol=1e-15)
    assert (part.frame, part.name, part.meta) == ("NED", "s", {"k": 1})
    assert rec.slice(stop=3).n_samples == 3
    assert rec.slice(8).t[0] == 0.08
    with pytest.raises(ValueError, match="at least one sample"):
        rec.slice(5, 5)


def test_without_mag() -> None:
    f = _arrays()
    rec = Recording(**f)
    six = rec.without_mag()
    assert six.mag is None
    np.testing.assert_array_equal(six.gyr, f["gyr"])
    np.testing.assert_array_equal(six.movement, f["movement"])
    np.testing.assert_array_equal(rec.mag, f["mag"])  # the original keeps its magnetometer


def test_gaps() -> None:
    t = np.array([0.0, 0.01, 0.02, 0.04, 0.05, 0.08, 0.09])
    rec = Recording(t=t, gyr=np.zeros((7, 3)), acc=np.zeros((7, 3)))
    np.testing.assert_array_equal(rec.gaps(), [3, 5])
    np.testing.assert_array_equal(rec.gaps(factor=2.5), [5])
    assert rec.gaps(factor=4.0).size == 0
    assert rec.slice(0, 2).gaps().size == 0


def test_rebuilding_keeps_quat_true_bit_for_bit() -> None:
    rec = Recording(**_arrays(1000))
    again = Recording(t=rec.t, gyr=rec.gyr, acc=rec.acc, quat_true=rec.quat_true)
    np.testing.assert_array_equal(again.quat_true, rec.quat_true)
    np.testing.assert_array_equal(rec.slice(0, 1000).quat_true, rec.quat_true)


# --- resample -------------------------------------------------------------------------


def test_resample_against_hand_interpolation() -> None:
    t_src = np.array([0.0, 1.0, 3.0])
    values = np.array([[0.0, 10.0], [2.0, 20.0], [6.0, -20.0]])
    t_dst = np.array([-1.0, 0.0, 0.5, 2.0, 2.5, 3.0, 4.0])
    expected = np.array([
        [0.0, 10.0],  # before the span: first sample held
        [0.0, 10.0],
        [1.0, 15.0],  # halfway between samples 0 and 1
        [4.0, 0.0],  # halfway between samples 1 and 2
        [5.0, -10.0],  # three quarters of the way from 1 to 2
        [6.0, -20.0],
        [6.0, -20.0],  # after the span: last sample held
    ])
    np.testing.assert_allclose(resample(t_src, values, t_dst), expected, rtol=0, atol=1e-12)


def test_resample_one_channel_and_errors() -> None:
    out = resample([0.0, 2.0], [1.0, 3.0], [1.0])
    np.testing.assert_allclose(out, [[2.0]])
    with pytest.raises(ValueError, match=r"duplicate timestamp at sample 2"):
        resample([0.0, 1.0, 1.0], np.zeros((3, 2)), [0.5])
    # the message says "but t has 3" although the reference is t_src (reported, recording.py)
    with pytest.raises(ValueError, match="values has 2 samples but t"):
        resample([0.0, 1.0, 2.0], np.zeros((2, 3)), [0.5])
    with pytest.raises(ValueError, match=r"values has a non-finite value .* at sample 1"):
        resample([0.0, 1.0], [[0.0], [np.nan]], [0.5])


def test_saturated_magnetometer_is_found_with_its_first_sample() -> None:
    from margtrack import sim
    from margtrack.recording import find_saturation

    # a magnet passing 1 cm away drives a ±100 µT magnetometer into its limit
    magnet = sim.magnet_pass(t_center_s=5.0, duration_s=2.0, peak_ut=400.0, direction=(0, 1, 0))
    rec = sim.simulate(
        sim.static(10.0, 100.0),
        mag_disturbances=(magnet,),
        mag_errors=sim.SensorErrors(noise_density=0.05, saturation=100.0),
        acc_errors=sim.SensorErrors(noise_density=0.002),
        gyr_errors=sim.SensorErrors(noise_density=1e-4),
        seed=0,
    )
    hits = rec.saturation()
    assert set(hits) == {"mag"}
    clipped = np.flatnonzero(np.any(np.abs(rec.mag) >= 100.0, axis=1))
    assert hits["mag"].first_sample == clipped[0]
    assert hits["mag"].level == 100.0
    # a quiet quantised signal repeating its few levels is not clipping
    quantised = np.round(np.random.default_rng(0).normal(scale=0.6, size=(500, 3)))
    assert find_saturation(quantised) is None


def test_no_saturation_reported_on_real_recordings_with_held_magnetometer(broad_folder) -> None:
    from margtrack.io import read_broad

    # BROAD's magnetometer is slower than the IMU and held for a few samples: the repeats
    # at its maximum are ordinary holds, not clipping (these trials tripped a naive check)
    for name in ("04_undisturbed_slow_rotation_with_breaks_A", "06_undisturbed_fast_rotation_A"):
        assert read_broad(broad_folder / f"{name}.hdf5").saturation() == {}
