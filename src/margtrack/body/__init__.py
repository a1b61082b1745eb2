"""Human body model from segment orientations (000, "Quaternion Based Human Body Model").

- :class:`Skeleton` (:mod:`.skeleton`): up to 15 segments rooted at the pelvis, segment
  vectors from body height (Winter 2009, Fig. 4.1) or given per segment; presets ``full``,
  ``lower``, ``left_arm``/``right_arm``, ``left_leg``/``right_leg``.
- :func:`calibrate` (:mod:`.offsets`): sensor-to-segment offsets from a still reference pose
  (000, eq. 10), heading from magnetic north or from the pelvis sensor.
- :func:`segment_orientations`, :func:`positions`, :func:`track` (:mod:`.kinematics`):
  ``q_segment = q_sensor ⊗ q_offset`` (eq. 7) and joint positions (eq. 11).
- :func:`joint_angles` (:mod:`.joints`): hip, knee, ankle, shoulder, elbow, X-Y-Z Cardan.
- Gait (:mod:`.gait`): :func:`analyse_gait` finds heel strikes and toe offs in the shank
  (or foot) gyroscope and the cycles of each leg (:class:`SideGait`: stance %, cadence);
  :func:`normalise_cycles` puts a signal over 0-100 % of each cycle.
- Root (:mod:`.root`): :func:`root_from_contacts` moves the root (pelvis) with the foot
  contacts, the stance foot held still (:class:`RootPath`).
- Export: :func:`write_bvh`, :func:`write_sto` (OpenSim quaternion table),
  :func:`write_joint_angles_csv`; :func:`plot_stick_figures` draws frames with matplotlib,
  :func:`plot_joint_angles` the angle curves, :func:`plot_gait_cycles` the angles over the
  gait cycle.
- The workflow (:mod:`.workflow`, ``margtrack body``): :func:`read_body` reads a
  multi-sensor recording, :func:`read_body_map` a sensor -> segment map, and
  :func:`process_body` filters every sensor, calibrates and returns a :class:`BodyResult`
  (joint angles, pose, gait, root path, summary, ``write(outdir)``); with ``no_mag``
  (``--no-mag``) :func:`chain_orientations` (:mod:`.chain`) estimates the pelvis 6-D and
  ties every other segment to its parent across the joint (:class:`ConstrainedJoint`).

Arrays are frames first, then segments in the skeleton's order: (N, S, 4) quaternions,
(N, S, 3) positions in metres, in the skeleton's earth frame (ENU default, or NED).
"""

from __future__ import annotations

from margtrack.body.chain import ConstrainedJoint, chain_orientations
from margtrack.body.export_bvh import bvh_axes, write_bvh
from margtrack.body.export_csv import read_joint_angles_csv, write_joint_angles_csv
from margtrack.body.export_sto import OPENSENSE_NAMES, opensim_axes, read_sto, write_sto
from margtrack.body.gait import SideGait, analyse_gait, normalise_cycles
from margtrack.body.inputs import read_body
from margtrack.body.joints import JOINTS, JointAngles, cardan_xyz, joint_angles
from margtrack.body.kinematics import (
    BodyPose,
    positions,
    resample_orientations,
    segment_orientations,
    track,
)
from margtrack.body.mapping import BodyMap, read_body_map
from margtrack.body.offsets import Calibration, average_quaternions, calibrate, still_window
from margtrack.body.plot import plot_gait_cycles, plot_joint_angles, plot_stick_figures
from margtrack.body.root import RootPath, root_from_contacts
from margtrack.body.skeleton import (
    ALIASES,
    PRESETS,
    SEGMENT_NAMES,
    WINTER_FRACTIONS,
    Segment,
    Skeleton,
    body_axes,
    dimensions_from_height,
)
from margtrack.body.workflow import BodyResult, SensorReport, process_body

__all__ = [
    "ALIASES",
    "JOINTS",
    "OPENSENSE_NAMES",
    "PRESETS",
    "SEGMENT_NAMES",
    "WINTER_FRACTIONS",
    "BodyMap",
    "BodyPose",
    "BodyResult",
    "Calibration",
    "ConstrainedJoint",
    "JointAngles",
    "RootPath",
    "Segment",
    "SensorReport",
    "SideGait",
    "Skeleton",
    "analyse_gait",
    "average_quaternions",
    "body_axes",
    "bvh_axes",
    "calibrate",
    "cardan_xyz",
    "chain_orientations",
    "dimensions_from_height",
    "joint_angles",
    "normalise_cycles",
    "opensim_axes",
    "plot_gait_cycles",
    "plot_joint_angles",
    "plot_stick_figures",
    "positions",
    "process_body",
    "read_body",
    "read_body_map",
    "read_joint_angles_csv",
    "read_sto",
    "resample_orientations",
    "root_from_contacts",
    "segment_orientations",
    "still_window",
    "track",
    "write_bvh",
    "write_joint_angles_csv",
    "write_sto",
]
