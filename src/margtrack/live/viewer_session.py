"""A live session in the browser: the engine, its viewer and the viser server, started and
stopped together (:func:`run_live`, :class:`LiveSession`); what the page shows is
:mod:`margtrack.live.viewer`'s. Who may connect: :mod:`margtrack.live.security`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
import warnings
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from numpy.typing import ArrayLike

from margtrack.body.export_bvh import BVH_UNITS
from margtrack.body.offsets import Heading
from margtrack.live import calibration_panel
from margtrack.live.engine import Engine
from margtrack.live.protocol import Source
from margtrack.live.security import AccessPolicy, exposure_warning, guarded_viser_server, page_url
from margtrack.live.viewer import LiveViewer

__all__ = ["LiveSession", "run_live"]


@dataclasses.dataclass
class LiveSession:
    """A running engine, its viewer and the viser server; :meth:`stop` ends them all.

    url : the page's address, with ``?token=...`` when the page needs one; token : that
    token (None on loopback without one).
    """

    viewer: LiveViewer
    server: Any
    url: str
    token: str | None = None

    @property
    def engine(self) -> Engine:
        """The engine now shown (a new one after *Replay again*)."""
        return self.viewer.engine

    def stop(self) -> None:
        """Stop the viewer, the engine (closing the source) and the server."""
        self.viewer.close()
        self.engine.stop()
        self.server.stop()

    def __enter__(self) -> LiveSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _warn(message: str) -> None:
    warnings.warn(message, UserWarning, stacklevel=3)


def run_live(
    source: Source,
    method: str = "default",
    port: int = 8080,
    *,
    host: str = "127.0.0.1",
    token: str | bool | None = None,
    params: Mapping[str, Any] | Iterable[str] = (),
    display_hz: float = 25.0,
    height_m: float = 1.75,
    calibrate_at_start: bool = False,
    heading: Heading = "north",
    forward_axis: ArrayLike | None = None,
    out_dir: str | Path | None = None,
    block: bool = True,
    duration_s: float | None = None,
    announce: Callable[[LiveSession], None] | None = None,
    warn: Callable[[str], None] = _warn,
    record: str | Path | None = None,
    no_mag: bool = False,
    lever_arms: Mapping[str, Any] | None = None,
    walking_root: bool = False,
    bvh_unit: str = "cm",
) -> LiveSession:
    """Track ``source`` live and serve the 3-D view at ``session.url``.

    Parameters
    ----------
    source : any :class:`~margtrack.live.protocol.Source` (simulator, replay, UDP, serial).
    method, params : the filter (registered name) and its parameters.
    port : TCP port of the page (0: a free one, see ``session.url``).
    host : address bound; ``127.0.0.1`` (default): this machine only. Any other address
        needs a token and ``warn`` is called with what it exposes.
    token : None: a random token off loopback, none on it; True: a random one anyway;
        a string: that token (12+ URL-safe characters); False: none (refused off loopback).
        See :mod:`margtrack.live.security`.
    display_hz, height_m, calibrate_at_start, heading, forward_axis, no_mag, lever_arms,
    walking_root : see :class:`Engine`.
    out_dir : where "Stop recording and export" writes (default ``./margtrack_live``).
    bvh_unit : length unit of the exported BVH, ``"cm"`` or ``"m"``.
    block : serve until Ctrl-C (or ``duration_s``), then stop everything and return the
        stopped session; ``False`` returns the running session at once (call ``stop()``).
    duration_s : with ``block``, stop after this many seconds.
    announce : called with the running session once the page is served (e.g. to print
        ``session.url``, which holds the real port and the token).
    warn : called with the exposure warning of a non-loopback ``host`` (default: a
        ``UserWarning``).
    record : start a raw recording with the engine (``viewer.raw_recorder``; the caller
        saves it, :func:`margtrack.live.calibration_panel.attach`).
    """
    if bvh_unit not in BVH_UNITS:
        raise ValueError(f"bvh_unit must be cm or m, got {bvh_unit!r}")
    policy = AccessPolicy.for_bind(host, token)
    if (message := exposure_warning(host)) is not None:
        warn(message)

    def new_engine() -> Engine:
        return Engine(source.info, method, params, height_m=height_m, display_hz=display_hz,
                      heading=heading, forward_axis=forward_axis,
                      calibrate_at_start=calibrate_at_start, no_mag=no_mag,
                      lever_arms=lever_arms, walking_root=walking_root)

    engine = new_engine()
    server = guarded_viser_server(host, port, policy)
    try:
        viewer = LiveViewer(engine, server, out_dir, source=source, new_engine=new_engine)
        source = calibration_panel.attach(viewer, source, record)  # guided calibration panel
        viewer.source, viewer.record_path = source, record  # for Replay again
        viewer.bvh_unit = bvh_unit
        engine.start(source)
    except BaseException:
        server.stop()
        raise
    session = LiveSession(viewer, server, page_url(host, server.get_port(), policy.token),
                          policy.token)
    if announce is not None:
        announce(session)
    if not block:
        return session
    end = math.inf if duration_s is None else time.perf_counter() + duration_s
    try:
        with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C ends the session cleanly
            while time.perf_counter() < end:
                time.sleep(min(0.2, max(end - time.perf_counter(), 0.0)))
    finally:
        session.stop()
    return session

