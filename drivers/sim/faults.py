"""Seeded fault injection for the simulated printer: one generator and counter per kind."""

from __future__ import annotations

import math
import random
import threading
from collections import Counter

from drivers.sim.config import FAULT_KINDS, SimulatorConfig

NEVER = 1 << 62  # a countdown that never runs out


class FaultInjector:
    """Decides, reproducibly for a seed, whether each fault fires, and counts both.

    Each kind has its own generator (seeded from ``seed`` and the kind's name), so enabling
    one kind never shifts the draws of another.
    """

    def __init__(self, config: SimulatorConfig, threaded: bool = True) -> None:
        """``threaded=False``: one thread only draws (the virtual-clock printer), no lock."""
        self._p = {kind: float(getattr(config, f"p_{kind}")) for kind in FAULT_KINDS}
        self._rng = {kind: random.Random(f"{config.seed}:{kind}") for kind in FAULT_KINDS}
        self._lock = threading.Lock()
        self.fired: Counter[str] = Counter()
        self.chances: Counter[str] = Counter()
        if not threaded:
            # one thread draws (the virtual-clock printer): no lock, and each kind draws
            # the number of chances until it next fires (geometric, the same odds as one
            # draw per chance), so a chance costs a countdown; ``chances`` stays empty
            self.fires = self._fires_counted  # type: ignore[method-assign]
            self.left = {kind: self._gap(kind) for kind in FAULT_KINDS}

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

    def _gap(self, kind: str) -> int:
        """Chances that pass before ``kind`` fires next (``NEVER``: it does not)."""
        p = self._p[kind]
        if p <= 0.0:
            return NEVER
        if p >= 1.0:
            return 0
        return int(math.log(1.0 - self._rng[kind].random()) / math.log1p(-p))

    def _fires_counted(self, kind: str) -> bool:
        left = self.left[kind]
        if left:
            self.left[kind] = left - 1
            return False
        return self.fire(kind)

    def fire(self, kind: str) -> bool:
        """``kind`` fires now (its countdown in ``left`` reached 0): counted, and the next
        countdown drawn. A single-threaded caller may count ``left`` down itself (one
        chance: ``left[kind] -= 1`` while it is not 0) and call this at 0. Returns True."""
        self.fired[kind] += 1
        self.left[kind] = self._gap(kind)
        return True

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
