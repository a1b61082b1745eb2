"""Body workflow on the x-IMU3 lower-body walk: margtrack's filter against the devices' own.

The work itself is ``margtrack body`` (:func:`margtrack.body.process_body`): every sensor
of ../shared/data/xio_lower_body filtered by a margtrack method, one 50 Hz time base, the
sensor-to-segment offsets calibrated on the first still second with the heading from the
pelvis sensor (-z forward: it sits on the sacrum), joint angles and the files (CSV, .sto,
BVH, PNG) in --out. This script adds what only a benchmark does:

- the same body model on the devices' own orientation estimates (``Quaternion.csv``, NWU),
  the route this benchmark took before the workflow existed: knee flexion peaks per step,
  labelled by what the body does, side by side, and their differences;
- the BVH read back with bvhio (if installed), joint positions against the body model;
- speed: frames/s of the vectorised body model (eq. 7 + eq. 11 + joint angles) against a
  per-frame loop over scipy Rotation objects doing the same work, in the same run.

Run: python benchmarks/body_xio.py [--data DIR] [--out DIR] [-m METHOD]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from scipy.signal import find_peaks
from scipy.spatial.transform import Rotation

from margtrack import body
from margtrack import quaternion as quat
from margtrack.bench.speed import measure
from margtrack.body.xio import read_xio_orientations

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "xio_lower_body"
HIGH_KNEE_DEG = 90.0  # knee peaks above this are the recording's high-knee raises, not steps
TURN_DEG = 20.0  # pelvis heading change within +-0.5 s of a peak that marks a turning step


def scipy_loop(skeleton: body.Skeleton, offsets: np.ndarray, q_sensor: np.ndarray) -> np.ndarray:
    """Joint positions frame by frame with scipy Rotation: the reference implementation."""
    off = Rotation.from_quat(offsets[:, [1, 2, 3, 0]])
    out = np.empty((q_sensor.shape[0], len(skeleton), 3))
    offsets_m = skeleton.offsets_m
    for n in range(q_sensor.shape[0]):
        seg = Rotation.from_quat(q_sensor[n][:, [1, 2, 3, 0]]) * off
        out[n, 0] = skeleton.root_position_m
        for i in range(1, len(skeleton)):
            p = skeleton.parents[i]
            out[n, i] = out[n, p] + seg[p].apply(offsets_m[i])
    return out


def device_angles(data: Path, rate_hz: float) -> tuple[np.ndarray, body.JointAngles, np.ndarray]:
    """Joint angles from the devices' own quaternions (same skeleton, window and heading)."""
    t, names, q = read_xio_orientations(data, rate_hz, device_frame="NWU", frame="ENU")
    skeleton = body.Skeleton.from_height(1.75, "lower", "ENU")
    q = q[:, skeleton.order(names)]
    window = body.still_window(t, q, duration_s=1.0, max_motion_deg=2.0)
    cal = body.calibrate(skeleton, q[window], heading="pelvis", forward_axis=(0, 0, -1))
    pose = body.track(skeleton, cal, q)
    yaw = np.degrees(np.unwrap(quat.to_euler(pose.q_segment[:, 0])[:, 0]))
    return t - t[0], body.joint_angles(skeleton, pose.q_segment), yaw


def labelled_peaks(t: np.ndarray, knees: dict[str, np.ndarray], yaw: np.ndarray, rate_hz: float
                   ) -> dict[str, list[tuple[float, float, str]]]:
    """Knee flexion peaks (> 20 deg, >= 0.5 s apart) as (time s, deg, what the body does)."""
    half = int(0.5 * rate_hz)
    out: dict[str, list[tuple[float, float, str]]] = {}
    for side, flex in knees.items():
        peaks, _ = find_peaks(flex, height=20.0, distance=half)
        rows = []
        for k, i in enumerate(peaks):
            lo, hi = max(i - half, 0), min(i + half, t.size - 1)
            near = slice(max(i - int(0.8 * rate_hz), 0), i + int(0.8 * rate_hz))
            if max(knees["left"][near].max(), knees["right"][near].max()) >= HIGH_KNEE_DEG:
                label = "high-knee raise" if flex[i] >= HIGH_KNEE_DEG else "stance of a raise"
            elif abs(yaw[hi] - yaw[lo]) > TURN_DEG:
                label = "turning"
            else:
                label = "first step" if k == 0 else "straight walking"
            rows.append((float(t[i]), float(flex[i]), label))
        out[side] = rows
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "body_xio")
    parser.add_argument("-m", "--method", default="default")
    args = parser.parse_args()

    result = body.process_body(body.read_body(args.data), method=args.method)
    print("\n".join(result.summary()))
    written = result.write(args.out, force=True, inputs=[args.data])
    print(f"wrote {', '.join(p.name for p in written.values())} to {args.out}")

    rate = result.rate_hz
    t_dev, dev, yaw = device_angles(args.data, rate)
    knees = {s: result.angles.degrees(f"{s}_knee")[:, 0] for s in ("left", "right")}
    dev_knees = {s: dev.degrees(f"{s}_knee")[:, 0] for s in ("left", "right")}
    ours = labelled_peaks(result.t_rel_s, knees, yaw[: result.t_s.size], rate)
    theirs = labelled_peaks(t_dev, dev_knees, yaw, rate)
    print(f"\nknee flexion peaks (deg): margtrack {result.method} vs the devices' quaternions")
    diffs = []
    for side in ("left", "right"):
        for (s, v, label), (s2, v2, _) in zip(ours[side], theirs[side], strict=False):
            diffs.append(v - v2)
            print(f"  {side:5s} {s:5.1f} s  {v:6.1f}  device {v2:6.1f} at {s2:4.1f} s  "
                  f"({label})")
        straight = [v for _, v, label in ours[side] if label == "straight walking"]
        dev_straight = [v for _, v, label in theirs[side] if label == "straight walking"]
        print(f"  {side:5s} straight walking: mean {np.mean(straight):.1f} deg "
              f"(device {np.mean(dev_straight):.1f} deg, {len(straight)} steps)")
    n = min(t_dev.size, result.t_s.size)
    gap = np.concatenate([knees[s][:n] - dev_knees[s][:n] for s in knees])
    print(f"  peak differences: max {np.max(np.abs(diffs)):.1f} deg; knee flexion over the "
          f"whole walk differs by median {np.median(np.abs(gap)):.1f} deg, RMS "
          f"{np.sqrt(np.mean(gap**2)):.1f} deg")

    try:
        import bvhio
    except ImportError:
        print("  (bvhio not installed: BVH read-back check skipped)")
    else:
        hierarchy = bvhio.readAsHierarchy(str(written["bvh"]))
        nodes = {j.Name: j for j, _, _ in hierarchy.layout()}
        m = body.bvh_axes("ENU")
        worst = 0.0
        frames = range(0, result.t_s.size, 10)
        for f in frames:
            hierarchy.loadPose(f, recursive=True)
            for i, name in enumerate(result.skeleton.names):
                p = m.T @ np.array(nodes[name].PositionWorld, dtype=float) / 100.0
                worst = max(worst, float(np.abs(p - result.pose.joints_m[f, i]).max()))
        print(f"  BVH read back with bvhio: joint positions within {worst:.1e} m of the body "
              f"model ({len(frames)} frames)")

    skeleton, cal, q = result.skeleton, result.calibration, result.q_sensor
    big = np.tile(q, (max(1, 100_000 // q.shape[0]), 1, 1))

    def vectorised() -> object:
        return body.joint_angles(skeleton, body.track(skeleton, cal, big).q_segment)

    small = q[:2000]
    fast = measure("margtrack.body (numpy, vectorised)", vectorised, big.shape[0])
    slow = measure("per-frame loop, scipy Rotation",
                   lambda: scipy_loop(skeleton, cal.offsets, small), small.shape[0], repeats=1)
    diff = np.abs(body.track(skeleton, cal, small).joints_m
                  - scipy_loop(skeleton, cal.offsets, small)).max()
    print(f"\nspeed ({len(skeleton)} segments per frame; frames/s):")
    for th in (fast, slow):
        print(f"  {th.label:<38} {th.samples_per_s:12.0f}  ({th.us_per_sample:.2f} us/frame)")
    print(f"  ratio vectorised / loop: {fast.ratio_to(slow):.0f}x; joint positions agree to "
          f"{diff:.1e} m")


if __name__ == "__main__":
    main()
