"""Jittered exponential backoff: the one reconnect delay policy of the printer link and MQTT."""

from __future__ import annotations

import random
from collections.abc import Iterator
from dataclasses import dataclass


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
