"""Futures for the protocol core's tokens: who waits for which line, in the asyncio shell."""

from __future__ import annotations

import asyncio


class Waiters:
    """Tokens handed to the core, each with the future its caller awaits."""

    def __init__(self) -> None:
        self._futures: dict[int, asyncio.Future[int]] = {}
        self._last = 0

    def new(self) -> tuple[int, asyncio.Future[int]]:
        """A fresh token and its future (in the running loop)."""
        self._last += 1
        future: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        self._futures[self._last] = future
        return self._last, future

    def token(self) -> int:
        """A fresh token with no future yet (a line of a batch nobody awaits alone)."""
        self._last += 1
        return self._last

    def wait_for(self, token: int) -> asyncio.Future[int]:
        """The future of ``token`` (from :meth:`token`), resolved as :meth:`new`'s are."""
        future: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        self._futures[token] = future
        return future

    def settle(self, token: int, *, result: int = 0, error: Exception | None = None) -> None:
        """Resolve ``token``'s future with ``result`` (a line number) or ``error``."""
        future = self._futures.pop(token, None)
        if future is None or future.done():
            return
        if error is not None:
            future.set_exception(error)
        else:
            future.set_result(result)

    def fail_all(self, error: Exception) -> None:
        """Every future still waiting fails with ``error``."""
        futures, self._futures = self._futures, {}
        for future in futures.values():
            if not future.done():
                future.set_exception(error)
