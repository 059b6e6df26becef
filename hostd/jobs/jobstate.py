"""A job's states, the moves between them, and the events of its life, as enums and dataclasses."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar


class JobState(StrEnum):
    """Where a job is in its life, as the job store records it."""

    QUEUED = "queued"
    SLICING = "slicing"
    HEATING = "heating"
    PRINTING = "printing"
    PAUSED = "paused"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"
    INTERRUPTED = "interrupted"


class HubState(StrEnum):
    """The printer's state in the status snapshot (``hostd.api.STATES``)."""

    IDLE = "idle"
    HEATING = "heating"
    PRINTING = "printing"
    PAUSED = "paused"
    ERROR = "error"
    OFFLINE = "offline"


STATES: tuple[JobState, ...] = tuple(JobState)
ACTIVE_STATES = (JobState.SLICING, JobState.HEATING, JobState.PRINTING, JobState.PAUSED)
FINAL_STATES = (JobState.DONE, JobState.FAILED, JobState.CANCELLED)

# state -> states it may move to
TRANSITIONS: dict[JobState, frozenset[JobState]] = {
    JobState.QUEUED: frozenset({JobState.SLICING, JobState.PRINTING, JobState.FAILED,
                                JobState.CANCELLED, JobState.INTERRUPTED}),
    JobState.SLICING: frozenset({JobState.HEATING, JobState.PRINTING, JobState.FAILED,
                                 JobState.CANCELLED, JobState.INTERRUPTED}),
    JobState.HEATING: frozenset({JobState.PRINTING, JobState.PAUSED, JobState.FAILED,
                                 JobState.CANCELLED, JobState.INTERRUPTED}),
    JobState.PRINTING: frozenset({JobState.PAUSED, JobState.DONE, JobState.FAILED,
                                  JobState.CANCELLED, JobState.INTERRUPTED}),
    JobState.PAUSED: frozenset({JobState.PRINTING, JobState.HEATING, JobState.FAILED,
                                JobState.CANCELLED, JobState.INTERRUPTED}),
    JobState.INTERRUPTED: frozenset({JobState.QUEUED, JobState.FAILED, JobState.CANCELLED}),
    JobState.DONE: frozenset(),
    JobState.FAILED: frozenset(),
    JobState.CANCELLED: frozenset(),
}

# the snapshot's state while a job is in one of the active states
HUB_STATE_OF: dict[JobState, HubState] = {
    JobState.SLICING: HubState.HEATING,  # the start block heats while the first layer slices
    JobState.HEATING: HubState.HEATING,
    JobState.PRINTING: HubState.PRINTING,
    JobState.PAUSED: HubState.PAUSED,
}


def printed_nothing(state: str, layer: int) -> bool:
    """The rule for an interrupted job: True when nothing of it can be on the bed.

    A job stopped while ``slicing`` or ``heating`` with no layer completed
    (``layer`` = last completed layer, -1 for none) never reached its first
    extruding move: it is queued again and starts from the top. Any other
    interrupted job waits to be resumed, its part on the bed.
    """
    return state in (JobState.SLICING, JobState.HEATING) and layer < 0


class EventKind(StrEnum):
    """The kinds of job event (``hostd.api.EVENTS``)."""

    QUEUED = "queued"
    STARTED = "started"
    LAYER = "layer"
    PAUSED = "paused"
    RESUMED = "resumed"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"
    INTERRUPTED = "interrupted"
    OBJECT_CANCELLED = "object_cancelled"
    OBJECT_RESTORED = "object_restored"
    RETUNED = "retuned"
    ERROR = "error"
    REPAIRED = "repaired"


@dataclass(frozen=True)
class Event:
    """A job event; subclasses name their kind and carry their fields."""

    kind: ClassVar[EventKind]

    def fields(self) -> dict[str, Any]:
        """The event's data as published: ``{"event": kind, "ts": ...}`` plus these."""
        return {item.name: getattr(self, item.name) for item in dataclasses.fields(self)}


@dataclass(frozen=True)
class Queued(Event):
    """A dropped file was taken and queued."""

    kind: ClassVar[EventKind] = EventKind.QUEUED
    id: str
    name: str


@dataclass(frozen=True)
class Started(Event):
    """A job began streaming (``resumed_from``: first layer of a resume, else None)."""

    kind: ClassVar[EventKind] = EventKind.STARTED
    id: str
    name: str
    layers: int
    resumed_from: int | None


@dataclass(frozen=True)
class LayerDone(Event):
    """Every line of ``layer`` was acknowledged."""

    kind: ClassVar[EventKind] = EventKind.LAYER
    id: str
    name: str
    layer: int
    layers: int


@dataclass(frozen=True)
class Paused(Event):
    """Sending stopped by command (``layer``: last completed layer)."""

    kind: ClassVar[EventKind] = EventKind.PAUSED
    id: str
    name: str
    layer: int


@dataclass(frozen=True)
class Resumed(Event):
    """Sending continues after a pause."""

    kind: ClassVar[EventKind] = EventKind.RESUMED
    id: str
    name: str
    layer: int


@dataclass(frozen=True)
class Interrupted(Event):
    """A job stopped by a crash, a stop or a lost printer, to be resumed."""

    kind: ClassVar[EventKind] = EventKind.INTERRUPTED
    id: str
    name: str
    layer: int


@dataclass(frozen=True)
class Done(Event):
    """A job ended well; ``gcode`` is its G-code file in done/."""

    kind: ClassVar[EventKind] = EventKind.DONE
    id: str
    name: str
    gcode: str


@dataclass(frozen=True)
class Failed(Event):
    """A job ended in failed/ with ``reason``."""

    kind: ClassVar[EventKind] = EventKind.FAILED
    id: str
    name: str
    reason: str


@dataclass(frozen=True)
class Cancelled(Event):
    """A job was cancelled or removed from the queue."""

    kind: ClassVar[EventKind] = EventKind.CANCELLED
    id: str
    name: str
    reason: str


@dataclass(frozen=True)
class ObjectCancelled(Event):
    """A body is left out from ``from_layer`` on."""

    kind: ClassVar[EventKind] = EventKind.OBJECT_CANCELLED
    id: str
    name: str
    object: int
    from_layer: int


@dataclass(frozen=True)
class ObjectRestored(Event):
    """A cancelled body is sliced again (no layer without it was sliced yet)."""

    kind: ClassVar[EventKind] = EventKind.OBJECT_RESTORED
    id: str
    name: str
    object: int


@dataclass(frozen=True)
class Retuned(Event):
    """The layers from ``from_layer`` on are sliced with ``settings`` (flat keys)."""

    kind: ClassVar[EventKind] = EventKind.RETUNED
    id: str
    name: str
    from_layer: int
    settings: dict[str, Any]


@dataclass(frozen=True)
class ModelRepaired(Event):
    """The slicer repaired the model (``message`` says what); the print goes on."""

    kind: ClassVar[EventKind] = EventKind.REPAIRED
    id: str
    name: str
    message: str


@dataclass(frozen=True)
class JobError(Event):
    """Something went wrong with a job's files or records; the print goes on."""

    kind: ClassVar[EventKind] = EventKind.ERROR
    id: str
    message: str


@dataclass(frozen=True)
class PrinterError(Event):
    """The printer reported an error."""

    kind: ClassVar[EventKind] = EventKind.ERROR
    message: str
    source: str = "printer"


def ended(state: JobState, job_id: str, name: str, reason: str) -> Event:
    """The event of a job ending ``failed`` or ``cancelled``."""
    if state == JobState.CANCELLED:
        return Cancelled(job_id, name, reason)
    return Failed(job_id, name, reason)
