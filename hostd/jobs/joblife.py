"""The one writer of a job's state and of the snapshot's printer state, and its events."""

from __future__ import annotations

import logging
from typing import Any, Protocol

from hostd.api import InterruptedJob, JobStatus, PrinterInfo
from hostd.jobs.jobstate import (
    ACTIVE_STATES,
    HUB_STATE_OF,
    Event,
    HubState,
    Interrupted,
    JobState,
    printed_nothing,
)
from hostd.jobs.jobstore import Job, JobStore

log = logging.getLogger("hostd.jobs.joblife")


class Announcer(Protocol):
    """Where a job's life is told: the status hub (:class:`hostd.publishing.status.StatusHub`),
    which the jobs below it do not import."""

    def update(self, **changes: Any) -> Any:
        """Replace top-level fields of the status snapshot."""
        ...

    def event(self, kind: str, **data: Any) -> dict[str, Any]:
        """Publish one job event."""
        ...


class JobLife:
    """Moves jobs through their states, and keeps the status snapshot in step.

    Every change of a job's recorded state goes through :meth:`enter`, which
    writes the job store first and then, for the job printing, the snapshot's
    state, so that the two never disagree (or through its halves :meth:`record`
    and :meth:`show`, when the store is written in another thread: the
    checkpoint writer's). The snapshot's state without a job
    (offline, idle) is written by :meth:`printer_offline` and :meth:`idle`.

    The daemon builds one and hands it to what changes jobs: the intake and its
    outcomes, the command controller, the farm agent and each print's
    :class:`~hostd.printing.activejob.ActiveJob` (which lends it to its runner).
    """

    def __init__(self, store: JobStore, hub: Announcer) -> None:
        self.store = store
        self.hub = hub

    def enter(
        self,
        job_id: str,
        state: JobState,
        note: str = "",
        status: JobStatus | None = None,
        **fields: Any,
    ) -> Job:
        """Record the job's move to ``state`` (and ``fields``); publish it when active.

        ``status`` replaces the snapshot's job part. Raises ``TransitionError``
        when the state machine forbids the move.
        """
        job = self.record(job_id, state, note, **fields)
        self.show(state, status)
        return job

    def record(
        self, job_id: str, state: JobState, note: str = "", store: JobStore | None = None,
        **fields: Any,
    ) -> Job:
        """The store half of :meth:`enter`: the move recorded, on ``store`` when given
        (another connection to the same database, for a thread of its own)."""
        return (store or self.store).transition(job_id, state, note=note, **fields)

    def show(self, state: JobState, status: JobStatus | None = None) -> None:
        """The snapshot half of :meth:`enter`, once the move is recorded: the state of
        an active job, and ``status`` as its job part."""
        if state in ACTIVE_STATES:
            changes: dict[str, Any] = {"state": HUB_STATE_OF[state].value}
            if state == JobState.SLICING:
                changes["error"] = None
            if status is not None:
                changes["job"] = status
            self.hub.update(**changes)

    def show_job(self, status: JobStatus) -> None:
        """The snapshot's job part, its state unchanged (progress between moves)."""
        self.hub.update(job=status)

    def interrupt(self, job_id: str, note: str) -> Job | None:
        """Leave an active job interrupted at its checkpoint, or queued if it printed nothing.

        Returns the job as recorded afterwards, or None when it was not active.
        """
        job = self.store.get(job_id)
        if job.state not in ACTIVE_STATES:
            return None
        return self._settle_interrupted(self.store.transition(job_id, JobState.INTERRUPTED,
                                                              note=note), job.state)

    def recover(self) -> list[Job]:
        """At start: every job left active is interrupted (or queued again); returns them."""
        found = []
        for job in self.store.jobs(*ACTIVE_STATES):
            stopped = self.store.transition(job.id, JobState.INTERRUPTED,
                                            note=f"found {job.state} at start")
            found.append(self._settle_interrupted(stopped, job.state, report=False))
        return found

    def _settle_interrupted(self, job: Job, was: str, report: bool = True) -> Job:
        if printed_nothing(was, job.layer):
            # nothing was extruded yet: the bed is clear, start it again from the top
            log.warning("job %s %s was stopped before printing; queued again", job.id, job.name)
            return self.store.transition(job.id, JobState.QUEUED,
                                         note="restarted: nothing printed yet")
        if report:
            self.publish(Interrupted(job.id, job.name, job.layer))
        return job

    def request_resume(self, job_id: str, first: int | None) -> Job:
        """Queue an interrupted job again, to continue from layer ``first``."""
        return self.store.transition(job_id, JobState.QUEUED, note="resume requested",
                                     resume_from=first)

    def end(self, job_id: str, state: JobState, reason: str | None, outcome: str) -> Job:
        """Record a job's outcome (done, failed or cancelled) and where its files go."""
        return self.store.transition(job_id, state, note=reason or "", error=reason,
                                     outcome=outcome)

    # -- the snapshot without a job -------------------------------------------

    def printer_offline(self, printer: PrinterInfo, error: str) -> None:
        """The printer link is down."""
        self.hub.update(state=HubState.OFFLINE.value, error=error, printer=printer)

    def printer_online(self, printer: PrinterInfo) -> None:
        """The printer link is up, no job printing."""
        self.hub.update(state=HubState.IDLE.value, error=None, printer=printer)

    def idle(self) -> None:
        """No job is printing any more."""
        self.hub.update(state=HubState.IDLE.value, job=None)

    def publish_queue(self, printing: str | None) -> None:
        """Publish what waits (the queue, without the job ``printing``) and what is interrupted."""
        self.hub.update(
            queue=tuple(job.name for job in self.store.queued() if job.id != printing),
            interrupted=tuple(
                InterruptedJob(job.id, job.name, job.layer) for job in self.store.interrupted()
            ),
        )

    def publish(self, event: Event) -> dict[str, Any]:
        """Publish one job event."""
        return self.hub.event(event.kind.value, **event.fields())
