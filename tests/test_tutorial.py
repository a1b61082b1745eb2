"""docs/tutorial.md runs as written: every ```bash block, in order, in an empty folder.

The folder sits beside a ``shared/data`` link to the real data, so the tutorial's
``../shared/data/...`` paths resolve as they do from the repository root. Each block runs
in ``bash -e`` with this interpreter's ``margtrack`` and ``python`` first on the PATH; the
outputs are then checked for content, not only existence.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.md"
DATA = ROOT.parent / "shared" / "data"


def _sections() -> dict[str, list[str]]:
    """The tutorial's ``## `` sections, each with its bash blocks in order."""
    text = TUTORIAL.read_text(encoding="utf-8")
    out: dict[str, list[str]] = {}
    for part in re.split(r"^## ", text, flags=re.M)[1:]:
        title = part.splitlines()[0].strip()
        out[title] = re.findall(r"```bash\n(.*?)```", part, re.S)
    return out


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp("tutorial")
    (base / "shared").mkdir()
    (base / "shared" / "data").symlink_to(DATA, target_is_directory=True)
    work = base / "work"
    work.mkdir()
    return work


def _run(block: str, cwd: Path) -> str:
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(["bash", "-e", "-c", block], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, f"block failed:\n{block}\n{done.stdout}\n{done.stderr}"
    return done.stdout


def test_the_tutorial_has_its_two_sections() -> None:
    sections = _sections()
    assert list(sections) == ["Phone CSV -> orientation -> plot",
                              "x-IMU3 folder -> joint angles -> OpenSim"]
    phone = "\n".join(sections["Phone CSV -> orientation -> plot"])
    assert ("margtrack run phone.csv --column t=time_ms --column gyr=gx,gy,gz --column "
            "acc=ax,ay,az --column mag=mx,my,mz --time-unit ms --gyr-unit deg/s --acc-unit g "
            "-o out.h5") in phone
    assert "margtrack plot out.h5 -o out.png" in phone


def test_phone_csv_section_runs(workdir: Path) -> None:
    from margtrack import io

    outputs = [_run(b, workdir) for b in _sections()["Phone CSV -> orientation -> plot"]]
    header = (workdir / "phone.csv").read_text().splitlines()[0]
    assert header == "time_ms,gx,gy,gz,ax,ay,az,mx,my,mz"
    rec = io.read(workdir / "sim.h5")
    table = np.loadtxt(workdir / "phone.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 1:4], np.degrees(rec.gyr), rtol=1e-9, atol=1e-9)
    import h5py

    with h5py.File(workdir / "out.h5") as f:
        t, q = f["t"][()], f["quat"][()]
    np.testing.assert_allclose(t, rec.t, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    for png in ("out.png", "error.png"):
        assert (workdir / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    total = re.search(r"against the truth: total (\d+\.\d+) deg", "\n".join(outputs))
    assert total is not None and float(total.group(1)) < 5.0, outputs[-1]


def test_xio_section_runs(workdir: Path) -> None:
    if not (DATA / "xio_lower_body" / "pelvis" / "Inertial.csv").is_file():
        pytest.skip(f"x-IMU3 lower-body data not found at {DATA} (it lives in ../shared)")
    pytest.importorskip("opensim", reason="the tutorial's OpenSim block needs `opensim`")
    from margtrack.body import read_joint_angles_csv

    outputs = [_run(b, workdir) for b in _sections()["x-IMU3 folder -> joint angles -> OpenSim"]]
    assert "calibration on 0.00-0.98 s" in outputs[0]
    t, names, deg = read_joint_angles_csv(workdir / "walk" / "joint_angles.csv")
    assert t.size == 930 and "right_knee_flexion" in names
    assert 118.0 < deg[:, names.index("right_knee_flexion")].max() < 130.0
    # the renamed copy with a map is the same recording: the same angles
    t2, names2, deg2 = read_joint_angles_csv(workdir / "lab_walk" / "joint_angles.csv")
    assert names2 == names and np.array_equal(t2, t)
    np.testing.assert_allclose(deg2, deg, atol=1e-9)
    assert ("['pelvis_imu', 'femur_l_imu', 'tibia_l_imu', 'calcn_l_imu', 'femur_r_imu', "
            "'tibia_r_imu', 'calcn_r_imu']") in outputs[-1]
    assert "930 rows at 50.000000 Hz" in outputs[-1]
