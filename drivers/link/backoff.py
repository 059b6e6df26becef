"""Jittered exponential backoff: the one reconnect policy (printer link, MQTT) and loop."""

from __future__ import annotations

import asyncio
import random
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass
from typing import TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class Backoff:
    """Reconnect delays in seconds: the ceiling grows by ``factor`` from ``initial_s`` up
    to ``maximum_s``, and each wait is drawn from half to all of it, so that hosts that
    lost one shared link (a broker, a USB hub) do not retry in step."""

    initial_s: float = 0.5
    maximum_s: float = 30.0
    factor: float = 2.0

    def delay(self, attempt: int, rng: random.Random) -> float:
        """The wait before reconnect attempt ``attempt`` (0-based): half to all of the ceiling."""
        ceiling = min(self.maximum_s, self.initial_s * self.factor ** min(attempt, 64))
        return rng.uniform(ceiling / 2, ceiling)

    def delays(self, rng: random.Random) -> Iterator[float]:
        """The waits before attempts 0, 1, 2, ... (endless)."""
        attempt = 0
        while True:
            yield self.delay(attempt, rng)
            attempt += 1


async def reconnect(
    attempt: Callable[[], Awaitable[T]],
    policy: Backoff,
    *,
    errors: tuple[type[Exception], ...],
    attempts: int | None = None,
    wait_first: bool = False,
    failed: Callable[[Exception, float], None] | None = None,
    rng: random.Random | None = None,
) -> T:
    """``await attempt()`` until it succeeds, waiting ``policy``'s jittered delays between
    tries: the one reconnect loop of the printer link (the port reopened by the streamer,
    the link reopened by the daemon).

    ``errors`` are the failures that mean "try again"; after ``attempts`` tries (None: no
    end) the last one is raised. ``wait_first``: wait before the first try too (a port just
    lost, a link just failed). ``failed(error, wait)`` is told of each failure before its
    wait.
    """
    delays = policy.delays(rng or random.Random())
    if wait_first:
        await asyncio.sleep(next(delays))
    tries = 0
    while True:
        try:
            return await attempt()
        except errors as exc:
            tries += 1
            if attempts is not None and tries >= attempts:
                raise
            wait = next(delays)
            if failed is not None:
                failed(exc, wait)
            await asyncio.sleep(wait)
