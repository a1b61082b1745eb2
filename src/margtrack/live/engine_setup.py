"""What a live engine runs with, checked before it is built: the method and the body models.

:func:`checked_setup` refuses, with the fix in the message, what cannot run live: an
offline method, a method that needs the magnetometer when ``no_mag`` leaves it out or the
source has none, lever arms without ``no_mag``, body models in another earth frame than
the filter's, and the north heading without magnetometers.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from margtrack import methods
from margtrack.body.offsets import Heading
from margtrack.estimator import Estimator
from margtrack.live.avatars import Avatars
from margtrack.live.protocol import SourceInfo

__all__ = ["checked_setup"]


def checked_setup(info: SourceInfo, method: str, params: Mapping[str, Any] | Iterable[str],
                  avatars: Avatars | str | None, height_m: float, heading: Heading,
                  no_mag: bool, lever_arms: Mapping[str, Any] | None
                  ) -> tuple[str, Estimator, Avatars | None]:
    """(method's registered name, its estimator at the source's rate, the body models) for
    :class:`~margtrack.live.engine.Engine` (its parameters of the same names); ``avatars``
    ``"auto"`` builds them from the sensor names, ``height_m`` m tall."""
    name = methods.get(method).name
    if getattr(methods.get(method), "offline", False):
        raise ValueError(f"method {name!r} is offline (it needs the whole recording); "
                         "live streams need a causal method such as 'robust'")
    estimator: Estimator = methods.create(method, params, rate_hz=info.rate_hz)
    if (no_mag or not info.has_mag) and not type(estimator).mag_optional:
        why = "--no-mag leaves it out" if no_mag else "the source has none"
        raise ValueError(f"method {name!r} needs a magnetometer; {why}: choose a "
                         "method that runs without one (margtrack methods)")
    if lever_arms and not no_mag:
        raise ValueError("lever arms (--lever-arms) serve the joint constraint of --no-mag; "
                         "give them with --no-mag (no_mag=True)")
    frame = estimator.params.frame
    if isinstance(avatars, str):
        if avatars != "auto":
            raise ValueError(f"avatars must be 'auto', None or Avatars, got {avatars!r}")
        avatars = Avatars.from_names(info.sensor_names, height_m, frame)
    if avatars is not None and avatars.skeleton.frame != frame:
        raise ValueError(f"avatars are in {avatars.skeleton.frame} but the filter in {frame}")
    if no_mag and heading == "north" and avatars is not None:
        raise ValueError("heading 'north' needs the magnetometers, which --no-mag leaves "
                         "out: use the pelvis heading (--heading pelvis, and the pelvis "
                         "sensor's --forward-axis)")
    return name, estimator, avatars
