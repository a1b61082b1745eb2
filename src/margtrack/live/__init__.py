"""Real-time tracking: sources, the engine, the live 3-D view (000, "Prototype ... System").

- Sources (:mod:`.protocol`: timestamped chunks of multi-sensor samples, polled):
  :class:`SimulatorSource` (:mod:`.simulator`, people walking or waving, up to 15 sensors
  each), :class:`ReplaySource` / :func:`replay_path` (:mod:`.replay`, BROAD, x-IMU3 body
  folders, margtrack files, at any speed), :class:`UdpSource` (:mod:`.udp`) and
  :class:`SerialSource` (:mod:`.serial_port`, pyserial) reading the line format of
  :mod:`.lines`.
- :class:`Engine` (:mod:`.engine`): one filter per sensor batched in the multi-sensor kernel,
  the body model (:mod:`.avatars`), poses at the display rate to subscribers, live parameter
  changes, "calibrate now", recording and export (:mod:`.recording`), and
  :class:`EngineStats` (:mod:`.stats`): processing time, latency, drops, sensor health.
- :func:`run_live` (:mod:`.viewer`, needs ``viser``): the browser view; :mod:`.cli` holds
  the ``margtrack live`` command.

Names are imported lazily, so ``import margtrack.live`` loads neither viser nor pyserial.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = [
    "Avatars",
    "Chunk",
    "Engine",
    "EngineStats",
    "LiveRecording",
    "PeopleSimulation",
    "Pose",
    "ReplaySource",
    "SerialSource",
    "SimulatorSource",
    "Source",
    "SourceInfo",
    "UdpSource",
    "format_line",
    "parse_line",
    "replay_path",
    "replay_recordings",
    "run_live",
]

_WHERE = {
    "Avatars": "avatars",
    "Chunk": "protocol",
    "Engine": "engine",
    "EngineStats": "stats",
    "LiveRecording": "recording",
    "PeopleSimulation": "simulator",
    "Pose": "engine",
    "ReplaySource": "replay",
    "SerialSource": "serial_port",
    "Source": "protocol",
    "SourceInfo": "protocol",
    "SimulatorSource": "simulator",
    "UdpSource": "udp",
    "format_line": "lines",
    "parse_line": "lines",
    "replay_path": "replay",
    "replay_recordings": "replay",
    "run_live": "viewer",
}


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'margtrack.live' has no attribute {name!r}")
    return getattr(importlib.import_module(f"margtrack.live.{_WHERE[name]}"), name)


def __dir__() -> list[str]:
    return sorted(__all__)
