"""A layer's print time as Marlin's planner takes its emitted moves: one chain of blocks.

The moves are the ones written to the G-code (simplified, arcs cut into the
chords Marlin's ``plan_arc`` cuts them into), travels included, in order. A
block's entry speed follows Marlin's junction deviation, with its cap for
gentle turns between short blocks; a retraction or a prime (a move of the
extruder alone) stops the head. Forward and backward passes over the whole
chain (prefix minima, vectorised) make every speed change reachable with the
acceleration; each block then takes the time of its trapezoid. Moves of the
extruder alone and the lift to the layer's height are timed at Marlin's default
axis limits. The travel into the layer is counted as from the layer's own last
point (where the layer below, alike, is likely to have ended), so a layer's
time depends on that layer alone.
"""

from __future__ import annotations

import numpy as np

from slicer.output.budget import Moves
from slicer.output.motion import JUNCTION_DEVIATION, planned_time, rest_time

# Marlin's default limits (Configuration.h) for the axes a slicer does not set: mm/s, mm/s^2
MAX_Z_SPEED = 5.0
MAX_Z_ACCEL = 100.0
MAX_E_SPEED = 25.0
# Marlin's plan_arc: MIN_ARC_SEGMENT_MM, MAX_ARC_SEGMENT_MM, MIN_CIRCLE_SEGMENTS
ARC_MIN_SEGMENT = 0.1
ARC_MAX_SEGMENT = 1.0
ARC_MIN_CIRCLE = 72
# Marlin's slowest planned speed (mm/s): the speed of a stop
MIN_SPEED = 0.05


def layer_time(
    mv: Moves, speeds: np.ndarray, travel_speed: float, leaves: np.ndarray,
    retract_length: float, retract_speed: float, layer_height: float, accel: float,
) -> float:
    """Seconds to print one layer's moves ``mv``, path ``i`` at ``speeds[i]`` mm/s, travels
    at ``travel_speed`` mm/s; ``leaves`` (n-1,) bool: the travel before path ``i + 1`` is
    retracted and primed (``retract_length`` mm at ``retract_speed`` mm/s each way), as is
    the lift of ``layer_height`` mm to the layer; ``accel`` mm/s^2 for every block.
    """
    pts, starts, ends = mv.pts, mv.starts, mv.ends
    if len(pts) == 0:
        return 0.0
    speed_into = np.repeat(np.asarray(speeds, dtype=np.float64), ends - starts)
    speed_into[starts] = travel_speed  # the move into a path's first point is the travel
    stop = np.zeros(len(pts), dtype=bool)
    stop[[0, -1]] = True
    retracts = 0
    if retract_length > 0:
        hop = np.asarray(leaves, dtype=bool)
        stop[ends[:-1] - 1] |= hop  # retract before the travel
        stop[starts[1:]] |= hop  # prime after it
        retracts = 1 + int(hop.sum())
    chain, chain_speed, chain_stop = _chords(mv, speed_into, stop)
    time_s = chain_time(chain, chain_speed, chain_stop, accel)
    # the travel into the layer, from its last point, and the lift to its height
    into = float(np.hypot(*(pts[0] - pts[-1])))
    time_s += rest_time(into, travel_speed, accel)
    time_s += lift_time(layer_height, travel_speed, accel)
    if retracts:
        e = rest_time(retract_length, min(retract_speed, MAX_E_SPEED), accel)
        time_s += 2 * retracts * e
    return time_s


def lift_time(height: float, travel_speed: float, accel: float) -> float:
    """Seconds of a lift by ``height`` mm at ``travel_speed`` mm/s, from rest to rest, held to
    Marlin's default Z limits; ``accel`` mm/s^2 (the settings')."""
    if height <= 0:
        return 0.0
    return rest_time(height, min(travel_speed, MAX_Z_SPEED), min(accel, MAX_Z_ACCEL))


def _chords(
    mv: Moves, speed_into: np.ndarray, stop: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The chain with every arc cut into Marlin's chords: points (k, 2) mm, the speed of
    the move into each point (k,) mm/s, and stops (k,) bool."""
    arc = np.asarray(mv.arc, dtype=bool).copy()
    arc[0] = False
    if not arc.any():
        return mv.pts, speed_into, stop
    at = np.flatnonzero(arc)
    start, end, centre = mv.pts[at - 1], mv.pts[at], mv.centre[at]
    r0 = start - centre
    r1 = end - centre
    radius = np.hypot(r0[:, 0], r0[:, 1])
    cross = r0[:, 0] * r1[:, 1] - r0[:, 1] * r1[:, 0]
    dot = (r0 * r1).sum(axis=1)
    angular = np.arctan2(cross, dot)
    angular = np.where(angular < 0.0, angular + 2.0 * np.pi, angular)
    ccw = np.asarray(mv.ccw, dtype=bool)[at]
    angular = np.where(ccw, angular, angular - 2.0 * np.pi)
    full = (np.abs(angular) < 1e-9) | np.all(np.isclose(start, end, rtol=0.0, atol=1e-9), axis=1)
    angular = np.where(full, np.where(ccw, 2.0 * np.pi, -2.0 * np.pi), angular)
    travel = np.abs(angular) * radius
    count = np.maximum.reduce([
        np.ones(len(at), dtype=np.int64),
        (travel / ARC_MAX_SEGMENT).astype(np.int64),
        np.ceil(ARC_MIN_CIRCLE * np.abs(angular) / (2.0 * np.pi)).astype(np.int64),
    ])
    short = travel / count < ARC_MIN_SEGMENT
    count = np.where(short, np.maximum(1, (travel / ARC_MIN_SEGMENT).astype(np.int64)), count)
    count = np.where((radius < 1e-9) | (travel < 1e-9), 1, count)
    repeat = np.ones(len(mv.pts), dtype=np.int64)
    repeat[at] = count
    pts = np.repeat(mv.pts, repeat, axis=0)
    speed = np.repeat(speed_into, repeat)
    # stops stay on the arc's end point, the last of its chords
    last = np.cumsum(repeat) - 1
    chain_stop = np.zeros(len(pts), dtype=bool)
    chain_stop[last] = stop
    # the chords' points: k = 1 .. count-1 on the circle, the last one the arc's end
    first = last[at] - count + 1
    offsets = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    which = np.repeat(np.arange(len(at)), count)
    rows = np.repeat(first, count) + offsets
    step = (angular / count)[which] * (offsets + 1)
    angle0 = np.arctan2(r0[:, 1], r0[:, 0])[which]
    on_circle = offsets + 1 < count[which]
    ring = centre[which] + radius[which][:, None] * np.stack(
        [np.cos(angle0 + step), np.sin(angle0 + step)], axis=1)
    pts[rows[on_circle]] = ring[on_circle]
    return pts, speed, chain_stop


def chain_time(
    pts: np.ndarray, speed_into: np.ndarray, stop: np.ndarray, accel: float
) -> float:
    """Seconds to follow the polyline ``pts`` (k, 2) mm, the move into point ``j`` at
    ``speed_into[j]`` mm/s (``[0]`` unused), stopping at the points where ``stop`` (k,)
    bool, with ``accel`` mm/s^2. Corners follow Marlin's junction deviation; a gentle turn
    into a move shorter than 1 mm is held to the speed of the arc through it, as Marlin
    does.
    """
    if len(pts) < 2:
        return 0.0
    seg = np.diff(pts, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    keep = length > 1e-9
    # a stop at any point between two kept moves (zero moves dropped) stops the junction
    seen = np.cumsum(stop)
    idx = np.flatnonzero(keep)
    if len(idx) == 0:
        return 0.0
    seg, length = seg[keep], length[keep]
    speed = np.asarray(speed_into, dtype=np.float64)[1:][keep]
    unit = seg / length[:, None]
    m = len(length)
    # junction j sits between kept move j-1 (ending at point idx[j-1]+1) and move j
    # (starting at point idx[j]); any stop among those points stops there
    after = idx[:-1] + 1
    before = idx[1:]
    stopped = seen[before] - np.concatenate(([0], seen))[after] > 0
    cos_theta = -np.einsum("ij,ij->i", unit[:-1], unit[1:])
    sin_half = np.sqrt(np.clip(0.5 * (1.0 - cos_theta), 0.0, 1.0))
    v2 = accel * JUNCTION_DEVIATION * sin_half / np.maximum(1.0 - sin_half, 1e-12)
    gentle = (length[1:] < 1.0) & (cos_theta < -0.7071067812)
    theta = np.arccos(np.clip(-cos_theta, -1.0, 1.0))
    arc_v2 = length[1:] * accel / np.maximum(theta, 1e-12)
    v2 = np.where(gentle & (theta > 0.0), np.minimum(v2, arc_v2), v2)
    v2 = np.where(cos_theta > 0.999999, MIN_SPEED**2, v2)
    v2 = np.minimum(v2, np.minimum(speed[1:], speed[:-1]) ** 2)
    limit = np.full(m + 1, MIN_SPEED**2)
    limit[1:-1] = np.where(stopped, MIN_SPEED**2, v2)
    return planned_time(length, speed, limit, accel)
