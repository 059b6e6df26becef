"""Object labels other hosts cancel by: Marlin's M486 and Klipper's EXCLUDE_OBJECT, per body."""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING

import numpy as np
import shapely

if TYPE_CHECKING:
    from slicer.plan import SlicePlan

# one move as this slicer writes it: G0..G3, then F, X, Y, Z, I/J, E in that order
_MOVE = re.compile(
    r"G([0-3])(?: F\S+)?(?: X(-?[\d.]+))?(?: Y(-?[\d.]+))?(?: Z\S+)?(?: [IJ]\S+)*(?: E(-?[\d.]+))?"
)
_SAMPLED_LAYERS = 24  # layers whose outlines make a body's footprint


class ObjectLabels:
    """Names, footprints and per-layer brackets of a plan's bodies (``body_<n>``, from 0)."""

    def __init__(self, plan: SlicePlan) -> None:
        self.plan = plan
        self.count = plan.body_count
        self.names = [f"body_{b}" for b in range(self.count)]

    def define_lines(self) -> list[str]:
        """``M486 T<count>`` and one ``EXCLUDE_OBJECT_DEFINE`` per body (centre, outline)."""
        plan = self.plan
        n = plan.layer_count
        parts: list[list[shapely.Geometry]] = [[] for _ in range(self.count)]
        for i in np.unique(np.linspace(0, n - 1, min(n, _SAMPLED_LAYERS)).astype(int)).tolist():
            polys, bodies = plan.layer_bodies(i)
            for poly, body in zip(polys.tolist(), bodies.tolist(), strict=True):
                parts[body].append(poly)
        lines = [f"M486 T{self.count}"]
        for body, outlines in enumerate(parts):
            hull = shapely.convex_hull(shapely.union_all(outlines)) if outlines else None
            if hull is None or hull.is_empty or hull.geom_type != "Polygon":
                continue
            hull = shapely.simplify(hull, 0.2)
            centre = hull.centroid
            ring = shapely.get_coordinates(hull.exterior)[:-1]
            polygon = ",".join(f"[{x:.3f},{y:.3f}]" for x, y in ring.tolist())
            lines.append(f"EXCLUDE_OBJECT_DEFINE NAME={self.names[body]} "
                         f"CENTER={centre.x:.3f},{centre.y:.3f} POLYGON=[{polygon}]")
        return lines

    def label_layer(self, i: int, lines: list[str]) -> list[str]:
        """Layer ``i``'s lines with each body's extruding moves between its start and end.

        Every extruding move is given to the body whose outline is nearest its
        midpoint; a run of moves of one body is opened by ``M486 S<b>`` and
        ``EXCLUDE_OBJECT_START NAME=...`` and closed after its last extrusion by
        ``EXCLUDE_OBJECT_END`` and ``M486 S-1``. Travels and retractions
        between bodies stay outside the brackets.
        """
        polys, bodies = self.plan.layer_bodies(i)
        if not len(polys):
            return lines
        ext, points = extruding_moves(lines)
        if not len(ext):
            return lines
        tree = shapely.STRtree(polys)
        nearest = tree.query_nearest(shapely.points(points), all_matches=False)
        owner = np.empty(len(ext), dtype=np.int64)
        owner[nearest[0]] = bodies[nearest[1]]
        change = np.flatnonzero(np.diff(owner)) + 1
        starts = np.concatenate([[0], change])
        ends = np.concatenate([change, [len(ext)]]) - 1
        out: list[str] = []
        position = 0
        for start, end in zip(starts.tolist(), ends.tolist(), strict=True):
            first, last, body = int(ext[start]), int(ext[end]), int(owner[start])
            out += lines[position:first]
            out += [f"M486 S{body}", f"EXCLUDE_OBJECT_START NAME={self.names[body]}"]
            out += lines[first:last + 1]
            out += [f"EXCLUDE_OBJECT_END NAME={self.names[body]}", "M486 S-1"]
            position = last + 1
        out += lines[position:]
        return out


def extruding_moves(lines: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the moves that extrude while moving in X/Y, (k,) int64, and each one's
    midpoint (start and end averaged), (k, 2) float64 mm. Absolute X Y, relative E."""
    matches = [_MOVE.match(line) for line in lines]
    count = len(lines)
    x = np.full(count, np.nan)
    y = np.full(count, np.nan)
    e = np.zeros(count)
    for k, match in enumerate(matches):
        if match is None:
            continue
        gx, gy, ge = match.group(2, 3, 4)
        if gx is not None:
            x[k] = float(gx)
        if gy is not None:
            y[k] = float(gy)
        if ge is not None:
            e[k] = float(ge)
    fx, fy = _fill_forward(x), _fill_forward(y)
    px, py = np.roll(fx, 1), np.roll(fy, 1)
    if count:
        px[0], py[0] = np.nan, np.nan
    moved = (~np.isnan(x) | ~np.isnan(y)) & ((fx != px) | (fy != py))
    ext = np.flatnonzero((e > 0) & moved & ~np.isnan(fx) & ~np.isnan(fy))
    sx = np.where(np.isnan(px[ext]), fx[ext], px[ext])
    sy = np.where(np.isnan(py[ext]), fy[ext], py[ext])
    points = np.column_stack([(sx + fx[ext]) / 2, (sy + fy[ext]) / 2])
    return ext, points


def _fill_forward(values: np.ndarray) -> np.ndarray:
    """Each NaN replaced by the last number before it (NaN while there is none)."""
    index = np.where(np.isnan(values), 0, np.arange(len(values)))
    np.maximum.accumulate(index, out=index)
    filled = values[index]
    if len(values) and np.isnan(values[0]):
        first = np.flatnonzero(~np.isnan(values))
        filled[: first[0] if len(first) else len(values)] = np.nan
    return filled


def progress_line(before_s: float, total_s: float) -> str:
    """``M73 P<percent> R<minutes left>`` for a point ``before_s`` into ``total_s`` seconds."""
    if total_s <= 0:
        return "M73 P0 R0"
    percent = min(100, int(100 * before_s / total_s))
    return f"M73 P{percent} R{math.ceil(max(0.0, total_s - before_s) / 60)}"
