"""Where each BROAD trial's field points in the truth's earth frame: at rest and moving.

Run ``python benchmarks/broad_field_north.py [--folder ../shared/data/broad]``.

Each field sample is carried into the earth frame (ENU) by the optical truth, and the
median of those vectors is taken over three spans: the rest before the movement mask's
first sample, the movement, the rest after its last. Printed per trial: the heading of
each median (deg from north towards east: 0 where the field's horizontal part points to
the truth's north), its dip (deg below the horizon), and the standard deviation of the
single samples' headings while moving.

What it shows (docs/methods.md, "smoother"): at rest the field points to the truth's
north within about a degree, while the sensor moves its mean points a few degrees away.
A smoother takes the movement's heading from the movement's field, so its heading error
over the movement is about that offset; nothing in the estimator is measured here.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from margtrack import frames
from margtrack import quaternion as quat
from margtrack.io.broad import broad_trials, read_broad

DEFAULT_FOLDER = Path(__file__).resolve().parents[2] / "shared" / "data" / "broad"


def heading_and_dip_deg(field_enu: np.ndarray) -> tuple[float, float]:
    """deg, the heading (from north towards east) and dip of the median of (N, 3) ENU
    field vectors; nan when there are none."""
    if field_enu.shape[0] == 0:
        return float("nan"), float("nan")
    east, north, up = np.median(field_enu, axis=0)
    return (float(np.degrees(np.arctan2(east, north))),
            float(np.degrees(np.arctan2(-up, np.hypot(east, north)))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--folder", type=Path, default=DEFAULT_FOLDER)
    args = parser.parse_args()
    print("field in the truth's earth frame: heading (dip), deg")
    print(f"{'trial':42s} {'rest before':>14s} {'moving':>14s} {'rest after':>14s} "
          f"{'sd moving':>9s}")
    for trial in broad_trials(args.folder):
        rec = read_broad(trial.path)
        field = quat.rotate(frames.convert(rec.quat_true, rec.frame, "ENU"), rec.mag)
        known = np.all(np.isfinite(field), axis=1)
        moving = np.flatnonzero(rec.movement)
        index = np.arange(rec.t.size)
        spans = (index < moving[0], rec.movement, index > moving[-1])
        cells = []
        for span in spans:
            head, dip = heading_and_dip_deg(field[span & known])
            cells.append(f"{head:6.2f} ({dip:4.1f})" if np.isfinite(head) else "-")
        single = np.degrees(np.arctan2(field[:, 0], field[:, 1]))[rec.movement & known]
        print(f"{trial.name:42s} {cells[0]:>14s} {cells[1]:>14s} {cells[2]:>14s} "
              f"{np.std(single):9.2f}")


if __name__ == "__main__":
    main()
