"""From a multi-sensor recording to joint angles: filter, common time base, calibration, model.

:func:`process_body` takes one :class:`~margtrack.recording.Recording` per sensor (e.g. from
:func:`margtrack.body.inputs.read_body`) and

1. matches sensors to segments (names or a map, :mod:`margtrack.body.mapping`) and builds
   the skeleton of those segments (:meth:`Skeleton.from_segments`);
2. estimates every sensor's orientation with a margtrack method (``-m``/``-p`` as in
   ``margtrack run``) on its own timestamps, in the skeleton's earth frame; with
   ``no_mag`` (``--no-mag``) only the root sensor, 6-D, and every other segment chained
   to its parent across the joint (:mod:`.chain`);
3. brings the orientations onto one time base by slerp: the span all sensors cover, at
   ``rate_hz`` (default: the slowest sensor's rate, rounded to a whole Hz when within 1 %);
   a frame interpolated across a sensor gap longer than ``max_gap_s`` gets that sensor's
   ``GAP`` flag, and every frame carries the flags of the sensor samples around it;
4. calibrates the sensor-to-segment offsets on the reference pose (000, eq. 10): a given
   window, or the first still second, heading from north or from the pelvis sensor;
5. computes the body pose (000, eqs. 7, 11) and the joint angles (:mod:`.joints`);
6. detects the gait events and cycles of each leg from its shank (else foot) gyroscope
   turned into the segment frame (:mod:`.gait`), and moves the root (pelvis) with the foot
   contacts (:mod:`.root`; both legs needed, else the root stays put).

The result, :class:`BodyResult`, prints a summary (calibration spread per sensor, range of
motion per joint, knee flexion peaks, gait cycles, the root's path) and writes its files
(:mod:`margtrack.body.outputs`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.body.chain import ConstrainedJoint, chain_orientations
from margtrack.body.gait import SideGait, analyse_gait, segment_rates
from margtrack.body.joints import JointAngles, joint_angles
from margtrack.body.kinematics import BodyPose, resample_orientations, track
from margtrack.body.mapping import BodyMap, assign_segments, parse_axis
from margtrack.body.offsets import Calibration, Heading, calibrate, still_window
from margtrack.body.report import summary_lines
from margtrack.body.root import RootPath, leg_ends, root_from_contacts
from margtrack.body.skeleton import Skeleton
from margtrack.recording import Recording
from margtrack.time_base import common_time_base, flags_on_time_base
from margtrack.units import UnitError

Array = NDArray[np.float64]

__all__ = ["DEFAULT_FORWARD_AXIS", "BodyResult", "SensorReport", "process_body"]

#: The pelvis sensor's forward axis when none is given: ``-z``, an x-IMU3 on the sacrum
#: with its z axis out of the back (../shared/data/xio_lower_body).
DEFAULT_FORWARD_AXIS = (0.0, 0.0, -1.0)
#: Share of samples with an unusable field above which a magnetometer counts as dead.
DEAD_MAG_SHARE = 0.5


@dataclass(frozen=True)
class SensorReport:
    """What happened to one sensor: its segment, rate, span, flags and magnetometer.

    ``span_s`` is on the recording's own clock; ``flag_counts`` counts the estimator's flags
    over the sensor's own samples; ``mag_unusable_share`` is the share of samples whose field
    was absent, zero, clipped or stuck (``MAG_IGNORED``); ``gap_frames`` counts the common
    frames interpolated across a gap longer than ``max_gap_s``.
    """

    sensor: str
    segment: str
    n_samples: int
    rate_hz: float
    span_s: tuple[float, float]
    flag_counts: Mapping[str, int]
    mag_unusable_share: float
    gap_frames: int

    @property
    def mag_dead(self) -> bool:
        """True when the magnetometer is absent or unusable for most samples."""
        return self.mag_unusable_share > DEAD_MAG_SHARE


@dataclass(frozen=True, eq=False)
class BodyResult:
    """Joint angles and body pose of a multi-sensor recording (module docstring).

    Attributes
    ----------
    skeleton : the body model (segments of the sensors, skeleton order, earth frame).
    calibration : sensor-to-segment offsets, heading, spread per sensor.
    t_s : (N,) s, the common time base on the sensors' clock; ``t_rel_s`` starts at 0.
    q_sensor : (N, S, 4) sensor to earth, skeleton order.
    pose : segment orientations and joint positions (m), the root moving with ``root``.
    angles : joint angles (rad).
    window : the calibration frames (``slice``).
    sensors : one :class:`SensorReport` per segment, skeleton order.
    frame_flags : (N, S) uint16, per common frame and sensor (module docstring, step 3).
    method, params : the estimation method and its parameters.
    forward_axis : the pelvis sensor's forward axis (heading ``"pelvis"``), else None.
    notes : warnings for people (sensors left out, cropped spans, dead magnetometers...).
    gyr_segment : (N, S, 3) rad/s, every sensor's gyroscope in its segment frame.
    gait : ``"left"``/``"right"`` -> :class:`SideGait`, times in s from the first frame
        (the legs with a shank or foot sensor).
    root : the root's path from the foot contacts, or None without both legs (the root
        then stays at ``skeleton.root_position_m``).
    constrained : with ``no_mag``, the joints that tied each segment to its parent, with
        their lever arms (:class:`~margtrack.body.chain.ConstrainedJoint`); else empty.
    valid_from : the first frame whose angles count in :meth:`range_of_motion`: the end
        of the calibration window, or with the online joint chain (``no_mag`` without
        ``offline``, calibrated on a pose after every joint moved) the frame from which
        every joint's relative heading was found. None: the end of the calibration.
    """

    skeleton: Skeleton
    calibration: Calibration
    t_s: Array
    q_sensor: Array
    pose: BodyPose
    angles: JointAngles
    window: slice
    sensors: tuple[SensorReport, ...]
    frame_flags: NDArray[np.uint16]
    method: str
    params: Mapping[str, Any]
    forward_axis: Array | None
    notes: tuple[str, ...]
    gyr_segment: Array
    gait: Mapping[str, SideGait]
    root: RootPath | None
    constrained: tuple[ConstrainedJoint, ...] = ()
    valid_from: int | None = None

    @property
    def t_rel_s(self) -> Array:
        """(N,) s from the first common frame (the time column of every output)."""
        return self.t_s - self.t_s[0]

    @property
    def rate_hz(self) -> float:
        """Frame rate of the common time base, Hz."""
        return float(1.0 / np.median(np.diff(self.t_s)))

    def range_of_motion(self) -> list[tuple[str, str, float, float]]:
        """``(joint, component, min_deg, max_deg)`` over the frames from
        :attr:`range_from_s` on."""
        after = slice(self._range_start(), None)
        rows = []
        for j, (joint, comps) in enumerate(zip(self.angles.names, self.angles.components,
                                               strict=True)):
            deg = np.degrees(self.angles.angles_rad[after, j, :])
            rows += [(joint, c, float(deg[:, k].min()), float(deg[:, k].max()))
                     for k, c in enumerate(comps)]
        return rows

    def _range_start(self) -> int:
        start = self.window.stop if self.valid_from is None else self.valid_from
        return start if start < self.t_s.size else 0

    @property
    def range_from_s(self) -> float:
        """Where :meth:`range_of_motion` starts, s from the first frame."""
        return float(self.t_rel_s[self._range_start()])

    def peaks(self, joint: str, component: int = 0, height_deg: float = 20.0,
              min_separation_s: float = 0.5) -> tuple[Array, Array]:
        """Times (s from the start) and values (deg) of the peaks of one angle.

        Local maxima above ``height_deg`` at least ``min_separation_s`` apart
        (``scipy.signal.find_peaks``), e.g. knee flexion in swing.
        """
        from scipy.signal import find_peaks

        deg = self.angles.degrees(joint)[:, component]
        idx, _ = find_peaks(deg, height=height_deg,
                            distance=max(1, round(min_separation_s * self.rate_hz)))
        return self.t_rel_s[idx], deg[idx]

    def summary(self) -> list[str]:
        """The printed summary, one line per item (:func:`margtrack.body.report.summary_lines`)."""
        return summary_lines(self)

    def write(self, outdir: str | Path, force: bool = False,
              inputs: Iterable[str | Path] = (), bvh_unit: str = "cm") -> dict[str, Path]:
        """Write the outputs into ``outdir`` (:func:`margtrack.body.outputs.write_outputs`)."""
        from margtrack.body.outputs import write_outputs

        return write_outputs(self, outdir, force=force, inputs=inputs, bvh_unit=bvh_unit)


def _pose_window(t_rel: Array, q: Array, pose_window: tuple[float, float] | None,
                 still_s: float, max_motion_deg: float) -> slice:
    if pose_window is None:
        try:
            return still_window(t_rel, q, still_s, max_motion_deg)
        except ValueError:
            raise ValueError(
                f"no still {still_s:g} s found for the reference pose (every sensor within "
                f"{max_motion_deg:g} deg); give the time of the pose with --pose-window "
                "START,END (s from the start; pose_window=(start, end))"
            ) from None
    try:
        start, end = (float(v) for v in pose_window)
    except (TypeError, ValueError):
        raise ValueError(f"pose_window must be two numbers (start, end) in s, got "
                         f"{pose_window!r}") from None
    if not (np.isfinite(start) and np.isfinite(end) and 0 <= start < end):
        raise ValueError(f"pose window {start:g}-{end:g} s: need 0 <= START < END (s from "
                         "the start of the common time base)")
    idx = np.flatnonzero((t_rel >= start) & (t_rel <= end))
    if idx.size == 0:
        raise ValueError(f"pose window {start:g}-{end:g} s holds no frame; the recording "
                         f"spans 0-{t_rel[-1]:.2f} s (s from the start)")
    return slice(int(idx[0]), int(idx[-1]) + 1)


def _settled_pose_window(t_rel: Array, q: Array, pose_window: tuple[float, float] | None,
                         still_s: float, max_motion_deg: float, settled_s: float) -> slice:
    """The pose window of the online ``no_mag`` chain: after every joint's relative heading
    was found (``settled_s``, s from the start), else refused with the fix."""
    why = (f"with --no-mag the online joint estimate finds a joint's relative heading only "
           f"once the joint moves (every joint from {settled_s:.2f} s on), so ")
    fix = ("use --offline (the whole recording: a pose at the start works), or give a still "
           "pose after the movement with --pose-window START,END")
    if pose_window is not None:
        window = _pose_window(t_rel, q, pose_window, still_s, max_motion_deg)
        if t_rel[window.start] < settled_s:
            raise ValueError(f"pose window from {t_rel[window.start]:.2f} s: {why}a pose "
                             f"before then calibrates with them not yet found; {fix}")
        return window
    first = int(np.searchsorted(t_rel, settled_s))
    try:
        found = still_window(t_rel[first:], q[first:], still_s, max_motion_deg)
    except ValueError:
        raise ValueError(f"no still {still_s:g} s found for the reference pose after "
                         f"{settled_s:.2f} s: {why}the pose must come after that; {fix}"
                         ) from None
    return slice(found.start + first, found.stop + first)


def process_body(
    recordings: Mapping[str, Recording],
    mapping: BodyMap | Mapping[str, str] | None = None,
    method: str = "default",
    params: Mapping[str, Any] | Iterable[str] = (),
    pose_window: tuple[float, float] | None = None,
    heading: Heading = "pelvis",
    *,
    forward_axis: ArrayLike | str | None = None,
    rate_hz: float | None = None,
    height_m: float | None = None,
    frame: str = "ENU",
    align_start: bool = False,
    still_s: float = 1.0,
    max_motion_deg: float = 2.0,
    max_spread_deg: float = 5.0,
    max_gap_s: float = 0.1,
    notes: Iterable[str] = (),
    no_mag: bool = False,
    offline: bool = False,
) -> BodyResult:
    """Joint angles of a multi-sensor recording (module docstring, steps 1-5).

    Parameters
    ----------
    recordings : sensor name -> Recording (SI units; each on its own clock and rate).
    mapping : sensor -> segment (a :class:`BodyMap` or a dict), or None when the sensor
        names are segment names.
    method, params : estimation method and its parameters (``margtrack methods``).
    pose_window : (start, end) s from the start of the common time base, the reference
        pose (standing, facing the heading reference); None: the first still ``still_s``.
    heading : ``"pelvis"`` (the subject faces the pelvis sensor's ``forward_axis``) or
        ``"north"`` (the subject faces magnetic north; every magnetometer must work).
    forward_axis : the pelvis sensor's forward axis (``"-z"`` or a 3-vector); default the
        map's, else :data:`DEFAULT_FORWARD_AXIS`.
    rate_hz : rate of the common time base, Hz (default in the module docstring).
    height_m : body height, m (default the map's, else 1.75); positions only.
    frame : earth frame, ``"ENU"`` or ``"NED"``.
    align_start : re-time every sensor from its first sample (sensors started together on
        unsynchronised clocks).
    still_s, max_motion_deg : the still window searched for without ``pose_window``.
    max_spread_deg : largest motion of a sensor in the pose window, deg.
    max_gap_s : sensor gaps longer than this flag the interpolated frames ``GAP``, s.
    notes : notes of the reading to keep with the result (files left unread...).
    no_mag : no magnetometer: the root sensor 6-D, every other segment chained to its
        parent across the joint (:mod:`margtrack.body.chain`); needs heading ``"pelvis"``.
    offline : with ``no_mag``, the joints' offline (MAP) estimate instead of the online one
        (which finds a joint's relative heading only once it moves: the pose is then looked
        for, and must lie, after :attr:`~margtrack.body.chain.ChainOrientations.settled_s`).
    """
    from margtrack import methods
    from margtrack.estimator.flags import Flag, count_flags

    if not recordings:
        raise ValueError("no sensors: the recording holds no sensor data")
    if heading not in ("north", "pelvis"):
        raise ValueError(f"heading must be 'pelvis' or 'north', got {heading!r}")
    if heading == "north" and forward_axis is not None:
        raise ValueError("forward_axis (--forward-axis) gives the heading from the pelvis "
                         "sensor; leave it out with heading 'north', or use heading 'pelvis'")
    if no_mag and heading == "north":
        raise ValueError("heading 'north' needs the magnetometers, which --no-mag (no_mag=True) "
                         "leaves out; use the pelvis heading (--heading pelvis)")
    if offline and not no_mag:
        raise ValueError("offline (--offline) chooses the joints' estimate of --no-mag; give "
                         "it with --no-mag (no_mag=True)")
    body_map = mapping if isinstance(mapping, BodyMap) or mapping is None else BodyMap(mapping)
    pairs, left_out = assign_segments(list(recordings), body_map)
    skeleton = Skeleton.from_segments(
        list(pairs.values()),
        height_m if height_m is not None else (body_map.height_m if body_map and
                                               body_map.height_m else 1.75),
        frame,
    )
    if len(skeleton) < 2 or not joint_angles(skeleton, np.tile([1.0, 0, 0, 0],
                                                              (len(skeleton), 1))).names:
        raise ValueError(f"the sensors' segments ({', '.join(skeleton.names)}) form no joint "
                         "(hip, knee, ankle, shoulder, elbow); map the sensors to two "
                         "neighbouring segments at least")
    by_segment = {seg: s for s, seg in pairs.items()}
    sensors = [by_segment[n] for n in skeleton.names]
    recs = {s: recordings[s] for s in sensors}
    if align_start:
        recs = {s: replace(r, t=r.t - r.t[0]) for s, r in recs.items()}
    t, span_notes = common_time_base(recs, rate_hz)
    notes = [*notes, *(f"{s}: not in the map, left out" for s in left_out), *span_notes]
    param_values = dict(params) if isinstance(params, Mapping) else dict(
        methods.parse_params_items(params))
    methods.create(method, param_values)  # an unknown method or parameter fails here
    if no_mag:
        chain = chain_orientations(skeleton, sensors, recs, t, method, param_values, frame,
                                   offline)
        q, constrained = chain.q, chain.joints
        used_params, method_name = chain.params, chain.method
        flag_cols, reports = [], []
        for k, (sensor, segment) in enumerate(zip(sensors, skeleton.names, strict=True)):
            rec, own = recs[sensor], chain.sensor_flags[k]
            flag_cols.append(flags_on_time_base(chain.flag_times[k], own, t, max_gap_s))
            reports.append(SensorReport(
                sensor, segment, rec.n_samples, rec.rate_hz,
                (float(rec.t[0]), float(rec.t[-1])), count_flags(own), 1.0,
                int(np.count_nonzero(flag_cols[-1] & int(Flag.GAP)))))
        notes.append("magnetometers not used (--no-mag): the pelvis sensor's heading is its "
                     "gyroscope's, every other segment's follows its parent's across the joint "
                     f"({'offline' if offline else 'online'} joint estimate)")
    else:
        constrained = ()
        q, flag_cols, reports, used_params, method_name = _independent(
            sensors, skeleton, recs, t, method, param_values, frame, max_gap_s)
    dead = [r.sensor for r in reports if r.mag_dead]
    if dead and heading == "north" and not no_mag:
        raise ValueError(
            f"heading 'north' needs every magnetometer, but {', '.join(dead)} has none that "
            "works (absent, zero, clipped or stuck for most samples: flag MAG_IGNORED); use "
            "the pelvis heading (--heading pelvis)"
        )
    for r in reports:
        if r.mag_dead and not no_mag:
            notes.append(
                f"{r.sensor}: magnetometer unusable for {100 * r.mag_unusable_share:.0f} % of "
                "samples (MAG_IGNORED); its heading is the gyroscope's, so the angles of its "
                "joints mix flexion and abduction by that sensor's heading error")
    axis = None
    if heading == "pelvis":
        given = forward_axis if forward_axis is not None else (
            body_map.forward_axis if body_map is not None else None)
        axis = parse_axis(given if given is not None else DEFAULT_FORWARD_AXIS)
    t_rel = t - t[0]
    valid_from = None
    if no_mag and not offline:
        valid_from = int(np.searchsorted(t_rel, chain.settled_s - t[0]))
        window = _settled_pose_window(t_rel, q, pose_window, still_s, max_motion_deg,
                                      chain.settled_s - t[0])
        notes.append(f"online joint estimate (--no-mag without --offline): calibrated on a "
                     f"pose after every joint had moved ({chain.settled_s - t[0]:.2f} s on); "
                     "--offline uses the whole recording and a pose at the start")
    else:
        window = _pose_window(t_rel, q, pose_window, still_s, max_motion_deg)
    try:
        cal = calibrate(skeleton, q[window], heading=heading, forward_axis=axis,
                        max_spread_deg=max_spread_deg)
    except ValueError as exc:
        raise ValueError(f"calibration on {t_rel[window.start]:.2f}-"
                         f"{t_rel[window.stop - 1]:.2f} s: {exc} (--pose-window START,END)"
                         ) from None
    pose = track(skeleton, cal, q)
    angles = joint_angles(skeleton, pose.q_segment)
    gyr = segment_rates(t, [recs[s].t for s in sensors], [recs[s].gyr for s in sensors],
                        cal.offsets)
    gait = analyse_gait(t_rel, skeleton, gyr)
    root = None
    if len(leg_ends(skeleton)) == 2 and set(gait) == {"left", "right"}:
        root = root_from_contacts(
            skeleton, pose.q_segment, t_rel, {s: g.heel_strike_s for s, g in gait.items()},
            {s: g.toe_off_s for s, g in gait.items()})
        moved = root.position_m - skeleton.root_position_m
        pose = replace(pose, joints_m=pose.joints_m + moved[:, None],
                       ends_m=pose.ends_m + moved[:, None])
    elif any(seg.endswith("_thigh") for seg in skeleton.names):
        notes.append("the root stays put: moving it with the foot contacts needs a shank or "
                     "foot sensor on each leg")
    result = BodyResult(skeleton, cal, t, q, pose, angles, window, tuple(reports),
                        np.stack(flag_cols, axis=1), method_name, dict(used_params), axis,
                        tuple(notes), gyr, gait, root, constrained, valid_from)
    return replace(result, notes=result.notes + tuple(_sanity_notes(result)))


def _independent(sensors: list[str], skeleton: Skeleton, recs: Mapping[str, Recording],
                 t: Array, method: str, param_values: Mapping[str, Any], frame: str,
                 max_gap_s: float
                 ) -> tuple[Array, list[NDArray[np.uint16]], list[SensorReport],
                            Mapping[str, Any], str]:
    """One estimate per sensor with its own magnetometer (the path without ``no_mag``)."""
    from margtrack import methods
    from margtrack.estimator.flags import Flag, count_flags

    q_list: list[Array] = []
    flag_cols: list[NDArray[np.uint16]] = []
    reports: list[SensorReport] = []
    used_params: Mapping[str, Any] = {}
    method_name = method
    for sensor, segment in zip(sensors, skeleton.names, strict=True):
        rec = recs[sensor]
        try:
            est = methods.create(method, param_values).run(rec).in_frame(frame)
        except UnitError as exc:
            raise exc.prefixed(f"sensor {sensor}: ") from None
        except ValueError as exc:
            raise ValueError(f"sensor {sensor}: {exc}") from None
        used_params, method_name = est.params, est.method
        q_list.append(resample_orientations(rec.t, est.quat, t))
        flag_cols.append(flags_on_time_base(rec.t, est.flags, t, max_gap_s))
        flags = est.flags if est.flags is not None else np.zeros(rec.n_samples, np.uint16)
        unusable = 1.0 if rec.mag is None else float(
            np.mean((flags & int(Flag.MAG_IGNORED)) != 0))
        reports.append(SensorReport(
            sensor, segment, rec.n_samples, rec.rate_hz, (float(rec.t[0]), float(rec.t[-1])),
            count_flags(flags), unusable,
            int(np.count_nonzero(flag_cols[-1] & int(Flag.GAP)))))
    return np.stack(q_list, axis=1), flag_cols, reports, used_params, method_name


def _sanity_notes(result: BodyResult) -> list[str]:
    """Warnings when the angles look like a reversed forward axis (knees bending backwards)."""
    notes = []
    for side in ("left", "right"):
        joint = f"{side}_knee"
        if joint not in result.angles.names:
            continue
        flex = result.angles.degrees(joint)[result.window.stop:, 0]
        if flex.size and flex.min() < -30.0 and -flex.min() > flex.max():
            fix = ("--forward-axis (the pelvis sensor's axis that points forward)"
                   if result.forward_axis is not None else "--heading pelvis")
            notes.append(f"{joint} flexion reaches {flex.min():.0f} deg but only "
                         f"{flex.max():.0f} deg the other way: the knees bend backwards, so "
                         f"the facing direction is probably reversed; check {fix}")
    return notes
