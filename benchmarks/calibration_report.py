"""Recovered-vs-true tables of margtrack.calibration on simulated sensors with known errors.

Run: ``python benchmarks/calibration_report.py [--out DIR]``. Prints markdown tables for the
accelerometer (six-position, 12-parameter, norm fit), magnetometer (ellipsoid, min/max),
gyroscope (null, eq. 5, full matrix), Allan variance (against the simulated densities and
allantools), the guided 18-step procedure, and the BROAD-style errors (total / heading /
inclination RMSE, deg) of TRIAD and gyro integration before and after calibration. Writes
``allan.png`` and ``guided_procedure.png`` to DIR (default ``calibration_report``).
"""

from __future__ import annotations

import argparse
import itertools
import math
from pathlib import Path

import numpy as np
from scipy.linalg import sqrtm

from margtrack import methods, sim
from margtrack import quaternion as qt
from margtrack.bench.broad import evaluate_recording
from margtrack.calibration import (
    GuidedCalibration,
    TriadCalibration,
    allan_deviation,
    fit_ellipsoid,
    fit_known_directions,
    fit_norm,
    identify_noise,
    min_max,
    plot_allan,
    segment_means,
    simulate_procedure,
    six_position,
    static_segments,
)
from margtrack.calibration.accelerometer import choose_accel_model
from margtrack.calibration.gyroscope import gyro_from_turns
from margtrack.calibration.simulate_procedure import error_profile

F = 50.0


def table(title, header, rows):
    print(f"\n### {title}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for row in rows:
        print("| " + " | ".join(str(c) for c in row) + " |")


def fmt(values, digits=4):
    return ", ".join(f"{v:+.{digits}f}" for v in np.ravel(values))


def accelerometer(profile):
    _, errors, _ = error_profile(profile)
    ups = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    ups += [(sx, sy, sz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    targets = [qt.multiply(qt.from_axis_angle([0, 0, 1], np.radians(17.0 * k)),
                           qt.shortest_arc(np.array(u, float), np.array([0.0, 0.0, -1.0])))
               for k, u in enumerate(ups)]
    steps = [sim.Hold(2.0)]
    for prev, nxt in itertools.pairwise(targets):
        rotvec = qt.to_rotvec(qt.multiply(nxt, qt.conjugate(prev)))
        steps += [sim.Rotate(tuple(rotvec), np.degrees(np.linalg.norm(rotvec)), 60.0),
                  sim.Hold(2.0)]
    rec = sim.simulate(sim.rotation_sequence(steps, 100.0, q0=targets[0]), frame="NED",
                       acc_errors=errors, seed=5)
    means = segment_means(rec.acc, static_segments(rec))
    six = six_position(means[:6])
    rows = [["true", fmt(100 * np.array(errors.scale), 3), fmt(errors.bias),
             fmt(errors.misalignment_deg, 3)]]
    rows.append(["six-position (eqs. 1-2)", fmt(100 * (1 / six.scale - 1), 3),
                 fmt(six.null_m_s2), "not modelled"])
    for name, fit in (("12-parameter, 6 poses", fit_known_directions(means[:6])),
                      ("norm fit, 14 free poses", fit_norm(means))):
        scale, mis, _ = TriadCalibration("acc", fit.matrix).decompose()
        rows.append([name, fmt(100 * scale, 3), fmt(fit.bias), fmt(mis, 3)])
    # the model `margtrack calibrate accel` would choose for these 14 poses (same function)
    choice = choose_accel_model(means)
    scale, mis, _ = choice.chosen.decompose()
    rows.append([f"calibrate accel's choice: {choice.chosen_name}", fmt(100 * scale, 3),
                 fmt(choice.chosen.b), fmt(mis, 3)])
    table(f"Accelerometer, profile {profile} (MEMS noise, 2 s holds at 100 Hz); "
          "tolerance 0.1 %, 0.01 m/s², 0.05 deg",
          ["method", "scale error (%)", "bias (m/s²)", "misalignment αx αy αz (deg)"], rows)


def magnetometer(profile):
    _, _, errors = error_profile(profile)
    k = errors.matrix()
    s_true = np.real(sqrtm(k @ k.T))
    tumble = sim.simulate(sim.random_motion(60.0, 100.0, seed=1), frame="NED", field_ut=F,
                          mag_errors=errors, seed=2)
    fit = fit_ellipsoid(tumble.mag, field_ut=F)
    proc = simulate_procedure(*error_profile(profile), seed=4, field_ut=F)
    spans = {label: (t0, t1) for _, label, t0, t1 in proc.meta["procedure"]}

    def turn(label):
        t0, t1 = spans[label]
        return proc.mag[(proc.t >= t0) & (proc.t <= t1)]

    s15, s16 = min_max(turn("turn 360 deg about +y")), min_max(turn("turn 360 deg about +x"))
    turns = min_max(None, F, max_ut=[s15.max_ut[0], s16.max_ut[1], s16.max_ut[2]],
                    min_ut=[s15.min_ut[0], s16.min_ut[1], s16.min_ut[2]])
    free = min_max(tumble.mag, F)
    sens = np.linalg.norm(k, axis=1)
    rows = [
        ["ellipsoid fit, 60 s tumble", fmt(fit.offset_ut, 3),
         f"{100 * np.linalg.norm(fit.offset_ut - errors.bias) / F:.3f}",
         f"{100 * np.linalg.norm(fit.soft_iron - s_true, 2):.3f}",
         f"coverage {100 * fit.coverage:.0f} %, residual {fit.residual_rms_ut:.2f} µT"],
        ["min/max on 000 steps 15-16", fmt(turns.null_ut, 3),
         f"{100 * np.linalg.norm(turns.null_ut - errors.bias) / F:.3f}",
         f"{100 * np.max(np.abs(1 / turns.scale - sens)):.3f} (diagonal only)",
         "cross-axis soft iron not modelled"],
        ["min/max on the tumble", fmt(free.null_ut, 3),
         f"{100 * np.linalg.norm(free.null_ut - errors.bias) / F:.3f}",
         f"{100 * np.max(np.abs(1 / free.scale - sens)):.3f} (diagonal only)",
         "extremes never reached"],
    ]
    table(f"Magnetometer, profile {profile}: true hard iron {fmt(errors.bias, 3)} µT, "
          f"F = {F} µT; tolerance 1 % of F",
          ["method", "hard iron (µT)", "hard-iron error (% F)", "soft-iron error (% F)",
           "quality / limits"], rows)


def gyroscope(profile):
    errors = error_profile(profile)[0]
    q = qt.identity()
    steps = [sim.Hold(3.0)]
    known = []
    for axis in np.eye(3):
        for angle in (90.0, -180.0, 90.0):
            steps += [sim.Rotate(tuple(qt.rotate(q, axis)), angle, 90.0), sim.Hold(2.0)]
            q = qt.multiply(qt.from_axis_angle(qt.rotate(q, axis), np.radians(angle)), q)
            known.append(angle)
    rec = sim.simulate(sim.rotation_sequence(steps, 100.0), frame="NED", gyr_errors=errors,
                       seed=8)
    # the turn detection of `margtrack calibrate gyro` (same function): multiples of 90 deg
    found = gyro_from_turns(rec.t, rec.gyr, static_segments(rec), 90.0)
    detected = [r.known_deg for r in found.rotations]
    if detected != known or found.skipped_deg:
        raise SystemExit(f"turn detection found {detected} (skipped {len(found.skipped_deg)}), "
                         f"the script turned {known}")
    null, eq5 = found.null, found.scale.scale_factor
    rows = [["null (deg/s)", fmt(np.degrees(errors.bias)), fmt(np.degrees(null.null_rad_s)),
             fmt(np.degrees(null.null_rad_s - errors.bias)),
             f"floor {fmt(np.degrees(null.noise_floor_rad_s))}"],
            ["sensitivity 1/eq. 5 - 1 (%)", fmt(100 * (np.diag(errors.matrix()) - 1), 3),
             fmt(100 * (1 / eq5 - 1), 3), fmt(100 * (1 / eq5 - np.diag(errors.matrix())), 4),
             "tolerance 0.2 %"]]
    table(f"Gyroscope, profile {profile}: 3 s still, then +90/-180/+90 about x, y, z",
          ["figure", "true", "recovered", "error", "note"], rows)


def allan(out_dir):
    gyr = sim.SensorErrors(noise_density=math.radians(0.005),
                           bias_random_walk=math.radians(0.001))
    acc = sim.SensorErrors(noise_density=150e-6 * 9.80665, bias_random_walk=1e-4)
    rate_hz, n = 5.0, 216_000
    rng = np.random.default_rng(21)
    yg, ya = gyr.apply(np.zeros((n, 3)), rate_hz, rng), acc.apply(np.zeros((n, 3)), rate_hz, rng)
    dg, da = allan_deviation(yg, rate_hz), allan_deviation(ya, rate_hz)
    tg, ta = identify_noise(dg), identify_noise(da)
    import allantools

    worst = max(float(np.max(np.abs(allantools.oadev(y[:, c], rate=rate_hz, data_type="freq",
                                                     taus=d.tau_s)[1] / d.adev[:, c] - 1)))
                for y, d in ((yg, dg), (ya, da)) for c in range(3))
    rows = [
        ["gyr N (rad/s/√Hz)", f"{gyr.noise_density:.4g}", fmt(tg.white / gyr.noise_density)],
        ["gyr K (rad/s/√s)", f"{gyr.bias_random_walk:.4g}",
         fmt(tg.random_walk / gyr.bias_random_walk)],
        ["acc N (m/s²/√Hz)", f"{acc.noise_density:.4g}", fmt(ta.white / acc.noise_density)],
        ["acc K (m/s³/√Hz)", f"{acc.bias_random_walk:.4g}",
         fmt(ta.random_walk / acc.bias_random_walk)],
    ]
    table(f"Allan variance, 12 h still at 5 Hz; max |ours/allantools - 1| = {worst:.1e}; "
          "tolerance 10 %", ["term", "true", "recovered / true (x, y, z)"], rows)
    plot_allan([("gyroscope", dg, tg, "rad/s"), ("accelerometer", da, ta, "m/s²")],
               out_dir / "allan.png")


def guided(profile, out_dir):
    gyr, acc, mag = error_profile(profile)
    rec = simulate_procedure(gyr, acc, mag, seed=1, field_ut=F)
    machine = GuidedCalibration()
    machine.add_recording(rec)
    result = machine.result()
    cal = result.calibration
    rows = []
    for name, triad, errors, unit, factor in (
            ("gyr", cal.gyr, gyr, "deg/s", 180 / math.pi), ("acc", cal.acc, acc, "m/s²", 1.0),
            ("mag", cal.mag, mag, "µT", 1.0)):
        scale, mis, rot = triad.decompose()
        true_scale = np.array(errors.scale)
        if name == "mag":  # the file keeps the sensor's average unit (det K = 1)
            true_scale = np.linalg.norm(errors.matrix(), axis=1) / np.linalg.det(
                errors.matrix()) ** (1 / 3) - 1
        rows.append([f"{name} bias ({unit})", fmt(np.array(errors.bias) * factor),
                     fmt(triad.b * factor)])
        rows.append([f"{name} scale (%)", fmt(100 * true_scale, 3), fmt(100 * scale, 3)])
        rows.append([f"{name} misalignment (deg)", fmt(errors.misalignment_deg, 3),
                     fmt(mis, 3) + f" (triad rotation {rot:.3f})"])
    ref = result.reference
    rows.append(["dip (deg), field", f"{sim.DEFAULT_DIP_DEG}, {F} µT",
                 f"{ref.dip_deg:.3f}, {ref.field_ut:.3f} (sensor unit)"])
    table(f"Guided 18-step procedure, profile {profile} ({rec.duration_s:.0f} s recording)",
          ["figure", "true", "recovered"], rows)
    test = sim.simulate(sim.random_motion(60.0, 100.0, seed=5), gyr_errors=gyr,
                        acc_errors=acc, mag_errors=mag, seed=6)
    rows = []
    for method in ("triad", "gyro"):
        before, _ = evaluate_recording(methods.create(method), test)
        after, _ = evaluate_recording(methods.create(method), cal.apply(test))
        rows.append([method, *(f"{getattr(before, k):.3f} → {getattr(after, k):.3f}" for k in
                               ("total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg"))])
    table(f"BROAD-style RMSE (deg) on 60 s of simulated random motion, profile {profile}: "
          "raw → calibrated by the guided procedure", ["method", "total", "heading",
                                                       "inclination"], rows)
    if profile == "raw":
        plot_procedure(rec, machine, out_dir / "guided_procedure.png")


def plot_procedure(rec, machine, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(12, 6), sharex=True)
    a1.plot(rec.t, rec.acc, lw=0.8)
    a1.set_ylabel("acc (m/s²)")
    a2.plot(rec.t, np.degrees(rec.gyr), lw=0.8)
    a2.set_ylabel("gyr (deg/s)")
    a2.set_xlabel("t (s)")
    for start, stop in static_segments(rec):
        for ax in (a1, a2):
            ax.axvspan(rec.t[start], rec.t[stop - 1], color="0.85", zorder=0)
    for e in machine.events:
        if e.kind == "done":
            a1.annotate(str(e.message.split(":")[0].replace("step ", "")), (e.t_s, 11.5),
                        fontsize=8, ha="center")
            a1.axvline(e.t_s, color="g", lw=0.6)
    a1.set_title("guided procedure: still periods (grey) and completed steps (green)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("calibration_report"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for profile in ("mems", "raw"):
        accelerometer(profile)
        magnetometer(profile)
        gyroscope(profile)
    allan(args.out)
    for profile in ("mems", "raw"):
        guided(profile, args.out)
    print(f"\nplots: {args.out / 'allan.png'}, {args.out / 'guided_procedure.png'}")


if __name__ == "__main__":
    main()
