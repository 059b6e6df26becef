"""Motion model of the simulated printer: positions, modes, move durations and the planner."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

AXES = ("X", "Y", "Z", "E")


@dataclass(frozen=True)
class MotionLimits:
    """Speeds in mm/s: Marlin's default feedrate, per-axis maxima (X, Y, Z, E), homing."""

    default_feedrate: float = 25.0
    max_feedrate: tuple[float, float, float, float] = (300.0, 300.0, 5.0, 25.0)
    homing_xy: float = 50.0
    homing_z: float = 4.0
    homing_overhead_s: float = 3.0


class Motion:
    """Tool position and the G90/G91/M82/M83 modes; computes each move's duration.

    Acceleration is not modelled: a move lasts its length divided by its feedrate
    (F in mm/min, modal), slowed so that no axis exceeds its maximum speed, and scaled
    by the M220 feedrate percentage.
    """

    def __init__(self, limits: MotionLimits | None = None) -> None:
        self.limits = limits or MotionLimits()
        self.reset()

    def reset(self) -> None:
        """Power-on state: origin, absolute modes, default feedrate, 100 %."""
        self.position = dict.fromkeys(AXES, 0.0)
        self.absolute_xyz = True
        self.absolute_e = True
        self.feedrate = self.limits.default_feedrate
        self.feed_percent = 100.0

    def set_absolute(self, absolute: bool) -> None:
        """G90 / G91: the mode of every axis, E included (as Marlin does)."""
        self.absolute_xyz = absolute
        self.absolute_e = absolute

    def set_position(self, params: dict[str, float]) -> None:
        """G92: redefine the current position of the named axes."""
        for axis in AXES:
            if axis in params:
                self.position[axis] = params[axis]

    def move(self, params: dict[str, float]) -> tuple[float, float]:
        """G0/G1 to ``params``; returns (length in mm, duration in simulated s)."""
        if params.get("F", 0.0) > 0.0:
            self.feedrate = params["F"] / 60.0
        delta: dict[str, float] = {}
        for axis in AXES:
            if axis not in params:
                continue
            absolute = self.absolute_e if axis == "E" else self.absolute_xyz
            target = params[axis] if absolute else self.position[axis] + params[axis]
            delta[axis] = target - self.position[axis]
            self.position[axis] = target
        xyz = math.sqrt(sum(delta.get(a, 0.0) ** 2 for a in "XYZ"))
        length = xyz if xyz > 0.0 else abs(delta.get("E", 0.0))
        if length <= 0.0:
            return 0.0, 0.0
        speed = self.feedrate * self.feed_percent / 100.0
        for axis, d in delta.items():
            axis_speed = speed * abs(d) / length
            limit = self.limits.max_feedrate[AXES.index(axis)]
            if axis_speed > limit:
                speed *= limit / axis_speed
        return length, length / speed

    def home(self, axes: str) -> float:
        """G28 on ``axes`` ("" = all); returns the duration in simulated s."""
        names = [a for a in "XYZ" if a in axes] or ["X", "Y", "Z"]
        xy = max((abs(self.position[a]) for a in names if a in "XY"), default=0.0)
        z = abs(self.position["Z"]) if "Z" in names else 0.0
        for axis in names:
            self.position[axis] = 0.0
        return (
            self.limits.homing_overhead_s
            + xy / self.limits.homing_xy
            + z / self.limits.homing_z
        )


class Planner:
    """Marlin's block buffer as a queue of block end times in simulated seconds."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self._ends: deque[float] = deque()

    def _prune(self, now: float) -> None:
        while self._ends and self._ends[0] <= now:
            self._ends.popleft()

    def free(self, now: float) -> int:
        """Free blocks at ``now``."""
        self._prune(now)
        return max(0, self.capacity - len(self._ends))

    def next_free_at(self, now: float) -> float:
        """Simulated time when a block will be free (``now`` if one is)."""
        self._prune(now)
        if len(self._ends) < self.capacity:
            return now
        return self._ends[len(self._ends) - self.capacity]

    def idle_at(self, now: float) -> float:
        """Simulated time when every planned block will have been executed."""
        self._prune(now)
        return self._ends[-1] if self._ends else now

    def add(self, now: float, duration: float) -> None:
        """Append a block of ``duration`` s that starts when the previous one ends."""
        start = max(now, self._ends[-1]) if self._ends else now
        self._ends.append(start + duration)

    def clear(self) -> None:
        """Drop every block (quick stop, reset)."""
        self._ends.clear()
