"""Motion model of the simulated printer: positions, modes, moves and arcs as planner blocks."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from drivers.sim.planner import Move, PlannerSettings, arc_segments

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

    A move's *nominal* duration is its length divided by its feedrate (F in mm/min,
    modal), slowed so that no axis exceeds its maximum speed, and scaled by the M220
    feedrate percentage; acceleration and corners are the planner's
    (``drivers.sim.planner``), which gets each move's vector and speed.
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
        delta = self._advance(params)
        return self._timed(delta)

    def move_delta(self, params: dict[str, float]) -> tuple[Move, float, float]:
        """G0/G1 to ``params``; returns the move (X, Y, Z, E mm), its speed (mm/s, the
        feedrate scaled by M220) and its nominal duration (length / speed, s)."""
        delta = self._advance(params)
        length, duration = self._timed(delta)
        speed = length / duration if duration > 0.0 else 0.0
        x, y, z, e = (delta.get(a, 0.0) for a in AXES)
        return (x, y, z, e), speed, duration

    def arc(
        self, params: dict[str, float], clockwise: bool, settings: PlannerSettings
    ) -> tuple[list[tuple[Move, float]], float, float]:
        """G2/G3 to ``params`` around start + (I, J) in the XY plane, cut into chords as
        Marlin's ``plan_arc`` does; Z and E are shared out by chord length.

        Returns each chord as (move X, Y, Z, E mm; speed mm/s), the arc's length (mm)
        and its nominal duration (s). Raises ValueError without I and J (R arcs are
        not supported) or with a zero radius.
        """
        if "I" not in params and "J" not in params:
            raise ValueError("arc without I and J (R arcs are not supported)")
        start = (self.position["X"], self.position["Y"], self.position["Z"],
                 self.position["E"])
        centre = (start[0] + params.get("I", 0.0), start[1] + params.get("J", 0.0))
        if math.hypot(centre[0] - start[0], centre[1] - start[1]) < 1e-6:
            raise ValueError("arc with zero radius")
        delta = self._advance({k: v for k, v in params.items() if k in AXES or k == "F"})
        end = (start[0] + delta.get("X", 0.0), start[1] + delta.get("Y", 0.0))
        points = arc_segments(start[:2], end, centre, clockwise, settings)
        xy = [start[:2], *points]
        lengths = [math.dist(a, b) for a, b in itertools.pairwise(xy)]
        arc_length = sum(lengths)
        dz, de = delta.get("Z", 0.0), delta.get("E", 0.0)
        speed = self.feedrate * self.feed_percent / 100.0
        chords = []
        for (a, b), length in zip(itertools.pairwise(xy), lengths, strict=True):
            share = length / arc_length if arc_length > 0.0 else 1.0
            chords.append(((b[0] - a[0], b[1] - a[1], dz * share, de * share), speed))
        total = math.hypot(arc_length, dz) if arc_length > 0.0 else abs(de)
        return chords, total, (total / speed if speed > 0.0 else 0.0)

    def _advance(self, params: dict[str, float]) -> dict[str, float]:
        """Apply the feedrate and targets of ``params``; the change of each axis named."""
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
        return delta

    def _timed(self, delta: dict[str, float]) -> tuple[float, float]:
        """Length (mm) and nominal duration (s) of a move: length / feedrate, axis limits."""
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
