"""Print-time model: a trapezoidal speed profile per move, vectorised over moves.

Each run of moves (one toolpath, or one travel) starts and ends at rest.
Inside a run, the speed through a corner follows Marlin's junction-deviation
rule, so long polylines that approximate curves are not charged a stop per
vertex, while sharp corners are; like Marlin's planner, entry and exit speeds
are limited to what the acceleration can reach over the neighbouring moves.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

# Marlin's default junction deviation, mm
JUNCTION_DEVIATION = 0.013


def runs_time(runs: list[np.ndarray], speeds: np.ndarray, accel: float) -> float:
    """Total seconds of many runs at once: ``runs`` polylines (k_i, 2) mm, ``speeds`` (r,) mm/s.

    The same as summing :func:`run_time` over the runs, in a handful of numpy calls.
    """
    if not runs:
        return 0.0
    sizes = np.array([len(r) for r in runs])
    return packed_runs_time(np.concatenate(runs), np.cumsum(sizes) - sizes, speeds, accel)


def packed_runs_time(
    pts: np.ndarray, starts: np.ndarray, speeds: np.ndarray, accel: float
) -> float:
    """:func:`runs_time` of runs packed in one array: ``pts`` (m, 2) mm, run ``k`` begins
    at ``starts[k]`` (ascending) and ends where the next begins; ``speeds`` (r,) mm/s."""
    if len(pts) == 0:
        return 0.0
    mark = np.zeros(len(pts), dtype=np.int64)
    mark[starts[1:]] = 1
    run_of_pt = np.cumsum(mark)
    seg = np.diff(pts, axis=0)
    same = run_of_pt[1:] == run_of_pt[:-1]
    length = np.hypot(seg[:, 0], seg[:, 1])
    keep = same & (length > 1e-9)
    seg, length = seg[keep], length[keep]
    if len(length) == 0:
        return 0.0
    run = run_of_pt[1:][keep]
    speed = np.asarray(speeds, dtype=np.float64)[run]
    unit = seg / length[:, None]
    n = len(length)
    # speed limit at each junction j (before segment j; j = n is the end): the
    # junction-deviation corner speed inside a run, zero where runs begin and end
    limit = np.zeros(n + 1)
    joined = run[1:] == run[:-1]
    cos_theta = -np.einsum("ij,ij->i", unit[:-1], unit[1:])
    sin_half = np.sqrt(np.clip(0.5 * (1.0 - cos_theta), 0.0, 1.0))
    v2 = accel * JUNCTION_DEVIATION * sin_half / np.maximum(1.0 - sin_half, 1e-12)
    v2 = np.minimum(v2, np.minimum(speed[1:], speed[:-1]) ** 2)
    limit[1:-1] = np.where(joined, v2, 0.0)
    return planned_time(length, speed, limit, accel)


def planned_time(
    length: NDArray[np.float64], speed: NDArray[np.float64], limit: NDArray[np.float64],
    accel: float,
) -> float:
    """Seconds of a chain of segments (``length``, ``speed`` (n,) mm, mm/s) whose squared
    speed at each junction (``limit`` (n + 1,) mm²/s², the chain's ends included) is at
    most ``limit``: the planner's forward and backward passes as prefix minima,
    ``v_j^2 = min_k (limit_k + 2 a |S_j - S_k|)``, then a trapezoid per segment."""
    two_a = 2.0 * accel
    s_fwd = np.concatenate(([0.0], np.cumsum(length)))
    fwd = two_a * s_fwd + np.minimum.accumulate(limit - two_a * s_fwd)
    s_bwd = s_fwd[-1] - s_fwd
    bwd = two_a * s_bwd + np.minimum.accumulate((limit - two_a * s_bwd)[::-1])[::-1]
    v = np.sqrt(np.maximum(np.minimum(fwd, bwd), 0.0))
    return float(segment_times(length, speed, v[:-1], v[1:], accel).sum())


def run_time(points: np.ndarray, speed: float, accel: float) -> float:
    """Seconds to follow the polyline ``points`` (k, 2) mm at ``speed`` mm/s from rest to rest.

    ``accel`` mm/s^2. Corner speeds follow the junction-deviation rule; entry
    and exit speeds are made reachable by forward and backward planner passes
    (as prefix minima, vectorised); each segment then takes the time of its
    trapezoid or triangle.
    """
    return packed_runs_time(points, np.zeros(1, dtype=np.int64), np.array([speed]), accel)


def rest_time(length: float, speed: float, accel: float) -> float:
    """Seconds of one move of ``length`` mm from rest to rest at ``speed`` mm/s, ``accel``
    mm/s^2: :func:`segment_times` of that move with zero entry and exit speeds, the same
    float to the bit (its operations in its order, less the exact ones on zero speeds, on
    plain floats, without numpy's cost per call on one element)."""
    v = float(speed)
    d_acc = v * v / (2.0 * accel)
    cruise = length - d_acc - d_acc
    if cruise >= 0:
        return v / accel + v / accel + cruise / v
    # a triangle (segment_times' "mean" case needs a peak below a zero entry speed: never)
    peak = math.sqrt(max(2.0 * accel * length / 2.0, 0.0))
    return peak / accel + peak / accel


def segment_times(
    length: NDArray[np.float64],
    speed: float | NDArray[np.float64],
    v_in: NDArray[np.float64],
    v_out: NDArray[np.float64],
    accel: float,
) -> NDArray[np.float64]:
    """Time of each move (n,) s: accelerate from ``v_in``, cruise at ``speed``, brake to ``v_out``.

    ``length`` (n,) mm; speeds mm/s; ``accel`` mm/s^2. When the move is too
    short to reach ``speed`` the profile is a triangle; when it is too short
    even for that, the mean of entry and exit speed is used.
    """
    v = speed
    if not (isinstance(v, np.ndarray) and v.dtype == np.float64 and v.shape == length.shape):
        v = np.broadcast_to(np.asarray(speed, dtype=np.float64), length.shape)
    d_acc = np.maximum(v * v - v_in * v_in, 0.0) / (2.0 * accel)
    d_dec = np.maximum(v * v - v_out * v_out, 0.0) / (2.0 * accel)
    cruise = length - d_acc - d_dec
    trapezoid = (v - v_in) / accel + (v - v_out) / accel + np.maximum(cruise, 0.0) / v
    peak = np.sqrt(np.maximum((2.0 * accel * length + v_in * v_in + v_out * v_out) / 2.0, 0.0))
    triangle = (peak - v_in) / accel + (peak - v_out) / accel
    mean = 2.0 * length / np.maximum(v_in + v_out, 1e-9)
    short = peak < np.maximum(v_in, v_out)
    return np.where(cruise >= 0, trapezoid, np.where(short, mean, triangle))
