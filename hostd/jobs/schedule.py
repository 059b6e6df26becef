"""A job's layer schedule: which slicing settings and which bodies apply to each layer."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np

from slicer.output import gcode
from slicer.output.entry import entered, last_xy
from slicer.output.gcode import fan_command
from slicer.plan import SlicePlan
from slicer.planprocess import PlanProcess, PlanProcessGone
from slicer.settings import SliceSettings

log = logging.getLogger("hostd.jobs.schedule")

# layers below the one being sliced whose outlines and skins stay held: more than any
# lookahead (at most 64) and a skin block's reach, so that the layers sliced after this
# one never cut them again; below, a print holds nothing of the model's layers (a view of
# an old layer cuts its block again)
HELD_LAYERS = 96
# whole-model work waits this long for the slicing process's plan, then runs here
READY_WAIT_S = 60.0

T = TypeVar("T")


class LayerSchedule:
    """Settings and excluded bodies per layer, after every retune and cancelled object.

    ``changes`` is the list of retunes ``(first layer, flat keys)`` in the order they
    were made; ``cancelled`` the list of ``(body index, first layer without it)``.
    The same lists, read back from the job store, rebuild the same schedule, so a
    resumed job slices every layer exactly as the first run did.
    """

    def __init__(
        self,
        plan: SlicePlan,
        settings: SliceSettings,
        changes: list[tuple[int, dict[str, Any]]] | None = None,
        cancelled: list[tuple[int, int]] | None = None,
    ) -> None:
        self.base_plan = plan
        self.base_settings = settings
        self.changes: list[tuple[int, dict[str, Any]]] = list(changes or [])
        self.cancelled: list[tuple[int, int]] = list(cancelled or [])
        self._plans: dict[SliceSettings, SlicePlan] = {settings: plan}
        self._lock = threading.Lock()
        # layer -> (the slicer's estimated seconds, filament mm) of each layer sliced here
        self.estimates: dict[int, tuple[float, float]] = {}
        # (two numbers a layer, for the ETA and the done file's totals: kept whole)
        self.lines: dict[int, int] = {}  # layer -> its command lines (the same layers)
        # layer -> its code made before the job began (base settings, every body)
        self._ahead: dict[int, gcode.LayerCode] = {}
        # the child process slicing the layers, once its plan is ready (see slice_in)
        self._process: PlanProcess | None = None
        self._owned: PlanProcess | None = None  # the process to close, even once it died
        self._closed = False  # the print ended: its slicing process is closed

    def slice_in(self, process: PlanProcess) -> None:
        """Slice the layers in ``process`` (the same model and base settings) from the
        moment its plan is ready: what slicing leaves in a heap then goes with the
        process. Until then, and if it dies, layers are sliced here as before; the
        lines are the same either way. A process given once the print ended is
        closed at once."""
        with self._lock:
            if not self._closed:
                self._process = self._owned = process
                return
        process.close()

    def close(self) -> None:
        """The print ended: no layer is sliced any longer, and the slicing process, if
        any, ends."""
        with self._lock:
            self._closed = True
            process, self._process, self._owned = self._owned, None, None
        if process is not None:
            process.close()

    def made_ahead(self, layer: int, code: gcode.LayerCode) -> None:
        """Layer ``layer``'s code, made by the base plan with every body before the job
        began (:mod:`hostd.jobs.speculate`): used once, if the layer is still sliced so."""
        self._ahead[layer] = code

    @property
    def layer_count(self) -> int:
        return int(self.base_plan.layer_count)

    def settings_at(self, layer: int) -> SliceSettings:
        """The settings layer ``layer`` is sliced with."""
        settings = self.base_settings
        for first, changed in self.changes:
            if first <= layer:
                settings = SliceSettings.from_mapping(changed, base=settings)
        return settings

    def excluded_at(self, layer: int) -> frozenset[int]:
        """Bodies left out of layer ``layer``."""
        return frozenset(body for body, first in self.cancelled if first <= layer)

    def plan_at(self, layer: int) -> SlicePlan:
        """The plan (same geometry, the layer's settings) that slices layer ``layer``."""
        settings = self.settings_at(layer)
        with self._lock:
            plan = self._plans.get(settings)
            if plan is None:
                plan = self.base_plan.with_settings(settings)
                self._plans[settings] = plan
        return plan

    def layer_gcode(self, layer: int) -> list[str]:
        """G-code lines of one layer for the printer (safe to call from worker threads).

        Takes the layer's code made ahead, if any, and records the layer's estimate
        and command count (the ETA's). On the first layer of a retune that changed a
        temperature or the fan, the new values are set right after the ``;LAYER:``
        line (the slicer sets them only in the start block).
        """
        code = self._code(layer, self._ahead.pop(layer, None))
        self.estimates[layer] = (code.time_s, code.filament_mm)
        self.lines[layer] = sum(1 for line in code.lines if line[:1] not in ("", ";"))
        self.forget_before(layer - HELD_LAYERS)
        return self._retuned(layer, code.lines)

    def forget_before(self, layer: int) -> None:
        """Let every plan of the schedule go of the outlines and skins of the layers
        below ``layer`` (:meth:`SlicePlan.forget_before`): what a print holds of its
        model stays a window of layers as it goes up."""
        if layer <= 0:
            return
        with self._lock:
            plans = list(self._plans.values())
        for plan in plans:
            plan.forget_before(layer)

    def layer_preview(self, layer: int) -> list[str]:
        """Layer ``layer``'s lines as :meth:`layer_gcode` makes them, for a view: nothing
        of the schedule changes (the code made ahead stays for the printer, no estimate
        is recorded), so any thread may call it while the job prints."""
        return self._retuned(layer, self._code(layer, self._ahead.get(layer)).lines)

    def _code(self, layer: int, ahead: gcode.LayerCode | None) -> gcode.LayerCode:
        """The layer's code: ``ahead`` when it was made with what the layer has now."""
        if ahead is None or self.settings_at(layer) != self.base_settings or (
                self.excluded_at(layer)):
            return self.fresh_code(layer)
        return ahead

    def on_plan(self, function: Callable[..., T], *args: Any) -> T:
        """``function(plan, *args)``, ``plan`` the base settings' plan: in the slicing
        process when there is one (waiting for its plan), so that whole-model work
        (the ETA's measure, the warnings of every layer) leaves nothing in the daemon;
        here otherwise. PlanProcessGone once the print ended."""
        if self._closed:
            raise PlanProcessGone("the print ended: its model is no longer sliced")
        process = self._process
        if process is not None and process.wait_ready(READY_WAIT_S):
            try:
                result: T = process.call(function, self.base_settings, *args).result()
                return result
            except PlanProcessGone:
                if self._closed:
                    raise
        return function(self.base_plan, *args)

    def fresh_code(self, layer: int) -> gcode.LayerCode:
        """Layer ``layer`` sliced now with its settings and bodies (in the slicing
        process when it is ready), nothing recorded; PlanProcessGone once the print
        ended (:meth:`close`)."""
        if self._closed:
            raise PlanProcessGone("the print ended: its layers are no longer sliced")
        excluded = self.excluded_at(layer)
        process = self._process
        if process is not None and not process.ready.is_set() and process.gone is not None:
            self._give_up(process, layer, process.gone)  # it never built its plan
            process = None
        if process is not None and process.ready.is_set():
            try:
                return process.layer_code(self.settings_at(layer), layer, excluded,
                                          layer - HELD_LAYERS)
            except PlanProcessGone as exc:
                if self._closed:  # closed with the print: the layer is not wanted
                    raise
                self._give_up(process, layer, str(exc))
        return self.plan_at(layer).layer_code(layer, excluded)

    def _give_up(self, process: PlanProcess, layer: int, why: str) -> None:
        """Slice here from ``layer`` on: ``process`` is gone (said once)."""
        with self._lock:
            if self._process is not process:
                return
            self._process = None
        log.warning("layers from %d on sliced in the daemon: %s", layer, why)

    def _retuned(self, layer: int, code_lines: list[str]) -> list[str]:
        """``code_lines`` (copied) with a retune's temperatures and fan set on its first layer."""
        lines = list(code_lines)
        if layer > 0 and any(first == layer for first, _changes in self.changes):
            extra = _retune_gcode(self.settings_at(layer - 1), self.settings_at(layer), layer)
            if extra:
                at = 1 if lines and lines[0].startswith(";LAYER:") else 0
                lines[at:at] = extra
        return lines

    def entered(self, layer: int, lines: list[str], came_from: np.ndarray | None) -> list[str]:
        """Layer ``layer``'s ``lines`` with its first travel, from ``came_from`` ((2,) mm,
        where the layer before ended; None: unknown), around the bodies cancelled by then
        (:mod:`slicer.output.entry`); the seconds added go into its estimate."""
        excluded = self.excluded_at(layer)
        if not excluded or came_from is None or layer <= 0:
            return lines
        plan = self.plan_at(layer)
        lines, extra = entered(lines, came_from, plan.entry_region(layer, excluded),
                               plan.settings.acceleration)
        if extra and layer in self.estimates:
            seconds, filament = self.estimates[layer]
            self.estimates[layer] = (seconds + extra, filament)
        return lines

    def came_from(self, layer: int) -> np.ndarray | None:
        """Where the nozzle is after layer ``layer`` (X, Y mm), as sliced by this schedule
        (slicing it again: for the layer before a resumed one); None if it moves nowhere."""
        if layer < 0:
            return None
        return last_xy(self.fresh_code(layer).lines)

    def retune(self, first: int, changed: Mapping[str, Any]) -> SliceSettings:
        """Apply ``changed`` from layer ``first`` on; raises SettingsError when refused."""
        settings = SliceSettings.from_mapping(changed, base=self.settings_at(first))
        plan = self.base_plan.with_settings(settings)  # refuses geometry changes
        with self._lock:
            self._plans.setdefault(settings, plan)
        self.changes.append((first, dict(changed)))
        return settings

    def cancel_body(self, body: int, first: int) -> None:
        """Leave body ``body`` out from layer ``first`` on."""
        self.cancelled.append((body, first))

    def restore_body(self, body: int) -> None:
        """Slice body ``body`` again in the layers not sliced yet (its cancels forgotten)."""
        self.cancelled = [item for item in self.cancelled if item[0] != body]


def _retune_gcode(before: SliceSettings, after: SliceSettings, layer: int) -> list[str]:
    """Commands that apply a retune's temperatures and fan speed (no waiting)."""
    lines = [";RETUNE"]
    if after.nozzle_temp != before.nozzle_temp:
        lines.append(f"M104 S{after.nozzle_temp:g}")
    if after.bed_temp != before.bed_temp:
        lines.append(f"M140 S{after.bed_temp:g}")
    if fan_command(after, layer) != fan_command(before, layer):
        lines.append(fan_command(after, layer))
    return lines if len(lines) > 1 else []
