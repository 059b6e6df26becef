"""Tagged acknowledgements: each job line's tag, given to ``send()``, delivered back in order."""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import AsyncIterator, Hashable
from dataclasses import dataclass


@dataclass(frozen=True)
class Ack:
    """A job line the printer acknowledged (once, in the order written).

    ``number`` is the line number it was written under, ``command`` the command,
    ``tag`` what the caller gave ``send()`` for it (``None``: untagged, such as the
    park moves of a pause or the end G-code of a cancel).
    """

    number: int
    command: str
    tag: Hashable | None


class AckChannel:
    """The acknowledgements of one listener, oldest first; fed by the link's reader.

    ``take()`` returns what arrived without waiting; ``async for ack in channel``
    waits for more until the channel is closed (the listener detached).
    """

    def __init__(self) -> None:
        self._queue: deque[Ack] = deque()
        self._ready = asyncio.Event()
        self.closed = False

    def put(self, ack: Ack) -> None:
        """One acknowledgement (called by the link; never waits)."""
        if not self.closed:
            self._queue.append(ack)
            self._ready.set()

    def take(self) -> list[Ack]:
        """Every acknowledgement delivered and not taken yet."""
        acks = list(self._queue)
        self._queue.clear()
        self._ready.clear()
        return acks

    def close(self) -> None:
        """No more acknowledgements: iteration ends once the queue is empty."""
        self.closed = True
        self._ready.set()

    async def __aiter__(self) -> AsyncIterator[Ack]:
        while True:
            while self._queue:
                yield self._queue.popleft()
            if self.closed:
                return
            self._ready.clear()
            await self._ready.wait()


class Tags:
    """Which tag belongs to which line: by the send's token until written, then by number.

    A line number is reused only after a renumbering, once every line written under
    the old numbering was acknowledged; a newly written line replaces any stale entry.
    """

    def __init__(self) -> None:
        self._by_token: dict[int, Hashable] = {}
        self._by_number: dict[int, Hashable] = {}

    def queued(self, token: int, tag: Hashable | None) -> None:
        """A job line was queued under ``token``."""
        if tag is not None:
            self._by_token[token] = tag

    def written(self, token: int, number: int) -> None:
        """The line queued under ``token`` went out as line ``number``."""
        tag = self._by_token.pop(token, None)
        if tag is None:
            self._by_number.pop(number, None)
        else:
            self._by_number[number] = tag

    def dropped(self, token: int) -> None:
        """The line queued under ``token`` will never be written (a cancel)."""
        self._by_token.pop(token, None)

    def acked(self, number: int) -> Hashable | None:
        """The tag of line ``number``, acknowledged now (forgotten)."""
        return self._by_number.pop(number, None)

    def clear(self) -> None:
        """Forget everything (the link closed or failed)."""
        self._by_token.clear()
        self._by_number.clear()
