"""Where the live walking root's drift on the x-IMU3 walk comes from.

The x-IMU3 lower-body walk (../shared/data/xio_lower_body) is run through the live engine
(the replay's frames, its own calibration on the still start, the walking root) and
through ``margtrack body`` (``process_body``). The root's horizontal path length and its
end's distance from its start (the walk returns where it began) are printed for:

1. live: live orientations, causal gait events (:class:`GaitEvents`), causal anchor;
2. offline: offline orientations, two-sided gait events (:func:`analyse_gait`), anchor
   from the whole recording (:func:`root_from_contacts`);
3. offline orientations with the live causal root (:class:`WalkingRoot` fed frame by
   frame): what the causal events and anchor change alone;
4. live orientations (the engine's, the final calibration) with the offline root: what
   the orientations change alone;
5. live orientations with the live causal root, fed here frame by frame.

Then, for 3 against 2 (the same orientations), the 0.5 s windows where the two roots'
steps differ by more than 0.1 m in all, with the share of those frames in which the
offline events have a foot in stance: where the causal and the two-sided gait events
disagree.

Run: python benchmarks/walking_root_drift.py [--folder ../shared/data/xio_lower_body]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from margtrack import io
from margtrack.body import process_body
from margtrack.body.gait import analyse_gait, sagittal_rate, segment_rates
from margtrack.body.mapping import parse_axis
from margtrack.body.root import root_from_contacts, stance
from margtrack.body.segments import body_axes
from margtrack.body.workflow import DEFAULT_FORWARD_AXIS
from margtrack.live.avatars import Avatars
from margtrack.live.engine import Engine
from margtrack.live.replay import replay_path
from margtrack.live.walking_root import WalkingRoot

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "xio_lower_body"


def _figures(position_m: np.ndarray, frame: str) -> tuple[float, float]:
    """(path length, end's distance from the start) of a root path (N, 3) m, horizontal."""
    up = body_axes(frame)[2]
    h = position_m - np.outer(position_m @ up, up)
    return (float(np.linalg.norm(np.diff(h, axis=0), axis=1).sum()),
            float(np.linalg.norm(h[-1] - h[0])))


def live_run(folder: Path):
    """The engine over the replayed walk: (times s, the recording, raw gyr (S, N, 3))."""
    source = replay_path(folder, speed=math.inf)
    engine = Engine(source.info, "default", heading="pelvis",
                    forward_axis=parse_axis(DEFAULT_FORWARD_AXIS), calibrate_at_start=True,
                    walking_root=True)
    engine.start_recording()
    source.open()
    while not source.finished:
        engine.push(source.poll(0.0), now_s=0.0)
    engine.push([], now_s=1e9, flush=True)
    return engine, engine.stop_recording(), source


def causal_root(skeleton, q_segment: np.ndarray, t_s: np.ndarray, gyr_segment: np.ndarray
                ) -> np.ndarray:
    """The live causal root (:class:`WalkingRoot`) over given orientations (N, K, 4) and
    segment-frame rates (N, K, 3) rad/s, frame by frame: (N, 3) m."""
    avatars = Avatars.from_names(skeleton.names, 1.75, skeleton.frame)  # both default 1.75 m
    root = WalkingRoot(avatars)
    sag = np.stack([sagittal_rate(gyr_segment[:, k], skeleton.frame)
                    for k in root.gait_segments])  # (2, N)
    contact = avatars.index[0][root.contact_sensors[0]]
    rates = np.linalg.norm(gyr_segment[:, contact], axis=2)  # (N, 2)
    out = np.empty((t_s.size, 3))
    for k in range(t_s.size):
        root.gait.step(t_s[k:k + 1], sag[None, :, k:k + 1])
        out[k] = root.update(float(t_s[k]), q_segment[k][None], rates[k][None])[0]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folder", type=Path, default=DATA)
    args = parser.parse_args()
    engine, rec, source = live_run(args.folder)
    sk = engine.avatars.skeleton
    walked = ~np.isnan(rec.root_m[:, 0, 0])
    rows = [("1 live (live q, causal root)", _figures(rec.root_m[walked, 0], sk.frame))]

    body = process_body(io.read_xio_body(args.folder))
    t_off = body.t_s - body.t_s[0]
    rows.append(("2 offline (offline q, two-sided events)",
                 _figures(body.root.position_m, sk.frame)))
    rows.append(("3 offline q, live causal root",
                 _figures(causal_root(body.skeleton, body.pose.q_segment, t_off,
                                      body.gyr_segment), sk.frame)))

    q_live = rec.segment_orientations(0)[walked]
    t_live = rec.t_s[walked]
    order = engine.avatars.index[0]  # the sensor of every segment
    gyr = segment_rates(t_live, [source.t_s - source.t_s[0]] * len(order),
                        [source.gyr[s] for s in order], rec.calibrations[0].offsets)
    gait = analyse_gait(t_live, sk, gyr)
    live_offline = root_from_contacts(sk, q_live, t_live,
                                      {s: g.heel_strike_s for s, g in gait.items()},
                                      {s: g.toe_off_s for s, g in gait.items()})
    rows.append(("4 live q, offline root", _figures(live_offline.position_m, sk.frame)))
    rows.append(("5 live q, live causal root (final calibration)",
                 _figures(causal_root(sk, q_live, t_live, gyr), sk.frame)))
    for name, (length, drift) in rows:
        print(f"{name:50s} walks {length:5.2f} m, ends {drift:4.2f} m from its start")
    causal = causal_root(body.skeleton, body.pose.q_segment, t_off, body.gyr_segment)
    gap = np.linalg.norm(np.diff(causal[:, :2] - body.root.position_m[:, :2], axis=0), axis=1)
    in_stance = [stance(t_off, body.gait[s].heel_strike_s, body.gait[s].toe_off_s)[0]
                 for s in ("left", "right")]
    span = max(1, round(0.5 / float(np.median(np.diff(t_off)))))
    total = 0.0
    for i in range(0, gap.size, span):
        part = slice(i, i + span)
        if gap[part].sum() > 0.1:
            total += gap[part].sum()
            print(f"  {t_off[i]:5.1f} s +0.5 s: steps differ by {gap[part].sum():.2f} m; "
                  f"offline stance left {in_stance[0][part].mean():.0%}, "
                  f"right {in_stance[1][part].mean():.0%}")
    print(f"  those windows: {total:.2f} m of {gap.sum():.2f} m of step differences")


if __name__ == "__main__":
    main()
