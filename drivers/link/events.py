"""What the protocol core tells its shell: the link's state and the events it produces."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:  # an annotation only: reading a configuration needs no response parser
    from drivers.link.responses import Response


class LinkState(StrEnum):
    """The link's state; each value equals the string the daemon and the API report."""

    DISCONNECTED = "disconnected"
    CONNECTING = "connecting"
    RECONNECTING = "reconnecting"
    READY = "ready"
    PAUSED = "paused"
    CANCELLED = "cancelled"
    ERROR = "error"
    HALTED = "halted"


# states in which nothing is written
STOPPED = frozenset({LinkState.ERROR, LinkState.HALTED, LinkState.DISCONNECTED,
                     LinkState.RECONNECTING})


class Written(NamedTuple):
    """A job line (``token`` from ``queue_job``) went out as line ``number``."""

    token: int
    number: int


class Acked(NamedTuple):
    """A line was acknowledged for the first time.

    ``job`` is False for the link's own lines (``M110``, ``M105``...); ``token`` is the
    handle given when it was queued (``None``: nobody waits for it).
    """

    number: int
    command: str
    job: bool
    token: int | None


@dataclass(frozen=True)
class Temperature:
    """A temperature report (``ok T:...``, auto-report or a heating wait's lines)."""

    response: Response


@dataclass(frozen=True)
class Report:
    """A printer error or a link problem worth telling the user about."""

    text: str


@dataclass(frozen=True)
class Failed:
    """The link failed or the printer halted: every waiter fails with ``reason``."""

    reason: str


@dataclass(frozen=True)
class Booted:
    """The printer announced a boot: its ``start`` banner was read (at connect, or a
    reset mid-stream)."""


@dataclass(frozen=True)
class Connected:
    """The handshake is done: the link is ready to stream (:mod:`drivers.link.handshake`)."""


Event = Written | Acked | Temperature | Report | Failed | Connected | Booted
