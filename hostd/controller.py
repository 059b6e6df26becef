"""Commands from the control socket and MQTT, carried out on the daemon's jobs.

Arguments: ``resume_job {"job": ID or NAME}``; ``cancel_object {"object": N}`` (a body
index from 0, also accepted as ``"body"``); ``set {"settings": {KEY: VALUE, ...}}`` or
``set {"key": KEY, "value": VALUE}`` with the flat slicing keys of the configuration;
``queue_move {"job": ID, "index": N}`` (0 = next); ``queue_remove {"job": ID}``;
``restore_object {"object": N}``; ``layer {"layer": N, "tolerance": MM, "field": [COLS, ROWS]}``
and ``estimate {"settings": {...}}`` (see :mod:`hostd.layerview`);
``emergency_stop`` (``M112``: the printer halts, the job printing fails).
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Any

from hostd import layerview
from hostd.intake import Intake
from hostd.joblife import JobLife
from hostd.jobstate import ObjectCancelled, ObjectRestored
from hostd.jobstore import JobStore, JobStoreError
from hostd.printjob import PrintJob
from hostd.status import CommandError, StatusHub
from slicer.settings import SettingsError


class DaemonController:
    """Implements ``hostd.status.Controller`` for the daemon.

    ``current`` returns the job being printed (or None); ``changed`` is called
    after the queue or the set of interrupted jobs changed.
    """

    def __init__(
        self,
        store: JobStore,
        hub: StatusHub,
        intake: Intake,
        current: Callable[[], PrintJob | None],
        changed: Callable[[], None],
        emergency_stop: Callable[[], Awaitable[bool]] | None = None,
    ) -> None:
        """``emergency_stop()`` sends ``M112`` to the printer; False when none is connected."""
        self.store = store
        self.hub = hub
        self.life = JobLife(store, hub)
        self.intake = intake
        self.current = current
        self.changed = changed
        self.emergency_stop = emergency_stop

    async def handle(self, cmd: str, args: dict[str, Any]) -> dict[str, Any]:
        """Carry out one command; raises CommandError with the reason when refused."""
        handler = getattr(self, f"_cmd_{cmd}", None)
        if handler is None:
            raise CommandError(f"unknown command {cmd!r}")
        try:
            return await handler(args)
        except JobStoreError as exc:
            raise CommandError(str(exc)) from exc

    def _printing(self) -> PrintJob:
        job = self.current()
        if job is None or job.runner is None:
            raise CommandError("no job is printing")
        return job

    async def _cmd_status(self, args: dict[str, Any]) -> dict[str, Any]:
        return {"status": self.hub.current.to_dict()}

    async def _cmd_pause(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        if job.runner.paused:
            raise CommandError("already paused")
        await job.runner.pause()
        return {"job": job.job.id}

    async def _cmd_resume(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        if not job.runner.paused:
            raise CommandError("not paused")
        await job.runner.resume()
        return {"job": job.job.id}

    async def _cmd_cancel(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        await job.runner.cancel()
        return {"job": job.job.id}

    async def _cmd_emergency_stop(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self.current()
        if job is not None:
            job.emergency = True  # the job fails: a halted printer's part is not resumed
        if self.emergency_stop is None or not await self.emergency_stop():
            raise CommandError("no printer is connected")
        return {"job": job.job.id if job is not None else None}

    async def _cmd_resume_job(self, args: dict[str, Any]) -> dict[str, Any]:
        ref = _text(args, "job")
        job = self.store.find(ref)
        if job.state != "interrupted":
            raise CommandError(f"job {job.id} ({job.name}) is {job.state}, not interrupted")
        if job.kind == "gcode" and job.layer >= 0:
            raise CommandError(f"job {job.id} is a G-code file; it cannot be resumed mid-file")
        # a sliced job continues in the layer it was in; one with nothing printed starts anew
        started = job.layer >= 0 or (job.layer_lines > 0 and job.kind == "stl")
        first = job.layer + 1 if started else None
        self.life.request_resume(job.id, first)
        self.changed()
        return {"job": job.id, "name": job.name, "from_layer": first or 0}

    async def _cmd_cancel_object(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        raw = args.get("object", args.get("body"))
        if isinstance(raw, bool) or not isinstance(raw, int):
            raise CommandError("cancel_object needs \"object\": a body number from 0")
        if job.schedule is None or job.source is None:
            raise CommandError("a G-code job has no objects to cancel")
        count = int(job.schedule.base_plan.body_count)
        if not 0 <= raw < count:
            raise CommandError(f"object {raw} does not exist: the model has {count} bodies")
        if raw in job.schedule.excluded_at(job.schedule.layer_count):
            raise CommandError(f"object {raw} is already cancelled")
        if len(job.schedule.excluded_at(job.schedule.layer_count)) + 1 >= count:
            raise CommandError("that would leave no object: cancel the job instead")
        first = job.source.next_unsliced
        job.schedule.cancel_body(raw, first)
        self.store.record_cancelled_object(job.job.id, raw, first)
        self.life.publish(ObjectCancelled(job.job.id, job.job.name, raw, first))
        return {"job": job.job.id, "object": raw, "from_layer": first}

    async def _cmd_restore_object(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        raw = args.get("object", args.get("body"))
        if isinstance(raw, bool) or not isinstance(raw, int):
            raise CommandError("restore_object needs \"object\": a body number from 0")
        if job.schedule is None or job.source is None:
            raise CommandError("a G-code job has no objects to restore")
        found = [first for body, first in job.schedule.cancelled if body == raw]
        if not found:
            raise CommandError(f"object {raw} is not cancelled")
        first = job.source.next_unsliced
        if found[-1] < first:
            raise CommandError(f"object {raw} is already left out of sliced layers (from layer "
                               f"{found[-1] + 1} on): too late to bring it back")
        job.schedule.cancelled = [item for item in job.schedule.cancelled if item[0] != raw]
        self.store.forget_cancelled_object(job.job.id, raw)
        self.life.publish(ObjectRestored(job.job.id, job.job.name, raw))
        return {"job": job.job.id, "object": raw}

    def _sliced(self) -> PrintJob:
        job = self._printing()
        if job.schedule is None or job.source is None:
            raise CommandError("a G-code job has no toolpaths to show")
        return job

    async def _cmd_layer(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._sliced()
        runner, schedule = job.runner, job.schedule
        index = args.get("layer", min(runner.completed + 1, schedule.layer_count - 1))
        if isinstance(index, bool) or not isinstance(index, int):
            raise CommandError("layer needs \"layer\": a layer index from 0")
        if not 0 <= index < schedule.layer_count:
            raise CommandError(f"layer {index} does not exist: the job has layers "
                               f"0..{schedule.layer_count - 1}")
        tolerance = args.get("tolerance", 0.2)
        field = args.get("field")
        if not isinstance(tolerance, int | float) or not 0 <= tolerance <= 50:
            raise CommandError("\"tolerance\" must be a number of mm from 0 to 50")
        if field is not None and not (
            isinstance(field, list) and len(field) == 2
            and all(isinstance(v, int) and 0 < v <= 1000 for v in field)
        ):
            raise CommandError("\"field\" must be [columns, rows], each 1..1000")
        stored = self.store.get(job.job.id)
        held = job.source.held(index)  # the lines streamed or made ahead, when there are
        reply = await asyncio.to_thread(
            layerview.layer_view, schedule, index, float(tolerance),
            tuple(field) if field else None, held,
        )
        reply["job"] = job.job.id
        reply["acked_before"] = layerview.acked_before(schedule, runner, job.source, stored, index)
        reply["next_unsliced"] = job.source.next_unsliced
        return reply

    async def _cmd_estimate(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._sliced()
        changes = args.get("settings")
        if changes is not None and (not isinstance(changes, dict) or not changes):
            raise CommandError("estimate takes \"settings\": {KEY: VALUE, ...}")
        status = job.runner.status()
        try:
            reply = await asyncio.to_thread(
                layerview.estimate, job.schedule, job.runner.completed + 1,
                job.source.next_unsliced, status.eta_s, changes,
            )
        except SettingsError as exc:
            raise CommandError(str(exc)) from exc
        reply["job"] = job.job.id
        return reply

    async def _cmd_set(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        if "settings" in args:
            changes = args["settings"]
            if not isinstance(changes, dict) or not changes:
                raise CommandError("set needs \"settings\": {KEY: VALUE, ...}")
        elif "key" in args and "value" in args:
            changes = {_text(args, "key"): args["value"]}
        else:
            raise CommandError("set needs \"settings\" or \"key\" and \"value\"")
        if job.schedule is None or job.source is None:
            raise CommandError("a G-code job cannot be retuned")
        first = job.source.next_unsliced
        try:
            job.schedule.retune(first, changes)
        except SettingsError as exc:
            raise CommandError(str(exc)) from exc
        self.store.record_settings(job.job.id, first, changes)
        return {"job": job.job.id, "from_layer": first, "settings": changes}

    async def _cmd_queue_move(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self.store.find(_text(args, "job"))
        index = args.get("index")
        if isinstance(index, bool) or not isinstance(index, int) or index < 0:
            raise CommandError("queue_move needs \"index\": 0 or more")
        queue = self.store.move(job.id, index)
        self.changed()
        return {"queue": [item.id for item in queue]}

    async def _cmd_queue_remove(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self.store.find(_text(args, "job"))
        if job.state not in ("queued", "interrupted"):
            raise CommandError(f"job {job.id} is {job.state}; only queued or interrupted jobs "
                               "can be removed")
        self.intake.fail(job, "removed from the queue", state="cancelled")
        self.changed()
        return {"job": job.id}


def _text(args: dict[str, Any], key: str) -> str:
    value = args.get(key)
    if isinstance(value, int) and not isinstance(value, bool):
        value = str(value)
    if not isinstance(value, str) or not value:
        raise CommandError(f"missing \"{key}\"")
    return value
