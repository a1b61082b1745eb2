"""Real-time tracking: sources, the engine, the live 3-D view (000, "Prototype ... System").

- Sources (:mod:`.protocol`: timestamped chunks of multi-sensor samples, polled;
  :class:`BaseSource` to write one): :class:`SimulatorSource` (:mod:`.simulator`, people
  walking or waving, up to 15 sensors each), :class:`ReplaySource` / :func:`replay_path`
  (:mod:`.replay`, BROAD, x-IMU3 body folders, margtrack files, at any speed),
  :class:`LiveReplaySource` (a raw live recording with its events), :class:`UdpSource`
  (:mod:`.udp`) and :class:`SerialSource` (:mod:`.serial_port`, pyserial) reading the line
  format of :mod:`.lines` (:class:`LineDecoder`), :class:`OscSource` (:mod:`.osc`) and
  :class:`LslSource` (:mod:`.lsl`, pylsl); :class:`FaultyStream` and :class:`Fault`
  (:mod:`.faults`) replay field faults for tests and soaks.
- :class:`Engine` (:mod:`.engine`): the sensors' filters batched in one multi-sensor run
  (:mod:`.clocks`, :mod:`.assembler`, :mod:`.filtering`: per-sensor clocks, frames, fault
  isolation, numpy over sensors), the body model of every person at once (:mod:`.avatars`),
  poses (:class:`Pose`) at the display rate to subscribers (:mod:`.subscribers`) from a
  worker thread (:mod:`.worker`), live parameter changes, "calibrate now"
  (:mod:`.calibrations`), recording (:mod:`.orientation_log`, :class:`LiveRecording`;
  raw: :class:`RawRecorder`), and :class:`EngineStats` / :class:`SensorHealth`
  (:mod:`.stats`): processing time, latency, losses, sensor health.
- :func:`run_live` (:mod:`.viewer_session`, the page in :mod:`.viewer`, needs ``viser``): the
  browser view; :mod:`.cli` holds the ``margtrack live`` command.

Names are imported lazily, so ``import margtrack.live`` loads neither viser, pyserial nor
pylsl.
"""

from __future__ import annotations

from margtrack.lazy import lazy_names

_WHERE = {
    "Avatars": "avatars",
    "BaseSource": "protocol",
    "Chunk": "protocol",
    "Engine": "engine",
    "EngineStats": "stats",
    "Fault": "faults",
    "FaultyStream": "faults",
    "Frames": "assembler",
    "LineDecoder": "lines",
    "LiveRecording": "recording",
    "LiveReplaySource": "replay",
    "LslSource": "lsl",
    "OscSource": "osc",
    "PeopleSimulation": "simulator",
    "Pose": "pose",
    "RawRecorder": "recording",
    "ReplaySource": "replay",
    "SensorHealth": "stats",
    "SerialSource": "serial_port",
    "SimulatorSource": "simulator",
    "Source": "protocol",
    "SourceInfo": "protocol",
    "SourceStats": "protocol",
    "UdpSource": "udp",
    "format_line": "lines",
    "iter_chunks": "protocol",
    "parse_line": "lines",
    "replay_path": "replay",
    "replay_recordings": "replay",
    "run_live": "viewer_session",
    "send_lines": "udp",
    "send_osc": "osc",
}

__all__ = sorted(_WHERE)


__getattr__, __dir__ = lazy_names(__name__, _WHERE)
