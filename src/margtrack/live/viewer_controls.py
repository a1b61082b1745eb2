"""Controls of the live page: filter parameters from their declarations, the joint plot.

:class:`ParamControls` adds one control per numeric or boolean parameter of the engine's
filter, labelled from the parameter declaration (:func:`margtrack.estimator.params.specs`:
the name in words with its declared unit, :func:`control_label`; help and bounds as the
hint); a change goes to
``Engine.set_params`` (in force from the next sample), a rejected value is reported and
the control reset to the value in force. :class:`JointPlot` is the joint-angle readout
and a uPlot chart of the joints ticked under it, fed by a
:class:`~margtrack.live.viewer_panels.JointTrace`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from margtrack import body
from margtrack.estimator.params import specs
from margtrack.live.viewer_panels import JointTrace, joint_table

Array = NDArray[np.float64]

__all__ = ["JointPlot", "ParamControls", "control_label"]

_PLOT_COLORS = ("#dc3c32", "#286edc", "#e08a00", "#2a9d55", "#8e44ad", "#555555")


#: words that spell a unit at the end of a parameter name (``bias_walk_deg_s_sqrt_s``)
_UNIT_WORDS = frozenset({"deg", "rad", "s", "s2", "m", "g", "hz", "ut", "sqrt", "per"})


def control_label(name: str, unit: str) -> str:
    """A parameter's label on the page: its name in words without the unit spelt in it,
    then the declared unit, e.g. ``bias_walk_deg_s_sqrt_s`` -> ``bias walk [deg/s/√s]``."""
    words = name.split("_")
    if unit:
        keep = len(words)
        while keep > 1 and words[keep - 1] in _UNIT_WORDS:
            keep -= 1
        words = words[:keep]
    text = " ".join(words)
    return f"{text} [{unit}]" if unit else text


def _step(value: float) -> float:
    return 10.0 ** (math.floor(math.log10(abs(value))) - 1) if value else 0.01


class ParamControls:
    """One GUI control per filter parameter; ``engine()`` gives the engine to retune."""

    def __init__(self, gui: Any, engine: Callable[[], Any], report: Callable[[str], None]
                 ) -> None:
        self._engine = engine
        self._report = report
        self._reverting = False
        self.handles: dict[str, Any] = {}
        params = engine().params
        for spec in specs(params):
            value = getattr(params, spec.name)
            if spec.name == "frame" or value is None or isinstance(value, (tuple, str)):
                continue
            label = control_label(spec.name, spec.unit)
            if isinstance(value, bool):
                handle = gui.add_checkbox(label, initial_value=value, hint=spec.help)
            else:
                low = spec.ge if spec.ge is not None else spec.gt
                high = spec.le if spec.le is not None else spec.lt
                handle = gui.add_number(
                    label, initial_value=value, min=low, max=high,
                    step=1 if isinstance(value, int) else _step(value),
                    hint=f"{spec.help} ({spec.bounds_text()} {spec.unit})".strip())
            handle.on_update(self._callback(spec.name, handle))
            self.handles[spec.name] = handle

    def _callback(self, name: str, handle: Any) -> Callable[[Any], None]:
        def changed(event: Any) -> None:
            if self._reverting:
                return
            engine = self._engine()
            try:
                engine.set_params(**{name: handle.value})
            except (ValueError, TypeError) as exc:
                self._report(f"{name} rejected: {exc}")
                if getattr(event, "client", None) is not None:
                    event.client.add_notification(f"{name} rejected", str(exc),
                                                  auto_close_seconds=5.0, color="red")
                self._reverting = True
                try:
                    handle.value = getattr(engine.params, name)
                finally:
                    self._reverting = False
            else:
                self._report(f"{name} = {handle.value} from the next sample")

        return changed


class JointPlot:
    """The first person's joint angles as a table and a scrolling plot (module docstring)."""

    def __init__(self, server: Any, joint_names: tuple[str, ...], trace: JointTrace) -> None:
        gui = server.gui
        self.server = server
        self.trace = trace
        self.table = gui.add_markdown("")
        chosen = [j for j in ("right_knee", "left_knee") if j in joint_names]
        chosen = chosen or list(joint_names[:2])
        self.plot = gui.add_uplot(*self._args(chosen), title="joint angles (deg)", aspect=1.6,
                                  scales={"x": {"time": False}})
        self.boxes: dict[str, Any] = {}
        with gui.add_folder("Plot joints", expand_by_default=False):
            for name in joint_names:
                box = gui.add_checkbox(name.replace("_", " "), initial_value=name in chosen)
                box.on_update(lambda _: self.update(None))
                self.boxes[name] = box

    def chosen(self) -> list[str]:
        """The joints ticked for the plot."""
        return [j for j, box in self.boxes.items() if box.value]

    def _args(self, joints: list[str]) -> tuple[tuple[Array, ...], tuple[dict, ...]]:
        data = self.trace.data(joints)
        series: tuple[dict, ...] = ({"label": "session time (s)"}, *(
            {"label": j.replace("_", " "), "stroke": _PLOT_COLORS[i % len(_PLOT_COLORS)],
             "width": 2} for i, j in enumerate(joints)))
        if data[0].size < 2:  # uPlot needs points: start with a flat zero segment
            data = (np.array([0.0, 0.1]), *[np.zeros(2) for _ in joints])
        return data, series

    def update(self, angles: body.JointAngles | None) -> None:
        """Show ``angles`` (None: keep the table) and the trace of the ticked joints."""
        if angles is not None:
            self.table.content = joint_table(angles)
        data, series = self._args(self.chosen())
        with self.server.atomic():
            self.plot.series = series
            self.plot.data = data
