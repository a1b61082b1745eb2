"""Import profiles: a logger's columns, units and layout in TOML, checked, merged with flags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from margtrack import io
from margtrack.io.profile import PROFILE_KEYS, load_profile, merge_profile

PROFILE = """\
# our lab's logger: semicolon, decimal comma, ms, deg/s, g
delimiter = ";"
decimal = ","
time_unit = "ms"
gyr_unit = "deg/s"
acc_unit = "g"
mag_unit = "nT"

[columns]
t = "zeit_ms"
gyr = ["wx", "wy", "wz"]
acc = "fx,fy,fz"
mag = ["bx", "by", "bz"]
"""


def _log(path: Path) -> Path:
    rows = ["zeit_ms;wx;wy;wz;fx;fy;fz;bx;by;bz",
            "0;180;0;-90;0;0;1;20000;0;-40000",
            "10,5;0;360;0;0,5;0;1;20000;1000;-40000",
            "21;0;0;0;0;0;1;20000;0;-40000"]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_a_profile_replaces_the_flags(tmp_path):
    prof = tmp_path / "lab.toml"
    prof.write_text(PROFILE)
    data = _log(tmp_path / "session.csv")
    rec = io.read(data, profile=prof)
    np.testing.assert_allclose(rec.t, [0.0, 0.0105, 0.021], atol=1e-15)
    np.testing.assert_allclose(rec.gyr[0], [np.pi, 0.0, -np.pi / 2], rtol=1e-15)
    np.testing.assert_allclose(rec.acc[1], [0.5 * 9.80665, 0.0, 9.80665], rtol=1e-15)
    np.testing.assert_allclose(rec.mag[1], [20.0, 1.0, -40.0], rtol=1e-15)  # nT -> µT
    same = io.read(data, columns={"t": "zeit_ms", "gyr": "wx,wy,wz", "acc": "fx,fy,fz",
                                  "mag": "bx,by,bz"}, time_unit="ms", gyr_unit="deg/s",
                   acc_unit="g", mag_unit="nT")
    np.testing.assert_array_equal(rec.gyr, same.gyr)
    np.testing.assert_array_equal(rec.mag, same.mag)


def test_flags_win_over_the_profile(tmp_path):
    prof = tmp_path / "lab.toml"
    prof.write_text(PROFILE)
    merged = merge_profile(prof, {"gyr_unit": "rad/s", "columns": {"t": "other"},
                                  "acc_unit": None})
    assert merged["gyr_unit"] == "rad/s" and merged["acc_unit"] == "g"
    assert merged["columns"]["t"] == ["other"] and merged["columns"]["gyr"] == ["wx", "wy", "wz"]
    rec = io.read(_log(tmp_path / "s.csv"), profile=prof, gyr_unit="rad/s")
    assert rec.gyr[0, 0] == 180.0  # declared rad/s: not converted


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('gyr_units = "deg/s"\n', r"unknown key\(s\) \['gyr_units'\].*gyr_unit \(unit of"),
        ('gyr_unit = "rpm"\n', r"gyr_unit: gyr_unit must be one of"),
        ("time_unit = 5\n", r"time_unit must be a string, got 5"),
        ('delimiter = "|"\n', r"delimiter must be one of"),
        ('decimal = ";"\n', r"decimal must be '\.' or ','"),
        ('frame = "NWU"\n', r"frame must be 'ENU' or 'NED'"),
        ("rate_hz = -3\n", r"rate_hz must be a number > 0"),
        ('columns = "t=time"\n', r"columns must be a table"),
        ('[columns]\ngyr = ["a", "b"]\n', r"columns\['gyr'\] must name 3 column"),
        ('[columns]\ngyro = "a,b,c"\n', r"unknown fields \['gyro'\]"),
        ("time_unit = \n", r"not valid TOML"),
    ],
)
def test_bad_profiles_are_refused_naming_the_file(tmp_path, text, message):
    prof = tmp_path / "bad.toml"
    prof.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        load_profile(prof)
    assert "bad.toml" in str(info.value)


def test_missing_profile_and_documented_keys(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such import profile"):
        load_profile(tmp_path / "none.toml")
    doc = (Path(io.__file__).parent / "profile.py").read_text()
    for key in PROFILE_KEYS:  # every accepted key appears in the module's example
        assert f"{key} = " in doc or f"[{key}]" in doc, key


def test_the_documented_profile_example_loads(tmp_path):
    import re

    page = Path(__file__).resolve().parents[2] / "docs" / "commands.md"
    block = re.search(r"```toml\n(.*?)```", page.read_text(encoding="utf-8"), re.S)
    assert block, "docs/commands.md has no profile example"
    prof = tmp_path / "lab.toml"
    prof.write_text(block.group(1))
    got = load_profile(prof)
    assert got["columns"] == {"t": ["time_ms"], "gyr": ["gx", "gy", "gz"],
                              "acc": ["ax", "ay", "az"]}
    assert (got["delimiter"], got["decimal"], got["gyr_unit"]) == (";", ",", "deg/s")
