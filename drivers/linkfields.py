"""What the protocol core's mixins share: its fields and methods, declared once for typing."""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

from drivers.linkconfig import StreamerConfig, StreamStats
from drivers.linkevents import Event, LinkState
from drivers.linkmodel import PrinterModel
from drivers.window import SendWindow

if TYPE_CHECKING:
    from drivers.linkwrite import Control, Renumber


class CoreFields:
    """The state of :class:`~drivers.linkcore.LinkCore` that its mixins (``Resync``,
    ``Writing``, ``Watching``) read and write; set in ``LinkCore.__init__``.

    Annotations only (no values): this class adds nothing at run time.
    """

    config: StreamerConfig
    stats: StreamStats
    capabilities: dict[str, str]
    state: LinkState
    window: SendWindow
    model: PrinterModel
    history: dict[int, tuple[str, bool]]
    next_number: int
    replay_next: int | None
    last_acked_number: int
    control: deque[Control]
    pending: deque[tuple[str, int]]
    renumber: Renumber | None
    paused: bool
    cancelled: bool
    stopping: bool
    force_replay: bool
    doubt: bool  # an answer may have been taken for an owed one: probe soon if silent
    resolving: bool  # a probe asked after a refusal left oks uncertain: no job line until answered
    fenced: bool
    started: bool
    connect_at: float
    last_rx: float
    last_answer: float
    last_poll: float
    probes_unanswered: int
    reports_unanswered: int
    last_probe_at: float
    over_budget: int
    reconnected_at: float
    _answers_owed: list[int]  # probes acknowledged ahead of their answers, still to come
    _events: list[Event]

    # methods of the core or of another mixin
    @property
    def capable(self) -> frozenset[str]:
        raise NotImplementedError

    def take_events(self) -> list[Event]:
        raise NotImplementedError

    def fail(self, reason: str) -> None:
        raise NotImplementedError

    def on_reset(self) -> None:
        raise NotImplementedError

    def may_force(self, nbytes: int, now: float, take: bool = True) -> bool:
        raise NotImplementedError

    def remember_waiter(self, number: int, token: int) -> None:
        raise NotImplementedError

    def queue_control(self, command: str, *, internal: bool, token: int | None = None,
                      probe: bool = False, force: bool = False, front: bool = False) -> None:
        raise NotImplementedError
