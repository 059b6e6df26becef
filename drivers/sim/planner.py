"""Marlin's motion planner on a simulated clock: block buffer, trapezoids, arcs, underruns.

A move becomes one block (an arc many: :func:`arc_segments`); the buffer holds
``blocks`` of them, the first of which is being executed. A block's speed
profile is fixed when it starts, as Marlin's stepper fixes the busy block:
it enters at the speed the previous block left at and leaves at the highest
speed the blocks queued behind it allow, found by Marlin's reverse pass
(every queued block must still be able to stop at the end of the last one)
and its forward limit (what the acceleration reaches over the block). Corner
speeds follow junction deviation with Marlin's arc-curvature cap. So a
starved buffer slows the machine down long before it runs empty.

The planner runs empty while a job still sends moves: an *underrun*, counted
with its starved time (until motion resumes) unless a long command (dwell,
homing, heating: anything that waits for the planner) emptied it on purpose.
Before that, a block that starts with nothing queued behind it must brake to
a stop at its end although more moves follow: a *stall* (counted once the
next move arrives; every underrun is also a stall).
Time only moves forward through the ``now`` arguments: the same planner serves
a real-time simulator and a virtual clock.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

# one move: X, Y, Z and E displacements, mm
Move = tuple[float, float, float, float]


@dataclass(frozen=True)
class PlannerSettings:
    """Marlin's defaults (``Configuration.h``, ``Configuration_adv.h``): mm, mm/s, mm/s^2, s.

    ``blocks`` is ``BLOCK_BUFFER_SIZE``; accelerations are ``M204 P/T/R``,
    ``max_acceleration`` and ``max_feedrate`` are per axis X, Y, Z, E;
    ``junction_deviation`` is ``JUNCTION_DEVIATION_MM``; the arc settings are
    ``MIN_ARC_SEGMENT_MM``, ``MAX_ARC_SEGMENT_MM`` and ``MIN_CIRCLE_SEGMENTS``;
    ``first_move_delay_s`` is ``BLOCK_DELAY_FOR_1ST_MOVE``: a block entering an
    empty buffer waits that long, or until three blocks are queued, so the
    first moves can be planned together.
    """

    blocks: int = 16
    acceleration: float = 3000.0
    travel_acceleration: float = 3000.0
    retract_acceleration: float = 3000.0
    max_acceleration: tuple[float, float, float, float] = (3000.0, 3000.0, 100.0, 10000.0)
    max_feedrate: tuple[float, float, float, float] = (300.0, 300.0, 5.0, 25.0)
    junction_deviation: float = 0.013
    min_planner_speed: float = 0.05
    min_arc_segment: float = 0.1
    max_arc_segment: float = 1.0
    min_circle_segments: int = 72
    first_move_delay_s: float = 0.1


@dataclass
class Block:
    """One planned straight move: length mm, nominal speed mm/s, acceleration mm/s^2,
    highest entry speed squared (mm/s)^2. ``serial`` and ``key`` are the planner's."""

    length: float
    speed: float
    accel: float
    max_entry_sq: float
    serial: int = 0
    key: float = 0.0


@dataclass(frozen=True)
class BufferReport:
    """Marlin's buffer monitoring (``M576``): free planner blocks, underruns since the last
    report and the longest of them (ms); totals since power-on."""

    planner_free: int
    underruns: int
    longest_ms: int
    total_underruns: int
    starved_s: float

    def line(self, queue_free: int) -> str:
        """The report as Marlin prints it (command-buffer underruns are not modelled: 0)."""
        return (f"M576 P{self.planner_free} B{queue_free} PU{self.underruns}"
                f" PD{self.longest_ms} BU0 BD0")


def move_block(
    delta: Move, feedrate: float, settings: PlannerSettings,
    previous: tuple[tuple[float, float, float], float] | None,
) -> tuple[Block, tuple[tuple[float, float, float], float]] | None:
    """The block of a move by ``delta`` (X, Y, Z, E mm) at ``feedrate`` mm/s, or None if
    it moves nothing.

    ``previous`` is the unit vector and nominal speed of the block planned before
    (None after the machine stopped); returns the block and the same pair for it.
    """
    xyz = math.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2)
    length = xyz if xyz > 1e-9 else abs(delta[3])
    if length <= 1e-9:
        return None
    speed = feedrate
    accel = (settings.acceleration if delta[3] != 0.0 else settings.travel_acceleration) \
        if xyz > 1e-9 else settings.retract_acceleration
    for i in range(4):
        share = abs(delta[i]) / length
        if share > 0.0:
            speed = min(speed, settings.max_feedrate[i] / share)
            accel = min(accel, settings.max_acceleration[i] / share)
    unit = (delta[0] / xyz, delta[1] / xyz, delta[2] / xyz) if xyz > 1e-09 else (0.0, 0.0, 0.0)
    max_entry_sq = settings.min_planner_speed ** 2
    if previous is not None and xyz > 1e-9 and previous[0] != (0.0, 0.0, 0.0):
        max_entry_sq = _junction_sq(previous[0], unit, accel, length, settings)
        max_entry_sq = min(max_entry_sq, speed * speed, previous[1] ** 2)
    return Block(length, speed, accel, max_entry_sq), (unit, speed)


def _junction_sq(
    prev: tuple[float, float, float], unit: tuple[float, float, float], accel: float,
    length: float, settings: PlannerSettings,
) -> float:
    """Marlin's junction-deviation corner speed squared, with its cap for short arc chords."""
    cos_theta = -(prev[0] * unit[0] + prev[1] * unit[1] + prev[2] * unit[2])
    if cos_theta > 0.999999:  # a reversal
        return settings.min_planner_speed ** 2
    cos_theta = max(cos_theta, -0.999999)
    sin_half = math.sqrt(0.5 * (1.0 - cos_theta))
    v_sq = accel * settings.junction_deviation * sin_half / (1.0 - sin_half)
    if length < 1.0 and cos_theta < -0.7071067812:
        # a gentle turn between short moves: the speed of the arc through them
        theta = math.acos(-cos_theta)
        if theta > 0.0:
            v_sq = min(v_sq, length * accel / theta)
    return v_sq


def arc_segments(
    start: tuple[float, float], end: tuple[float, float], centre: tuple[float, float],
    clockwise: bool, settings: PlannerSettings,
) -> list[tuple[float, float]]:
    """The points (after ``start``) of the chords Marlin's ``plan_arc`` cuts an arc into.

    ``centre`` is the arc's centre (start + I, J), mm. Segments are at most
    ``max_arc_segment`` long and at least ``min_circle_segments`` a full turn;
    an arc whose end equals its start is a full circle. The last point is ``end``.
    """
    rx, ry = start[0] - centre[0], start[1] - centre[1]
    radius = math.hypot(rx, ry)
    tx, ty = end[0] - centre[0], end[1] - centre[1]
    angular = math.atan2(rx * ty - ry * tx, rx * tx + ry * ty)
    if angular < 0.0:
        angular += 2.0 * math.pi
    if clockwise:
        angular -= 2.0 * math.pi
    if abs(angular) < 1e-9 or (math.isclose(start[0], end[0], abs_tol=1e-9)
                               and math.isclose(start[1], end[1], abs_tol=1e-9)):
        angular = -2.0 * math.pi if clockwise else 2.0 * math.pi
    travel = abs(angular) * radius
    if radius < 1e-9 or travel < 1e-9:
        return [end]
    segments = max(1, int(travel / settings.max_arc_segment),
                   math.ceil(settings.min_circle_segments * abs(angular) / (2.0 * math.pi)))
    if travel / segments < settings.min_arc_segment:
        segments = max(1, int(travel / settings.min_arc_segment))
    step = angular / segments
    cos_s, sin_s = math.cos(step), math.sin(step)
    points = []
    x, y = rx, ry
    for _ in range(segments - 1):
        x, y = x * cos_s - y * sin_s, x * sin_s + y * cos_s
        points.append((centre[0] + x, centre[1] + y))
    points.append(end)
    return points


class MarlinPlanner:
    """The block buffer with its timing; every method takes the current simulated time.

    ``free``, ``next_free_at``, ``idle_at``, ``add`` and ``clear`` keep the
    simulator's interface; ``add_block`` plans a :class:`Block`.
    """

    def __init__(self, settings: PlannerSettings | None = None) -> None:
        self.settings = settings or PlannerSettings()
        self.capacity = self.settings.blocks
        self._queue: deque[Block] = deque()  # waiting, not started
        # the reverse pass as a sliding minimum: the next block may be entered at
        # v^2 = min over queued k of (max_entry_k + C_k) - C_next, or stop at the end
        # (min speed^2 + C), where C_k sums 2 a L over every block queued before k
        self._climb = 0.0
        self._serial = 0
        self._mins: deque[tuple[int, float]] = deque()
        self._run_end: float | None = None  # end of the block being executed
        self._run_exit = 0.0  # speed it leaves at
        self._start_at: float | None = None  # first block after idle: when it may start
        self._empty_since: float | None = None
        self._expected_idle = True  # idle since power-on or a synchronize: not an underrun
        self.underruns = 0
        self.stalls = 0
        self._lean = False  # the block under way began with nothing queued behind it
        self.starved_s = 0.0
        self.longest_s = 0.0
        self.blocks_done = 0
        self.motion_s = 0.0
        self._report_underruns = 0
        self._report_longest = 0.0
        self.previous: tuple[tuple[float, float, float], float] | None = None

    # --- the simulator's interface ---------------------------------------------------

    def free(self, now: float) -> int:
        """Free blocks at ``now``."""
        self.advance(now)
        return max(0, self.capacity - self._count())

    def next_free_at(self, now: float) -> float:
        """Simulated time when a block will be free (``now`` if one is)."""
        self.advance(now)
        if self._count() < self.capacity:
            return now
        assert self._run_end is not None  # a full buffer always has a block under way
        return self._run_end

    def idle_at(self, now: float) -> float:
        """When every block planned will have been executed (runs them: nothing comes
        meanwhile); the idle that follows is expected, not an underrun."""
        self.advance(now)
        self._expected_idle = True
        end = now
        while self._run_end is not None or self._queue:
            if self._run_end is None:
                self._start_next(max(now, self._start_at if self._start_at is not None else now))
            end = self._run_end if self._run_end is not None else end
            self.advance(end)
        return max(end, now)

    def add(self, now: float, duration: float) -> None:
        """Append a block that lasts ``duration`` s at its speed, whatever its neighbours."""
        self.add_block(now, Block(duration, 1.0, 1e12, 0.0))

    def clear(self) -> None:
        """Drop every block (quick stop, reset): the machine stops, expectedly."""
        self._queue.clear()
        self._mins.clear()
        self._run_end = None
        self._start_at = None
        self._empty_since = None
        self._expected_idle = True
        self._lean = False
        self.previous = None

    # --- planning ----------------------------------------------------------------------

    def add_block(self, now: float, block: Block) -> float:
        """Queue ``block`` at ``now``, waiting for a free slot first; returns when it was
        queued (simulated s)."""
        now = self.next_free_at(now)
        self.advance(now)
        idle = self._run_end is None and not self._queue
        if self._lean and not self._expected_idle:
            self.stalls += 1
        self._lean = False
        if idle and self._empty_since is not None:
            if self._expected_idle:
                self._empty_since = None
            else:
                self.underruns += 1
                self._report_underruns += 1
        block.serial = self._serial
        self._serial += 1
        block.key = self._climb  # C before this block
        self._climb += 2.0 * block.accel * block.length
        entry_key = block.max_entry_sq + block.key
        while self._mins and self._mins[-1][1] >= entry_key:
            self._mins.pop()
        self._mins.append((block.serial, entry_key))
        self._queue.append(block)
        if idle:
            delay = self.settings.first_move_delay_s if self.capacity > 1 else 0.0
            self._start_at = now + delay
            self._expected_idle = False
        elif self._start_at is not None and len(self._queue) >= min(3, self.capacity):
            self._start_at = now
        self.advance(now)
        return now

    def advance(self, now: float) -> None:
        """Execute every block that starts or ends by ``now``."""
        while True:
            if self._run_end is not None and self._run_end <= now:
                end = self._run_end
                self._run_end = None
                if self._queue:
                    self._start_next(end)
                else:
                    self._empty_since = end
                    self._run_exit = 0.0
                    self.previous = None
            elif self._run_end is None and self._queue and self._start_at is not None \
                    and self._start_at <= now:
                self._start_next(self._start_at)
            else:
                return

    def _count(self) -> int:
        return len(self._queue) + (self._run_end is not None)

    def _start_next(self, t: float) -> None:
        """Fix the profile of the next block and start it at ``t``."""
        block = self._queue.popleft()
        if self._mins and self._mins[0][0] == block.serial:
            self._mins.popleft()
        if self._start_at is not None:  # restarting from rest
            self._start_at = None
            if self._empty_since is not None:
                gap = t - self._empty_since
                self.starved_s += gap
                self.longest_s = max(self.longest_s, gap)
                self._report_longest = max(self._report_longest, gap)
            self._empty_since = None
            v_in = self.settings.min_planner_speed
        else:
            v_in = self._run_exit
        # reverse pass: the fastest the next block may be entered so that every queued
        # block can still stop at the end of the last one
        v_sq = self.settings.min_planner_speed ** 2
        if self._queue:
            low = v_sq + self._climb
            if self._mins:
                low = min(low, self._mins[0][1])
            v_sq = max(low - self._queue[0].key, v_sq)
        self._lean = not self._queue
        v_out = math.sqrt(min(v_sq, v_in * v_in + 2.0 * block.accel * block.length))
        v_in = min(v_in, block.speed)
        v_out = min(v_out, block.speed)
        duration = trapezoid_time(block.length, block.speed, v_in, v_out, block.accel)
        self._run_end = t + duration
        self._run_exit = v_out
        self.blocks_done += 1
        self.motion_s += duration

    def report(self, now: float) -> BufferReport:
        """The buffer monitoring figures, resetting the per-report ones."""
        self.advance(now)
        rep = BufferReport(self.free(now), self._report_underruns,
                           round(self._report_longest * 1000.0), self.underruns, self.starved_s)
        self._report_underruns = 0
        self._report_longest = 0.0
        return rep


def trapezoid_time(length: float, speed: float, v_in: float, v_out: float, accel: float) -> float:
    """Seconds to cover ``length`` mm from ``v_in`` to ``v_out`` mm/s, cruising at most at
    ``speed``, with ``accel`` mm/s^2 (a triangle when the cruise speed is not reached)."""
    d_acc = max(speed * speed - v_in * v_in, 0.0) / (2.0 * accel)
    d_dec = max(speed * speed - v_out * v_out, 0.0) / (2.0 * accel)
    if d_acc + d_dec <= length:
        return (speed - v_in) / accel + (speed - v_out) / accel + (length - d_acc - d_dec) / speed
    peak_sq = (2.0 * accel * length + v_in * v_in + v_out * v_out) / 2.0
    peak = math.sqrt(max(peak_sq, 0.0))
    if peak < max(v_in, v_out):
        return 2.0 * length / max(v_in + v_out, 1e-9)
    return (peak - v_in) / accel + (peak - v_out) / accel
