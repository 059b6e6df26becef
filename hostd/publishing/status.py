"""The status hub: the one place where status snapshots and job events are produced."""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import time
from collections.abc import AsyncIterator, Callable
from typing import Any, Protocol

from hostd.api import Snapshot

log = logging.getLogger("hostd.publishing.status")


class Controller(Protocol):
    """What the control socket and the MQTT bridge call to act on the daemon.

    ``handle`` carries out one command of :data:`hostd.api.COMMANDS` with its
    arguments and returns the reply's extra fields; it raises ``CommandError``
    with a user-facing reason when the command is refused.
    """

    async def handle(self, cmd: str, args: dict[str, Any]) -> dict[str, Any]: ...


class CommandError(RuntimeError):
    """A command was refused; the message says why."""


class StatusHub:
    """Holds the current frozen snapshot and fans snapshots and events out to subscribers.

    Producers call :meth:`update` (new snapshot with some fields replaced) and
    :meth:`event`; consumers iterate :meth:`snapshots` or :meth:`events`. A slow
    consumer never blocks a producer: its queue keeps only the newest snapshot.
    """

    def __init__(self, initial: Snapshot | None = None) -> None:
        self._current = initial or Snapshot()
        self._snapshot_queues: set[asyncio.Queue[Snapshot]] = set()
        self._event_queues: set[asyncio.Queue[dict[str, Any]]] = set()
        self._listeners: list[Callable[[dict[str, Any]], None]] = []

    @property
    def current(self) -> Snapshot:
        return self._current

    def update(self, **changes: Any) -> Snapshot:
        """Replace the given top-level fields, stamp the time, notify subscribers."""
        snapshot = dataclasses.replace(self._current, ts=time.time(), **changes)
        self._current = snapshot
        for queue in self._snapshot_queues:
            if queue.full():
                queue.get_nowait()
            queue.put_nowait(snapshot)
        return snapshot

    def event(self, kind: str, **data: Any) -> dict[str, Any]:
        """Publish one job event ``{"event": kind, "ts": ..., **data}``."""
        item = {"event": kind, "ts": time.time(), **data}
        for listener in self._listeners:
            try:
                listener(item)
            except Exception:  # a listener's bug must not stop the producer
                log.exception("event listener failed on %s", kind)
        for queue in self._event_queues:
            if queue.full():
                queue.get_nowait()
            queue.put_nowait(item)
        return item

    def listen(self, listener: Callable[[dict[str, Any]], None]) -> None:
        """Call ``listener(event)`` at once for every event, in order, on the producer's thread.

        For quick bookkeeping that must see the daemon as it is when the event
        happens; anything slow belongs in a worker fed by the listener.
        """
        self._listeners.append(listener)

    async def snapshots(self) -> AsyncIterator[Snapshot]:
        """Every new snapshot from now on (the newest one when the reader lags)."""
        queue: asyncio.Queue[Snapshot] = asyncio.Queue(maxsize=1)
        self._snapshot_queues.add(queue)
        try:
            while True:
                yield await queue.get()
        finally:
            self._snapshot_queues.discard(queue)

    async def events(self) -> AsyncIterator[dict[str, Any]]:
        """Every event from now on (up to 1000 buffered for a slow reader)."""
        queue: asyncio.Queue[dict[str, Any]] = asyncio.Queue(maxsize=1000)
        self._event_queues.add(queue)
        try:
            while True:
                yield await queue.get()
        finally:
            self._event_queues.discard(queue)
