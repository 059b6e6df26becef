"""The owner of one print: what the job printing holds, and the commands that change it."""

from __future__ import annotations

import asyncio
from typing import Any

from hostd.api import JobStatus
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstate import JobState, ObjectCancelled, ObjectRestored, Retuned
from hostd.jobs.jobstore import Job
from hostd.jobs.schedule import LayerSchedule
from hostd.printing.runner import JobRunner
from hostd.printing.sources import LayerSource
from hostd.publishing import layerview
from hostd.publishing.status import CommandError
from slicer.settings import SettingsError


class ActiveJob:
    """One print, from the moment the daemon takes it from the queue to its outcome.

    The daemon builds one per print (``Daemon.current``) and drops it when the
    print ends. It holds what the print owns: the job's layer schedule and layer
    source (once the whole-model pass made them, :meth:`attach`), its runner
    (:meth:`start`), and the daemon's :class:`~hostd.jobs.joblife.JobLife`, the one
    writer of the job's state, which it lends to the runner.

    The commands of the control socket and MQTT reach the print only through its
    methods: :meth:`pause`, :meth:`resume`, :meth:`cancel`, :meth:`cancel_object`,
    :meth:`restore_object`, :meth:`retune`, :meth:`layer_view` and :meth:`estimate`.
    Each that changes the print changes memory first (the runner, the schedule),
    then the job store, then publishes a typed event (:mod:`hostd.jobs.jobstate`). A
    command the print cannot take raises :class:`~hostd.publishing.status.CommandError`
    with the reason, and changes nothing.
    """

    def __init__(self, job: Job, life: JobLife) -> None:
        self.job = job
        self.life = life
        self.schedule: LayerSchedule | None = None
        self.source: LayerSource | None = None
        self.runner: JobRunner | None = None
        self.emergency = False  # an emergency stop was ordered: the job fails

    # -- what the print owns ---------------------------------------------------

    def enter(self, state: JobState, status: JobStatus | None = None) -> Job:
        """Record the job's move to ``state`` (the store, then the snapshot)."""
        self.job = self.life.enter(self.job.id, state, status=status)
        return self.job

    def attach(self, schedule: LayerSchedule | None, source: LayerSource) -> None:
        """The whole-model pass is done: the print's schedule (None for a G-code file)
        and the source its layers come from."""
        self.schedule = schedule
        self.source = source

    def start(self, runner: JobRunner) -> None:
        """The runner that streams the print; commands reach it from now on."""
        self.runner = runner

    def release(self) -> None:
        """The print ended: let go of everything it owned (schedule, plans, source,
        runner), whoever still holds this object."""
        self.schedule = None
        self.source = None
        self.runner = None

    @property
    def printing(self) -> bool:
        """True once the runner streams the job (commands are taken), until it ends."""
        return self.runner is not None

    # -- commands --------------------------------------------------------------

    async def pause(self) -> None:
        """Stop sending after the lines written and park the nozzle (the runner's)."""
        runner = self._runner()
        if runner.paused:
            raise CommandError("already paused")
        await runner.pause()

    async def resume(self) -> None:
        """Unpark and send on where the pause stopped."""
        runner = self._runner()
        if not runner.paused:
            raise CommandError("not paused")
        await runner.resume()

    async def cancel(self) -> None:
        """No further line of the job; it ends cancelled once the lines in flight ran."""
        await self._runner().cancel()

    def cancel_object(self, body: int) -> int:
        """Leave body ``body`` out of every layer not sliced yet; returns the first such
        layer."""
        schedule, source = self._sliced("a G-code job has no objects to cancel")
        count = int(schedule.base_plan.body_count)
        if not 0 <= body < count:
            raise CommandError(f"object {body} does not exist: the model has {count} bodies")
        left_out = schedule.excluded_at(schedule.layer_count)
        if body in left_out:
            raise CommandError(f"object {body} is already cancelled")
        if len(left_out) + 1 >= count:
            raise CommandError("that would leave no object: cancel the job instead")
        first = source.next_unsliced
        schedule.cancel_body(body, first)
        self.life.store.record_cancelled_object(self.job.id, body, first)
        self.life.publish(ObjectCancelled(self.job.id, self.job.name, body, first))
        return first

    def restore_object(self, body: int) -> None:
        """Slice a cancelled body again, while no layer without it was sliced yet."""
        schedule, source = self._sliced("a G-code job has no objects to restore")
        found = [first for cancelled, first in schedule.cancelled if cancelled == body]
        if not found:
            raise CommandError(f"object {body} is not cancelled")
        if found[-1] < source.next_unsliced:
            raise CommandError(f"object {body} is already left out of sliced layers (from "
                               f"layer {found[-1] + 1} on): too late to bring it back")
        schedule.restore_body(body)
        self.life.store.forget_cancelled_object(self.job.id, body)
        self.life.publish(ObjectRestored(self.job.id, self.job.name, body))

    def retune(self, changes: dict[str, Any]) -> int:
        """Slice the layers not sliced yet with ``changes`` (flat slicing keys); returns
        the first layer they apply to."""
        schedule, source = self._sliced("a G-code job cannot be retuned")
        first = source.next_unsliced
        try:
            schedule.retune(first, changes)
        except SettingsError as exc:
            raise CommandError(str(exc)) from exc
        self.life.store.record_settings(self.job.id, first, changes)
        self.life.publish(Retuned(self.job.id, self.job.name, first, dict(changes)))
        return first

    async def layer_view(self, index: int | None, tolerance: float,
                         field: tuple[int, int] | None) -> dict[str, Any]:
        """Layer ``index``'s toolpaths (None: the layer printing), as
        :func:`~hostd.publishing.layerview.layer_view` draws them, and how far the printer is
        in it."""
        runner = self._runner()
        schedule, source = self._sliced("a G-code job has no toolpaths to show")
        if index is None:
            index = min(runner.completed + 1, schedule.layer_count - 1)
        if not 0 <= index < schedule.layer_count:
            raise CommandError(f"layer {index} does not exist: the job has layers "
                               f"0..{schedule.layer_count - 1}")
        stored = self.life.store.get(self.job.id)
        held = source.held(index)  # the lines streamed or made ahead, when there are
        reply = await asyncio.to_thread(layerview.layer_view, schedule, index, tolerance,
                                        field, held)
        reply["job"] = self.job.id
        reply["acked_before"] = layerview.acked_before(schedule, runner, source, stored, index)
        reply["next_unsliced"] = source.next_unsliced
        return reply

    async def estimate(self, changes: dict[str, Any] | None) -> dict[str, Any]:
        """What the rest of the print would take with ``changes`` (or as it is)."""
        runner = self._runner()
        schedule, source = self._sliced("a G-code job has no toolpaths to show")
        status = runner.status()
        try:
            reply = await asyncio.to_thread(
                layerview.estimate, schedule, runner.completed + 1, source.next_unsliced,
                status.eta_s, changes,
            )
        except SettingsError as exc:
            raise CommandError(str(exc)) from exc
        reply["job"] = self.job.id
        return reply

    # -- refusals --------------------------------------------------------------

    def _runner(self) -> JobRunner:
        if self.runner is None:
            raise CommandError("no job is printing")
        return self.runner

    def _sliced(self, refusal: str) -> tuple[LayerSchedule, LayerSource]:
        """The schedule and source of a sliced job printing; ``refusal`` for a G-code file."""
        self._runner()
        if self.schedule is None or self.source is None:
            raise CommandError(refusal)
        return self.schedule, self.source
