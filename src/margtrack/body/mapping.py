"""Which sensor sits on which body segment: names, aliases and the ``body.toml`` map file.

A recording names its sensors (x-IMU3 folder names, file names, the live engine's sensor
names). Where those are segment names or aliases (``pelvis``, ``left_upper_leg``,
``femur_r_imu``...) nothing more is needed; otherwise a map says which is which::

    # body.toml: sensor name = segment name
    [sensors]
    "IMU 3F2A" = "pelvis"
    imu_7 = "right_thigh"
    imu_8 = "femur_l"          # OpenSense body names are accepted too

    [pelvis]
    forward_axis = "-z"        # the pelvis sensor's axis that points forward (--heading pelvis)

    height_m = 1.80            # optional: body height, m (segment lengths; angles do not use it)

Segment names: :data:`margtrack.body.SEGMENT_NAMES`, their :data:`~margtrack.body.ALIASES`,
and the OpenSense IMU names of :data:`~margtrack.body.OPENSENSE_NAMES` with or without
``_imu``. Sensors of the recording that the map does not list are left out (and reported).
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from margtrack.body.export_sto import OPENSENSE_NAMES
from margtrack.body.skeleton import ALIASES, SEGMENT_NAMES, canonical_name

Array = NDArray[np.float64]

__all__ = ["BodyMap", "assign_segments", "parse_axis", "read_body_map", "segment_of"]

_OPENSENSE = {
    **{v: k for k, v in OPENSENSE_NAMES.items()},
    **{v.removesuffix("_imu"): k for k, v in OPENSENSE_NAMES.items()},
}
_AXES = {"x": 0, "y": 1, "z": 2}
_TOP_KEYS = ("sensors", "pelvis", "height_m")


def segment_of(name: str) -> str | None:
    """The segment ``name`` stands for (segment, alias or OpenSense name), else None."""
    key = str(name).strip().lower().replace(" ", "_").replace("-", "_")
    if key in _OPENSENSE:
        return _OPENSENSE[key]
    try:
        return canonical_name(key)
    except ValueError:
        return None


def _valid_names() -> str:
    return (f"{', '.join(SEGMENT_NAMES)} (also accepted: {', '.join(ALIASES)}, and the "
            "OpenSense names pelvis_imu, femur_r_imu, tibia_r_imu, calcn_r_imu...)")


def parse_axis(value: str | Sequence[float]) -> Array:
    """A sensor axis from ``"-z"``, ``"+x"``, ``"0,0,-1"`` or a 3-sequence: unit (3,) vector."""
    if isinstance(value, str):
        text = value.strip().lower()
        sign = -1.0 if text.startswith("-") else 1.0
        letter = text.lstrip("+-")
        if letter in _AXES:
            axis = np.zeros(3)
            axis[_AXES[letter]] = sign
            return axis
        parts = text.split(",")
    else:
        parts = list(value)
    try:
        axis = np.array([float(p) for p in parts], dtype=np.float64)
    except (TypeError, ValueError):
        axis = np.zeros(0)
    if axis.shape != (3,) or not np.all(np.isfinite(axis)) or not np.linalg.norm(axis) > 0:
        raise ValueError(
            f"a sensor axis is one of +x, -x, +y, -y, +z, -z or three numbers x,y,z (not all "
            f"zero), got {value!r}"
        )
    return axis / np.linalg.norm(axis)


@dataclass(frozen=True)
class BodyMap:
    """A sensor -> segment map and the optional settings of a ``body.toml`` (module docstring).

    Attributes
    ----------
    sensors : sensor name -> canonical segment name.
    forward_axis : (3,) the pelvis sensor's forward axis in its own frame, or None.
    height_m : body height, m, or None.
    source : the file it was read from ("" when built in code).
    """

    sensors: Mapping[str, str]
    forward_axis: Array | None = None
    height_m: float | None = None
    source: str = field(default="")

    def __post_init__(self) -> None:
        where = f"{self.source}: " if self.source else ""
        checked: dict[str, str] = {}
        for sensor, segment in dict(self.sensors).items():
            seg = segment_of(str(segment))
            if seg is None:
                raise ValueError(
                    f"{where}sensor {sensor!r} is mapped to {segment!r}, which is not a "
                    f"segment; valid segments: {_valid_names()}"
                )
            twice = [s for s, g in checked.items() if g == seg]
            if twice:
                raise ValueError(
                    f"{where}sensors {twice[0]!r} and {sensor!r} are both mapped to {seg}; "
                    "one sensor per segment"
                )
            checked[str(sensor)] = seg
        if not checked:
            raise ValueError(f"{where}the map lists no sensor; add 'sensor = \"segment\"' lines "
                             "under [sensors]")
        object.__setattr__(self, "sensors", checked)
        if self.forward_axis is not None:
            object.__setattr__(self, "forward_axis", parse_axis(self.forward_axis))
        if self.height_m is not None:
            h = self.height_m
            if isinstance(h, bool) or not isinstance(h, int | float) or not 0.5 <= h <= 2.8:
                raise ValueError(f"{where}height_m must be a body height in m in [0.5, 2.8], "
                                 f"got {h!r}")


def read_body_map(path: str | Path) -> BodyMap:
    """Read a ``body.toml`` (module docstring); errors name the file and the fix."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such map file: {p}")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{p} is not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{p} is not a UTF-8 text file: {exc}") from None
    unknown = sorted(set(data) - set(_TOP_KEYS))
    if unknown:
        raise ValueError(
            f"{p}: unknown key(s) {', '.join(unknown)}; a body map has [sensors] "
            "(sensor = \"segment\"), [pelvis] forward_axis and height_m"
        )
    sensors = data.get("sensors")
    if not isinstance(sensors, dict) or not all(isinstance(v, str) for v in sensors.values()):
        raise ValueError(f"{p}: needs a [sensors] table of sensor = \"segment\" lines")
    pelvis = data.get("pelvis", {})
    if not isinstance(pelvis, dict) or set(pelvis) - {"forward_axis"}:
        raise ValueError(f"{p}: [pelvis] takes only forward_axis (e.g. \"-z\" or [0, 0, -1])")
    try:
        return BodyMap(sensors, pelvis.get("forward_axis"), data.get("height_m"), str(p))
    except ValueError as exc:
        text = str(exc)
        raise ValueError(text if text.startswith(str(p)) else f"{p}: {text}") from None


def assign_segments(
    sensor_names: Sequence[str], mapping: BodyMap | Mapping[str, str] | None
) -> tuple[dict[str, str], list[str]]:
    """Sensor -> segment for the sensors of a recording, and the sensors left out.

    Without a map every sensor name must stand for a segment (:func:`segment_of`); with one,
    every sensor it lists must be in the recording, and the others are left out.
    """
    names = [str(n) for n in sensor_names]
    if mapping is None:
        unknown = [n for n in names if segment_of(n) is None]
        if unknown:
            raise ValueError(
                f"sensor(s) {', '.join(repr(n) for n in unknown)} are not segment names; "
                f"rename them or give a map (--map body.toml, [sensors] sensor = \"segment\"); "
                f"valid segments: {_valid_names()}"
            )
        pairs = {n: segment_of(n) for n in names}
        left_out: list[str] = []
    else:
        body_map = mapping if isinstance(mapping, BodyMap) else BodyMap(mapping)
        missing = [s for s in body_map.sensors if s not in names]
        if missing:
            raise ValueError(
                f"the map names sensor(s) {', '.join(repr(s) for s in missing)} that the "
                f"recording does not have; its sensors: {', '.join(names)}"
            )
        pairs = {n: body_map.sensors[n] for n in names if n in body_map.sensors}
        left_out = [n for n in names if n not in body_map.sensors]
    by_segment: dict[str, list[str]] = {}
    for sensor, seg in pairs.items():
        by_segment.setdefault(str(seg), []).append(sensor)
    twice = {seg: s for seg, s in by_segment.items() if len(s) > 1}
    if twice:
        seg, s = next(iter(twice.items()))
        raise ValueError(f"sensors {', '.join(s)} all stand for segment {seg}; one sensor per "
                         "segment: leave one out with a map (--map body.toml)")
    return {k: str(v) for k, v in pairs.items()}, left_out
