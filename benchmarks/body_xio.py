"""Body model on the x-IMU3 lower-body recording: calibration, joint angles, exports, speed.

Reads ../shared/data/xio_lower_body (7 x-IMU3 sensors: pelvis, left/right upper_leg,
lower_leg, foot; ~50 Hz; the devices' own orientation estimates in NWU), resamples every
sensor onto one 50 Hz time base, calibrates the sensor-to-segment offsets on the first still
second (the subject starts standing in the reference pose, 000 eq. 10) with the heading
taken from the pelvis sensor (its -z axis points forward: it sits on the sacrum), and
reports hip and knee angles: ranges of motion and knee flexion peaks per step. Writes a BVH,
an OpenSim .sto table, a CSV of joint angles and a PNG of stick figures to --out.

Speed: frames/s of the vectorised body model (eq. 7 + eq. 11 + joint angles) against a
per-frame loop over scipy Rotation objects doing the same work, in the same run.

Run: python benchmarks/body_xio.py [--data DIR] [--out DIR]
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
from margtrack.body.xio import from_device_frame, read_xio_orientations

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "xio_lower_body"
RATE_HZ = 50.0
HEIGHT_M = 1.75  # the subject's height is not given; it scales positions, not angles
PELVIS_FORWARD_AXIS = (0.0, 0.0, -1.0)
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


def gyro_orientations(folder: Path, names: list[str], t: np.ndarray) -> np.ndarray:
    """Orientations by gyro integration (bias from the first still second), ENU, on ``t``.

    An estimate independent of the device's filter and of the magnetometer, started from the
    device's first quaternion: a cross-check of the joint angles over this 18 s recording.
    """
    from margtrack.io import read_xio_quaternion, read_xio_sensor
    from margtrack.methods import create

    out = []
    for name in names:
        rec = read_xio_sensor(folder / name)
        _, q_dev = read_xio_quaternion(folder / name)
        bias = rec.gyr[rec.t < rec.t[0] + 1.0].mean(axis=0)
        est = create("gyro")
        est.reset(q_dev[0])
        q_nwu = est.run(gyr=rec.gyr - bias, acc=rec.acc, t=rec.t).quat
        out.append(body.resample_orientations(rec.t, from_device_frame(q_nwu, "NWU", "ENU"), t))
    return np.stack(out, axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "body_xio")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)

    t, names, q = read_xio_orientations(args.data, RATE_HZ, device_frame="NWU", frame="ENU")
    skeleton = body.Skeleton.from_height(HEIGHT_M, "lower", "ENU")
    q = q[:, skeleton.order(names)]
    window = body.still_window(t, q, duration_s=1.0, max_motion_deg=2.0)
    cal = body.calibrate(skeleton, q[window], heading="pelvis", forward_axis=PELVIS_FORWARD_AXIS)
    pose = body.track(skeleton, cal, q)
    angles = body.joint_angles(skeleton, pose.q_segment)
    t0 = t - t[0]

    print(f"x-IMU3 lower body: {len(names)} sensors, {t.size} frames at {RATE_HZ:g} Hz "
          f"({t0[-1]:.1f} s)")
    print(f"calibration window {t0[window.start]:.2f}-{t0[window.stop - 1]:.2f} s; subject "
          f"faced {cal.facing_deg:.1f} deg (compass); largest spread in the window "
          f"{cal.spread_deg.max():.2f} deg")
    moving = np.arange(t.size) >= window.stop
    print("\nranges of motion after the calibration window (deg):")
    print(f"{'joint':<12} {'component':<18} {'min':>7} {'max':>7} {'range':>7}")
    for joint in angles.names:
        if not joint.endswith(("hip", "knee")):
            continue
        deg = angles.degrees(joint)[moving]
        comps = angles.components[angles.names.index(joint)]
        for k, comp in enumerate(comps):
            lo, hi = deg[:, k].min(), deg[:, k].max()
            print(f"{joint:<12} {comp:<18} {lo:7.1f} {hi:7.1f} {hi - lo:7.1f}")
    print("\nknee flexion peaks (> 20 deg, >= 0.5 s apart), labelled by what the body does:")
    knees = {side: angles.degrees(f"{side}_knee")[:, 0] for side in ("left", "right")}
    yaw = np.degrees(np.unwrap(quat.to_euler(pose.q_segment[:, 0])[:, 0]))
    half = int(0.5 * RATE_HZ)
    straight: dict[str, list[float]] = {"left": [], "right": []}
    for side, flex in knees.items():
        peaks, _ = find_peaks(flex, height=20.0, distance=half)
        rows = []
        for k, i in enumerate(peaks):
            lo, hi = max(i - half, 0), min(i + half, t.size - 1)
            near = slice(max(i - int(0.8 * RATE_HZ), 0), i + int(0.8 * RATE_HZ))
            if max(knees["left"][near].max(), knees["right"][near].max()) >= HIGH_KNEE_DEG:
                label = "high-knee raise" if flex[i] >= HIGH_KNEE_DEG else "stance of a raise"
            elif abs(yaw[hi] - yaw[lo]) > TURN_DEG:
                label = "turning"
            elif k == 0:
                label = "first step"
            else:
                label = "straight walking"
                straight[side].append(float(flex[i]))
            rows.append(f"{flex[i]:.0f} at {t0[i]:.1f} s ({label})")
        print(f"  {side:5s} " + "; ".join(rows))
    for side, values in straight.items():
        print(f"  {side:5s} straight-walking peaks: mean {np.mean(values):.1f} deg, "
              f"range {min(values):.1f}-{max(values):.1f} deg ({len(values)} steps)")
    q_gyro = gyro_orientations(args.data, names, t)[:, skeleton.order(names)]
    cal_gyro = body.calibrate(skeleton, q_gyro[window], heading="pelvis",
                              forward_axis=PELVIS_FORWARD_AXIS)
    gyro_angles = body.joint_angles(skeleton, body.track(skeleton, cal_gyro, q_gyro).q_segment)
    diff = {s: np.abs(gyro_angles.degrees(f"{s}_knee")[:, 0] - knees[s]) for s in knees}
    print("  cross-check, gyro integration instead of the device quaternions: knee flexion "
          f"differs by median {np.median(np.concatenate(list(diff.values()))):.1f} deg, "
          f"max {max(d.max() for d in diff.values()):.1f} deg")
    hip = np.concatenate([angles.degrees(f"{s}_hip")[moving, 0] for s in ("left", "right")])
    print(f"  hip flexion over the recording: {hip.min():.1f} to {hip.max():.1f} deg")

    body.write_bvh(args.out / "xio_lower_body.bvh", skeleton, pose.q_segment, 1.0 / RATE_HZ)
    body.write_sto(args.out / "xio_lower_body_orientations.sto", skeleton, t0, pose.q_segment)
    body.write_joint_angles_csv(args.out / "xio_lower_body_angles.csv", t0, angles)
    left = angles.degrees("left_knee")[:, 0]
    frames = [int(window.start)] + [int(i) for i in np.argsort(-left)[:1]]
    steps, _ = find_peaks(left, height=20.0, distance=int(0.5 * RATE_HZ))
    steps = steps[left[steps] < HIGH_KNEE_DEG]
    if steps.size:
        s = int(steps[0])
        frames += [s - int(0.3 * RATE_HZ), s, s + int(0.3 * RATE_HZ)]
    frames = sorted(set(frames))
    body.plot_stick_figures(
        args.out / "xio_lower_body_sticks.png", skeleton, pose.joints_m, pose.ends_m, frames,
        labels=[f"{t0[i]:.2f} s" for i in frames], heading_quat=cal.heading_quat,
        title="x-IMU3 lower body (device quaternions, pelvis heading)",
    )
    print(f"\nwrote BVH, .sto, CSV and PNG to {args.out}")
    try:
        import bvhio
    except ImportError:
        print("  (bvhio not installed: BVH read-back check skipped)")
    else:
        hierarchy = bvhio.readAsHierarchy(str(args.out / "xio_lower_body.bvh"))
        nodes = {j.Name: j for j, _, _ in hierarchy.layout()}
        m = body.bvh_axes("ENU")
        worst = 0.0
        for f in range(0, t.size, 10):
            hierarchy.loadPose(f, recursive=True)
            for i, name in enumerate(skeleton.names):
                p = m.T @ np.array(nodes[name].PositionWorld, dtype=float) / 100.0
                worst = max(worst, float(np.abs(p - pose.joints_m[f, i]).max()))
        print(f"  BVH read back with bvhio: joint positions within {worst:.1e} m "
              f"of the body model ({len(range(0, t.size, 10))} frames)")

    n_rep = max(1, 100_000 // t.size)
    big = np.tile(q, (n_rep, 1, 1))

    def vectorised() -> object:
        p = body.track(skeleton, cal, big)
        return body.joint_angles(skeleton, p.q_segment)

    small = q[:2000]
    fast = measure("margtrack.body (numpy, vectorised)", vectorised, big.shape[0])
    slow = measure("per-frame loop, scipy Rotation", lambda: scipy_loop(skeleton, cal.offsets,
                   small), small.shape[0], repeats=1)
    ref = scipy_loop(skeleton, cal.offsets, small)
    diff = np.abs(body.track(skeleton, cal, small).joints_m - ref).max()
    print(f"\nspeed ({len(skeleton)} segments per frame; frames/s):")
    for th in (fast, slow):
        print(f"  {th.label:<38} {th.samples_per_s:12.0f}  ({th.us_per_sample:.2f} us/frame)")
    print(f"  ratio vectorised / loop: {fast.ratio_to(slow):.0f}x; joint positions agree to "
          f"{diff:.1e} m")


if __name__ == "__main__":
    main()
