"""margtrack batch: INPUT arguments to recordings, output names, and the resume records."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from margtrack.batch.inputs import expand_inputs, output_names
from margtrack.batch.state import HEAD_TAIL_BYTES, fingerprint, job_key, read_record


def _touch(path: Path, text: str = "x") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.fixture
def study(tmp_path: Path) -> Path:
    root = tmp_path / "study"
    for name in ("b.hdf5", "a.h5", "c.csv", "trials.json", "notes.txt", ".hidden.h5"):
        _touch(root / name)
    _touch(root / "pelvis" / "Inertial.csv")  # an x-IMU3 sensor folder
    _touch(root / "empty_dir" / "readme.md")
    _touch(root / "deep" / "x" / "trial.hdf5")
    _touch(root / "phone" / "Gyroscope.csv")  # one recording in per-sensor files
    _touch(root / "phone" / "TotalAcceleration.csv")
    _touch(root / "lab.tsv")
    return root


def test_a_folder_gives_its_recordings_and_sensor_folders_sorted(study):
    found = expand_inputs([study])
    assert [p.name for p in found] == ["a.h5", "b.hdf5", "c.csv", "lab.tsv", "pelvis", "phone"]
    # a per-sensor folder given itself is one recording, not its files
    assert expand_inputs([study / "phone"]) == [study / "phone"]
    assert expand_inputs([study / "notes.txt"]) == [study / "notes.txt"]  # named: a table


def test_globs_files_and_duplicates(study):
    found = expand_inputs([str(study / "**" / "*.hdf5"), study / "b.hdf5", study / "a.h5"])
    # the glob's matches in sorted order, then a.h5; b.hdf5 only once
    assert [p.relative_to(study).as_posix() for p in found] == [
        "b.hdf5", "deep/x/trial.hdf5", "a.h5"
    ]
    assert [p.name for p in expand_inputs([study / "pelvis"])] == ["pelvis"]


def test_the_output_folder_is_never_an_input(study):
    out = study / "out"
    _touch(out / "a.h5")
    assert out / "a.h5" not in expand_inputs([study / "**" / "*.h5"], exclude=out)
    with pytest.raises(ValueError, match="outside the output folder"):
        expand_inputs([out], exclude=out)


@pytest.mark.parametrize(
    ("arg", "error", "match"),
    [
        ("missing.h5", FileNotFoundError, "missing.h5: no such file or folder"),
        ("nothing_*.hdf5", ValueError, r"nothing_\*.hdf5: the pattern matched no file"),
        ("empty_dir", ValueError, "empty_dir: no recording there"),
        ("trials.json", ValueError, r"trials.json is not a recording \(.json\)"),
        ("*.json", ValueError, r"\*.json: no recording there"),
    ],
)
def test_bad_inputs_name_the_argument(study, arg, error, match):
    with pytest.raises(error, match=match):
        expand_inputs([str(study / arg)])


def test_no_argument_at_all_is_an_error():
    with pytest.raises(ValueError, match="no input given"):
        expand_inputs([])


def test_output_names_are_unique_and_stable(tmp_path):
    a = _touch(tmp_path / "a" / "trial.h5")
    b = _touch(tmp_path / "b" / "trial.csv")
    c = _touch(tmp_path / "c" / "other.hdf5")
    names = output_names([a, b, c])
    assert len(set(names)) == 3
    assert names[2] == "other.h5"
    assert names[0].startswith("trial-") and names[1].startswith("trial-")
    assert output_names([a, b, c]) == names  # same inputs, same names on a rerun
    assert output_names([a, c]) == ["trial.h5", "other.h5"]  # no collision, plain stems


def test_real_broad_and_xio_folders(broad_folder, xio_folder):
    trials = expand_inputs([broad_folder])
    assert len(trials) == len(list(broad_folder.glob("*.hdf5"))) == 16
    assert {p.suffix for p in trials} == {".hdf5"}
    sensors = expand_inputs([xio_folder])
    assert sorted(p.name for p in sensors) == sorted(
        d.name for d in xio_folder.iterdir() if (d / "Inertial.csv").is_file()
    )
    assert len(set(output_names(trials + sensors))) == 16 + len(sensors)


def test_fingerprint_sees_content_time_and_the_far_end_of_large_files(tmp_path):
    f = tmp_path / "big.bin"
    data = bytearray(os.urandom(3 * HEAD_TAIL_BYTES))
    f.write_bytes(bytes(data))
    first = fingerprint(f)
    assert fingerprint(f) == first and not first["full"]
    st = f.stat()
    # same size and restored time, last byte changed: the tail hash sees it
    data[-1] ^= 0xFF
    f.write_bytes(bytes(data))
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert fingerprint(f)["sha256"] != first["sha256"]
    # a middle byte with restored time: only the full hash sees it (documented trade-off)
    before = fingerprint(f)
    full_before = fingerprint(f, full=True)
    data[len(data) // 2] ^= 0xFF
    f.write_bytes(bytes(data))
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert fingerprint(f) == before
    assert fingerprint(f, full=True)["sha256"] != full_before["sha256"]
    # any rewrite that moves the time changes the fingerprint
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    assert fingerprint(f)["mtime_ns"] != before["mtime_ns"]


def test_job_key_depends_on_every_ingredient(tmp_path):
    f = _touch(tmp_path / "r.csv", "t,gyr\n")
    base = dict(method="robust", params={"gain": 0.1}, frame=None, calibration=None,
                read_kwargs={}, version="0.1.0")
    key = job_key(fingerprint(f), **base)
    assert job_key(fingerprint(f), **base) == key
    for change in ({"params": {"gain": 0.2}}, {"method": "gyro"}, {"frame": "NED"},
                   {"read_kwargs": {"gyr_unit": "deg/s"}}, {"version": "0.2.0"},
                   {"calibration": {"sha256": "0"}}):
        assert job_key(fingerprint(f), **{**base, **change}) != key, change
    _touch(f, "t,gyr,acc\n")
    assert job_key(fingerprint(f), **base) != key


def test_records_read_back_and_a_broken_one_is_empty(tmp_path):
    assert read_record(tmp_path / "none.json") is None
    broken = _touch(tmp_path / "r.json", '{"key": ')  # a crash mid-write of an old version
    assert read_record(broken) == {}
