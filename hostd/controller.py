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

from collections.abc import Awaitable, Callable
from typing import Any

from hostd.activejob import ActiveJob
from hostd.intake import Intake
from hostd.joblife import JobLife
from hostd.jobstore import JobStoreError
from hostd.status import CommandError


class DaemonController:
    """Implements ``hostd.status.Controller`` for the daemon.

    ``current`` returns the print in progress (its :class:`~hostd.activejob.ActiveJob`,
    or None); ``changed`` is called after the queue or the set of interrupted jobs
    changed. The controller reads the commands' arguments; what they do to the print
    is the active job's (its methods), and to the queue the job store's and the
    job's life's.
    """

    def __init__(
        self,
        life: JobLife,
        intake: Intake,
        current: Callable[[], ActiveJob | None],
        changed: Callable[[], None],
        emergency_stop: Callable[[], Awaitable[bool]] | None = None,
    ) -> None:
        """``emergency_stop()`` sends ``M112`` to the printer; False when none is connected."""
        self.life = life
        self.store = life.store
        self.hub = life.hub
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

    def _printing(self) -> ActiveJob:
        job = self.current()
        if job is None or not job.printing:
            raise CommandError("no job is printing")
        return job

    async def _cmd_status(self, args: dict[str, Any]) -> dict[str, Any]:
        return {"status": self.hub.current.to_dict()}

    async def _cmd_pause(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        await job.pause()
        return {"job": job.job.id}

    async def _cmd_resume(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        await job.resume()
        return {"job": job.job.id}

    async def _cmd_cancel(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        await job.cancel()
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
        first = job.cancel_object(raw)
        return {"job": job.job.id, "object": raw, "from_layer": first}

    async def _cmd_restore_object(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        raw = args.get("object", args.get("body"))
        if isinstance(raw, bool) or not isinstance(raw, int):
            raise CommandError("restore_object needs \"object\": a body number from 0")
        job.restore_object(raw)
        return {"job": job.job.id, "object": raw}

    async def _cmd_layer(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        if job.schedule is None:
            raise CommandError("a G-code job has no toolpaths to show")
        index = args.get("layer")
        if index is not None and (isinstance(index, bool) or not isinstance(index, int)):
            raise CommandError("layer needs \"layer\": a layer index from 0")
        tolerance = args.get("tolerance", 0.2)
        field = args.get("field")
        if not isinstance(tolerance, int | float) or not 0 <= tolerance <= 50:
            raise CommandError("\"tolerance\" must be a number of mm from 0 to 50")
        if field is not None and not (
            isinstance(field, list) and len(field) == 2
            and all(isinstance(v, int) and 0 < v <= 1000 for v in field)
        ):
            raise CommandError("\"field\" must be [columns, rows], each 1..1000")
        shape = (field[0], field[1]) if field else None
        return await job.layer_view(index, float(tolerance), shape)

    async def _cmd_estimate(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        if job.schedule is None:
            raise CommandError("a G-code job has no toolpaths to show")
        changes = args.get("settings")
        if changes is not None and (not isinstance(changes, dict) or not changes):
            raise CommandError("estimate takes \"settings\": {KEY: VALUE, ...}")
        return await job.estimate(changes)

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
        first = job.retune(changes)
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
