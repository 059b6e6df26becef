"""Seeded fault injection for the simulated printer: one generator and counter per kind."""

from __future__ import annotations

import random
import threading
from collections import Counter

from drivers.simconfig import FAULT_KINDS, SimulatorConfig


class FaultInjector:
    """Decides, reproducibly for a seed, whether each fault fires, and counts both.

    Each kind has its own generator (seeded from ``seed`` and the kind's name), so enabling
    one kind never shifts the draws of another.
    """

    def __init__(self, config: SimulatorConfig) -> None:
        self._p = {kind: float(getattr(config, f"p_{kind}")) for kind in FAULT_KINDS}
        self._rng = {kind: random.Random(f"{config.seed}:{kind}") for kind in FAULT_KINDS}
        self._lock = threading.Lock()
        self.fired: Counter[str] = Counter()
        self.chances: Counter[str] = Counter()

    def fires(self, kind: str) -> bool:
        """One chance for ``kind``: True with its configured probability."""
        p = self._p[kind]
        if p <= 0.0:
            return False
        with self._lock:
            self.chances[kind] += 1
            hit = self._rng[kind].random() < p
            if hit:
                self.fired[kind] += 1
            return hit

    def randint(self, kind: str, low: int, high: int) -> int:
        """A number in ``low..high`` from ``kind``'s generator (to shape a fault)."""
        with self._lock:
            return self._rng[kind].randint(low, high)

    def flip_bit(self, kind: str, data: bytes) -> bytes:
        """``data`` with one bit of one byte flipped (line terminators left alone)."""
        body = data.rstrip(b"\r\n")
        if not body:
            return data
        with self._lock:
            rng = self._rng[kind]
            index = rng.randrange(len(body))
            bit = 1 << rng.randrange(8)
        corrupted = bytearray(data)
        corrupted[index] ^= bit
        return bytes(corrupted)
