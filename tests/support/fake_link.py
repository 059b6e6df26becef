"""An in-memory printer link for the runner (``hostd.printing.runner.Link``): no wire, no printer.

Each line is carried out and acknowledged as it is written; what the link carried out,
in order, is :attr:`FakeLink.executed`. The test decides where it stops: after
``hold_at`` job lines a send waits (as when the send-ahead window is full) until
:meth:`release`; ``fail_at`` makes a job line fail as a lost printer does.
"""

from __future__ import annotations

import asyncio
from collections.abc import Hashable, Iterable, Iterator
from contextlib import contextmanager

from drivers.link.acks import Ack, AckChannel
from drivers.link.errors import LinkError, StreamCancelled


class FakeLink:
    """Pause, resume, cancel and tagged acknowledgements as ``drivers.link.streamer.Streamer``
    gives them, on a printer that carries out every line at once."""

    def __init__(self, hold_at: int | None = None, fail_at: int | None = None) -> None:
        self.executed: list[str] = []  # every line carried out, job or not, in order
        self.tags: list[Hashable | None] = []  # the tag of each line of `executed`
        self.job_lines = 0  # job lines written (tagged or not) since the link opened
        self.paused = False
        self.cancelled = False
        self.hold_at = hold_at
        self.fail_at = fail_at
        self.holding = asyncio.Event()  # a send waits at `hold_at`
        self.waiting_resume = asyncio.Event()  # a send waits for the pause to end
        self._released = asyncio.Event()
        self._running = asyncio.Event()
        self._running.set()
        self._channel: AckChannel | None = None

    # -- what the runner calls ----------------------------------------------------------

    async def send(self, command: str, tag: Hashable | None = None) -> int:
        """Carry out one job line; waits at ``hold_at`` and while paused."""
        if self.cancelled:
            raise StreamCancelled("stream cancelled")
        if self.fail_at is not None and self.job_lines >= self.fail_at:
            raise LinkError("the printer stopped answering")
        if self.hold_at is not None and self.job_lines >= self.hold_at:
            self.holding.set()
            await self._released.wait()
        while not self._running.is_set():
            self.waiting_resume.set()
            await self._running.wait()
        if self.cancelled:
            raise StreamCancelled("stream cancelled")
        self.job_lines += 1
        return self._carry_out(command, tag)

    async def send_many(self, commands: Iterable[tuple[str, Hashable | None]]) -> int | None:
        """Carry out each line in turn as :meth:`send` does; the last one's number."""
        number = None
        for command, tag in commands:
            number = await self.send(command, tag)
        return number

    async def drain(self) -> None:
        """Every line written is acknowledged already."""
        await asyncio.sleep(0)

    @contextmanager
    def acknowledgements(self) -> Iterator[AckChannel]:
        """One listener's channel of acknowledgements, closed when the block ends."""
        if self._channel is not None:
            raise RuntimeError("a listener is already attached to the acknowledgements")
        channel = self._channel = AckChannel()
        try:
            yield channel
        finally:
            self._channel = None
            channel.close()

    async def pause(self, park: Iterable[str] | None = None, *, settle: bool = True) -> None:
        """Stop after the lines written; then carry out ``park``."""
        self.paused = True
        self._running.clear()
        for command in park or ():
            self._carry_out(command, None)

    async def resume(self, unpark: Iterable[str] | None = None) -> None:
        """Carry out ``unpark``, then let the job's lines through again."""
        for command in unpark or ():
            self._carry_out(command, None)
        self.paused = False
        self.waiting_resume.clear()
        self._running.set()

    async def cancel(self, end_gcode: Iterable[str] = (), *, settle: bool = True) -> None:
        """Refuse every job line from now on (those waiting too); carry out ``end_gcode``."""
        self.cancelled = True
        self._running.set()
        self._released.set()
        for command in end_gcode:
            self._carry_out(command, None)

    async def interrupt_wait(self) -> None:
        """``M108``: out of band, at once."""
        self._carry_out("M108", None)

    # -- what the test calls ------------------------------------------------------------

    def release(self) -> None:
        """Let the send waiting at ``hold_at`` (and every later one) through."""
        self.hold_at = None
        self._released.set()

    def _carry_out(self, command: str, tag: Hashable | None) -> int:
        self.executed.append(command)
        self.tags.append(tag)
        number = len(self.executed)
        if self._channel is not None:
            self._channel.put(Ack(number, command, tag))
        return number
