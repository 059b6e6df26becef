"""The travel into a layer from where the layer before ended, around cancelled bodies.

Each layer is sliced on its own, so its first travel (the line that also moves to
its height) starts wherever the previous layer left the nozzle. Once a body is
cancelled, that travel is re-planned when the layers are joined in order: the
nozzle's position after the previous layer is read from its lines, and the way
to the layer's first point goes round the region (:mod:`slicer.paths.detour`), at the
previous layer's height and retracted, before the layer's own first travel.
"""

from __future__ import annotations

import re

import numpy as np
import shapely

from slicer.output.gcode import format_moves
from slicer.output.motion import run_time
from slicer.paths.detour import detours

# a move with X and Y (every move the slicer writes names both)
_MOVE = re.compile(r"^G[0-3] (?:F\S+ )?X(-?[\d.]+) Y(-?[\d.]+)")
# the layer's first travel: to its first point and its height
_ENTRY = re.compile(r"^G0 F(\d+) X(-?[\d.]+) Y(-?[\d.]+) Z-?[\d.]+$")


def last_xy(lines: list[str]) -> np.ndarray | None:
    """Where the nozzle is (X, Y mm, (2,)) after ``lines``, or None if they move nowhere."""
    for line in reversed(lines):
        found = _MOVE.match(line)
        if found:
            return np.array([float(found[1]), float(found[2])])
    return None


def entered(
    lines: list[str], came_from: np.ndarray | None, region: shapely.Geometry | None,
    accel: float,
) -> tuple[list[str], float]:
    """A layer's ``lines`` whose first travel, from ``came_from`` ((2,) mm: where the
    layer before ended), goes around ``region`` (mm; None: nothing to avoid), and the
    seconds the way round adds at ``accel`` mm/s². Unchanged when the straight line
    keeps clear of the region, or the layer has no first travel."""
    if came_from is None or region is None:
        return lines, 0.0
    at = next((k for k, line in enumerate(lines) if line.startswith("G0 ")), None)
    found = _ENTRY.match(lines[at]) if at is not None else None
    if at is None or found is None:
        return lines, 0.0
    target = np.array([float(found[2]), float(found[3])])
    points = detours(came_from[None, :], target[None, :], region)[0]
    if not len(points):
        return lines, 0.0
    feed = int(found[1])
    speed = feed / 60.0
    way = np.vstack([came_from, points, target])
    extra = run_time(way, speed, accel) - run_time(way[[0, -1]], speed, accel)
    return [*lines[:at], *format_moves(f"G0 F{feed} ", points), *lines[at:]], extra
