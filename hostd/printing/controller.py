"""Commands from the control socket and MQTT, carried out on the daemon's jobs.

Arguments: ``resume_job {"job": ID or NAME}``; ``cancel_object {"object": N}`` (a body
index from 0, also accepted as ``"body"``); ``set {"settings": {KEY: VALUE, ...}}`` or
``set {"key": KEY, "value": VALUE}`` with the flat slicing keys of the configuration;
``queue_move {"job": ID, "index": N}`` (0 = next); ``queue_remove {"job": ID}``;
``restore_object {"object": N}``; ``layer {"layer": N, "tolerance": MM, "field": [COLS, ROWS]}``
and ``estimate {"settings": {...}}`` (see :mod:`hostd.publishing.layerview`);
``emergency_stop`` (``M112``: the printer halts, the job printing fails). The arguments
are read into typed dataclasses by :mod:`hostd.printing.commandargs` (one checker, the settings
helper's fields); a wrong one is refused as ``CMD needs "KEY": REASON``.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

from hostd.jobs.intake import Intake
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstore import JobStoreError
from hostd.printing.activejob import ActiveJob
from hostd.printing.commandargs import (
    ArgumentError,
    EstimateArgs,
    JobArgs,
    LayerArgs,
    ObjectArgs,
    QueueMoveArgs,
    RetuneArgs,
    read_args,
)
from hostd.publishing.status import CommandError


class DaemonController:
    """Implements ``hostd.publishing.status.Controller`` for the daemon.

    ``current`` returns the print in progress (its :class:`~hostd.printing.activejob.ActiveJob`,
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
        except (JobStoreError, ArgumentError) as exc:
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
        job = self.store.find(read_args("resume_job", JobArgs.read, args).job)
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
        body = read_args("cancel_object", ObjectArgs.read, args).object
        first = job.cancel_object(body)
        return {"job": job.job.id, "object": body, "from_layer": first}

    async def _cmd_restore_object(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        body = read_args("restore_object", ObjectArgs.read, args).object
        job.restore_object(body)
        return {"job": job.job.id, "object": body}

    async def _cmd_layer(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        if job.schedule is None:
            raise CommandError("a G-code job has no toolpaths to show")
        view = read_args("layer", LayerArgs.read, args)
        return await job.layer_view(view.layer, view.tolerance, view.field)

    async def _cmd_estimate(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        if job.schedule is None:
            raise CommandError("a G-code job has no toolpaths to show")
        return await job.estimate(read_args("estimate", EstimateArgs.read, args).settings)

    async def _cmd_set(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self._printing()
        changes = read_args("set", RetuneArgs.read, args).settings
        first = job.retune(changes)
        return {"job": job.job.id, "from_layer": first, "settings": changes}

    async def _cmd_queue_move(self, args: dict[str, Any]) -> dict[str, Any]:
        move = read_args("queue_move", QueueMoveArgs.read, args)
        job = self.store.find(move.job)
        queue = self.store.move(job.id, move.index)
        self.changed()
        return {"queue": [item.id for item in queue]}

    async def _cmd_queue_remove(self, args: dict[str, Any]) -> dict[str, Any]:
        job = self.store.find(read_args("queue_remove", JobArgs.read, args).job)
        if job.state not in ("queued", "interrupted"):
            raise CommandError(f"job {job.id} is {job.state}; only queued or interrupted jobs "
                               "can be removed")
        self.intake.fail(job, "removed from the queue", state="cancelled")
        self.changed()
        return {"job": job.id}
