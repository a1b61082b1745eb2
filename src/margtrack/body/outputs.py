"""The files of a body workflow run, written safely into one output folder.

=====================  ===================================================================
file                   content
=====================  ===================================================================
joint_angles.csv       ``t (s)`` then ``<joint>_<component> (deg)`` (:mod:`.export_csv`)
orientations.sto       segment orientations for OpenSense: ``pelvis_imu``, ``femur_r_imu``,
                       ``tibia_r_imu``, ``calcn_r_imu``... (``head_imu`` with a head sensor),
                       OpenSim axes (:mod:`.export_sto`)
pelvis_position.csv    the companion of the .sto: ``t (s)``, the root's earth-frame
                       position (m) from the foot contacts and each foot's anchor share
                       (:mod:`.root`)
motion.bvh             the motion of the skeleton, the root moving with the foot contacts,
                       Y up, in cm (default) or m (``bvh_unit``) (:mod:`.export_bvh`)
joint_angles.png       the joint-angle curves, calibration window shaded (:mod:`.plot`)
gait_cycles.csv        one row per gait cycle: side, start, toe off, end (s), stance %,
                       cadence (:mod:`.gait`)
gait_cycles.png        the joint angles over 0-100 % of the gait cycle, mean ± SD per side;
                       not written when no side has two cycles (the summary says why)
sensor_flags.csv       ``t (s)`` then ``<sensor> (flag bits)`` per common frame: bits of
                       :class:`margtrack.estimator.Flag` (0: clean)
summary.txt            the printed summary
=====================  ===================================================================

Times are s from the first common frame. Every file is written to a temporary file in the
folder and renamed into place (:func:`margtrack.io.safe_output.atomic_output`); before any
is written, all are checked: none may be an input, and existing files are kept unless
``force`` (the CLI's ``--force``).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from margtrack.body.export_bvh import BVH_UNITS, write_bvh
from margtrack.body.export_csv import write_joint_angles_csv
from margtrack.body.export_sto import write_sto
from margtrack.body.gait import write_gait_cycles_csv
from margtrack.body.plot import plot_gait_cycles, plot_joint_angles

if TYPE_CHECKING:
    from margtrack.body.workflow import BodyResult

__all__ = ["OUTPUT_FILES", "check_outputs", "write_outputs"]

#: kind -> file name inside the output folder.
OUTPUT_FILES = {
    "angles": "joint_angles.csv",
    "sto": "orientations.sto",
    "root": "pelvis_position.csv",
    "bvh": "motion.bvh",
    "plot": "joint_angles.png",
    "gait": "gait_cycles.csv",
    "gait_plot": "gait_cycles.png",
    "flags": "sensor_flags.csv",
    "summary": "summary.txt",
}


def check_outputs(outdir: str | Path, inputs: Iterable[str | Path] = (),
                  force: bool = False) -> dict[str, Path]:
    """Check, before any work, that the output files can be written; their paths by kind.

    ``outdir`` may not exist yet (it is created by :func:`write_outputs`), but its parent
    must. It may not be an input folder or lie inside one (the outputs would be read as
    sensors next time). Existing outputs raise ``FileExistsError`` listing all of them
    unless ``force``.
    """
    from margtrack.io.safe_output import check_output

    out = Path(outdir)
    sources = [Path(i) for i in inputs]
    for src in sources:
        if src.is_dir() and (out.resolve() == src.resolve()
                             or src.resolve() in out.resolve().parents):
            raise ValueError(f"output folder {out} is inside the input {src}; choose a folder "
                             "outside the recording")
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"output {out} is a file; -o takes a folder")
    if not out.parent.is_dir():
        raise FileNotFoundError(f"cannot create {out}: folder {out.parent} does not exist; "
                                f"create it first (mkdir -p {out.parent})")
    paths = {kind: out / name for kind, name in OUTPUT_FILES.items()}
    existing = [p.name for p in paths.values() if p.exists()]
    if existing and not force:
        raise FileExistsError(f"{out} already holds {', '.join(existing)}, kept; pass --force "
                              "(force=True) to replace them, or choose another folder")
    if out.is_dir():
        for p in paths.values():
            check_output(p, sources, force=force)
    return paths


def _write_flags(path: Path, result: BodyResult) -> None:
    names = [f"{r.sensor} (flag bits)" for r in result.sensors]
    data = np.column_stack([result.t_rel_s, result.frame_flags.astype(np.float64)])
    np.savetxt(path, data, fmt=["%.10g"] + ["%d"] * len(names), delimiter=",",
               header=",".join(["t (s)", *names]), comments="")


def _write_root(path: Path, result: BodyResult) -> None:
    if result.root is not None:
        result.root.write_csv(path, result.t_rel_s, result.skeleton.root)
        return
    from margtrack.body.root import RootPath

    fixed = np.tile(result.skeleton.root_position_m, (result.t_s.size, 1))
    n = result.t_s.size
    RootPath(fixed, np.full((n, 2), np.nan), result.skeleton.frame, np.ones(n, bool)
             ).write_csv(path, result.t_rel_s, result.skeleton.root)


def write_outputs(result: BodyResult, outdir: str | Path, force: bool = False,
                  inputs: Iterable[str | Path] = (), bvh_unit: str = "cm") -> dict[str, Path]:
    """Write the files of the module table into ``outdir`` (created if missing).

    ``bvh_unit`` is the BVH's length unit, ``"cm"`` or ``"m"``. Returns the written paths
    by kind (``gait_cycles.png`` only when a side has two cycles or more). Raises before
    writing anything if :func:`check_outputs` does.
    """
    from margtrack.io.safe_output import atomic_output

    if bvh_unit not in BVH_UNITS:
        raise ValueError(f"the BVH unit must be one of {', '.join(BVH_UNITS)}, got {bvh_unit!r}")
    paths = check_outputs(outdir, inputs, force)
    Path(outdir).mkdir(exist_ok=True)
    t = result.t_rel_s
    sk, q_seg = result.skeleton, result.pose.q_segment
    root = None if result.root is None else result.root.position_m
    writers = {
        "angles": lambda p: write_joint_angles_csv(p, t, result.angles),
        "sto": lambda p: write_sto(p, sk, t, q_seg),
        "root": lambda p: _write_root(p, result),
        "bvh": lambda p: write_bvh(p, sk, q_seg, 1.0 / result.rate_hz, root, unit=bvh_unit),
        "plot": lambda p: plot_joint_angles(
            p, t, result.angles, window_s=(t[result.window.start], t[result.window.stop - 1]),
            title=f"joint angles ({result.method}, {len(result.sensors)} sensors)"),
        "gait": lambda p: write_gait_cycles_csv(p, result.gait),
        "gait_plot": lambda p: plot_gait_cycles(p, t, result.angles, result.gait),
        "flags": lambda p: _write_flags(p, result),
        "summary": lambda p: p.write_text("\n".join(result.summary()) + "\n",
                                          encoding="utf-8"),
    }
    if not any(g.n_cycles >= 2 for g in result.gait.values()):
        stale = paths.pop("gait_plot")
        stale.unlink(missing_ok=True)  # a former run's figure (force) would mislead
    for kind, path in paths.items():
        with atomic_output(path) as tmp:
            writers[kind](tmp)
    return paths
