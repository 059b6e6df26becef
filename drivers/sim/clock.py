"""Simulated time for the printer: wall time divided by time_scale, or virtual when instant."""

from __future__ import annotations

import threading
import time


class SimClock:
    """The printer's own clock, in simulated seconds.

    With ``time_scale > 0`` simulated time runs at ``1 / time_scale`` times wall time.
    With ``time_scale == 0`` it only moves when the printer waits: a wait of ``d``
    simulated seconds returns at once and advances the clock by ``d``, so heater and
    planner arithmetic stays the same at any speed.
    """

    def __init__(self, time_scale: float) -> None:
        self._scale = time_scale
        self._origin = time.monotonic()
        self._virtual = 0.0
        self._lock = threading.Lock()

    @property
    def time_scale(self) -> float:
        """Wall seconds per simulated second."""
        return self._scale

    def now(self) -> float:
        """Simulated seconds since the clock was made."""
        with self._lock:
            if self._scale > 0.0:
                return self._virtual + (time.monotonic() - self._origin) / self._scale
            return self._virtual

    def wait(self, seconds: float, interrupt: threading.Event) -> bool:
        """Let ``seconds`` of simulated time pass; False if ``interrupt`` was set meanwhile."""
        if seconds <= 0.0:
            return not interrupt.is_set()
        if self._scale > 0.0:
            return not interrupt.wait(seconds * self._scale)
        with self._lock:
            self._virtual += seconds
        return not interrupt.is_set()
