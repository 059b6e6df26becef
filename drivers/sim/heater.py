"""Heater model of the simulated printer: first-order approach to the target temperature."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class HeaterSpec:
    """Thermal constants of one heater; temperatures in deg C, times in simulated seconds.

    ``tau_heat_s`` is the time constant while a target is set (the hotend default reaches
    210 C from 20 C, to within 1 C, in about 80 s); ``tau_cool_s`` while it is off.
    """

    name: str
    tau_heat_s: float
    tau_cool_s: float
    max_c: float
    window_c: float = 1.0
    residency_s: float = 10.0


HOTEND = HeaterSpec("T", tau_heat_s=15.0, tau_cool_s=60.0, max_c=275.0)
BED = HeaterSpec("B", tau_heat_s=30.0, tau_cool_s=120.0, max_c=120.0, residency_s=10.0)


class Heater:
    """One heater whose temperature is a closed-form function of simulated time."""

    def __init__(self, spec: HeaterSpec, ambient_c: float) -> None:
        self.spec = spec
        self.ambient_c = ambient_c
        self.target_c = 0.0
        self._t0 = 0.0
        self._temp0 = ambient_c

    def temperature(self, now: float) -> float:
        """Temperature in deg C at simulated time ``now`` (s)."""
        goal = self.target_c if self.target_c > 0.0 else self.ambient_c
        tau = self.spec.tau_heat_s if self.target_c > 0.0 else self.spec.tau_cool_s
        elapsed = max(0.0, now - self._t0)
        return goal + (self._temp0 - goal) * math.exp(-elapsed / tau)

    def set_target(self, target_c: float, now: float) -> None:
        """Set the target (0 = off), clamped to the heater's maximum."""
        self._temp0 = self.temperature(now)
        self._t0 = now
        self.target_c = min(max(0.0, target_c), self.spec.max_c)

    def power(self, now: float) -> int:
        """Heater duty as Marlin reports it in ``@:``: 0..127."""
        if self.target_c <= 0.0:
            return 0
        error = self.target_c - self.temperature(now)
        hold = (self.target_c - self.ambient_c) / (self.spec.max_c - self.ambient_c)
        duty = 0.6 * hold + error / 20.0
        return round(127 * min(1.0, max(0.0, duty)))

    def settled(self, now: float, heating_only: bool) -> bool:
        """True when within the window of the target (or above it with ``heating_only``)."""
        temp = self.temperature(now)
        if heating_only and temp >= self.target_c - self.spec.window_c:
            return True
        return abs(temp - self.target_c) <= self.spec.window_c

    def reset(self, now: float) -> None:
        """Switch off (as a firmware reset does); the metal keeps its temperature."""
        self.set_target(0.0, now)


def format_temperatures(hotend: Heater, bed: Heater, now: float) -> str:
    """Marlin's heater report: `` T:201.20 /210.00 B:60.00 /60.00 @:64 B@:127``."""
    return (
        f" T:{hotend.temperature(now):.2f} /{hotend.target_c:.2f}"
        f" B:{bed.temperature(now):.2f} /{bed.target_c:.2f}"
        f" @:{hotend.power(now)} B@:{bed.power(now)}"
    )
