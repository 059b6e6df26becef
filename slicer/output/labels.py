"""Object labels other hosts cancel by: Marlin's M486 and Klipper's EXCLUDE_OBJECT, per body."""

from __future__ import annotations

import itertools
import math
import re
from typing import TYPE_CHECKING

import numpy as np
import shapely

from slicer.geometry.geom import sorted_unique

if TYPE_CHECKING:
    from slicer.plan import SlicePlan

# one line: a move as this slicer writes it (G0..G3, then F, X, Y, Z, I/J, E in that
# order), X, Y and E captured, or any other line (nothing captured); every line matches
# once, so one ``findall`` over a layer's text gives one (X, Y, E) per line
_LINE = re.compile(
    r"^(?:G[0-3](?: F\S+)?(?: X(-?[\d.]+))?(?: Y(-?[\d.]+))?(?: Z\S+)?(?: [IJ]\S+)*"
    r"(?: E(-?[\d.]+))?)?[^\n]*\n",
    re.M,
)
_SAMPLED_LAYERS = 24  # layers whose outlines make a body's footprint
_PAIRS = 1 << 20  # (point, polygon) box tests held at once when moves are given to bodies


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
        sampled = np.linspace(0, n - 1, min(n, _SAMPLED_LAYERS)).astype(int)
        layers = [plan.layer_bodies(i) for i in sorted_unique(sampled).tolist()]
        polys = np.concatenate([p for p, _ in layers]) if layers else np.empty(0, dtype=object)
        bodies = np.concatenate([b for _, b in layers]) if layers else np.empty(0, dtype=int)
        # the hull of a body's outlines is that of their points: no union needed; all
        # bodies' hulls in one call (a body without outlines on these layers has none)
        order = np.argsort(bodies, kind="stable")
        hulls = np.full(self.count, None, dtype=object)
        if len(order):
            present = sorted_unique(bodies)  # the bodies with outlines: indices without gaps
            grouped = shapely.multipolygons(polys[order],
                                            indices=np.searchsorted(present, bodies[order]))
            hulls[present] = shapely.convex_hull(grouped)
        lines = [f"M486 T{self.count}"]
        for body, hull in enumerate(hulls.tolist()):
            if hull is None or hull.is_empty or hull.geom_type != "Polygon":
                continue
            hull = shapely.simplify(hull, 0.2)
            centre = hull.centroid
            ring = shapely.get_coordinates(hull.exterior)[:-1]
            polygon = ",".join(f"[{x:.3f},{y:.3f}]" for x, y in ring.tolist())
            lines.append(f"EXCLUDE_OBJECT_DEFINE NAME={self.names[body]} "
                         f"CENTER={centre.x:.3f},{centre.y:.3f} POLYGON=[{polygon}]")
        return lines

    def label_layer(
        self, i: int, lines: list[str], spans: np.ndarray | None = None
    ) -> list[str]:
        """Layer ``i``'s lines with each body's extruding moves between its start and end.

        ``spans``: :attr:`slicer.output.gcode.LayerCode.spans` of these lines (each path's
        first and last move line and its body), when known: every path's moves
        then go to its body. Without them the lines are read, and every
        extruding move is given to the body whose outline is nearest its
        midpoint. A run of moves of one body is opened by ``M486 S<b>`` and
        ``EXCLUDE_OBJECT_START NAME=...`` and closed after its last move by
        ``EXCLUDE_OBJECT_END`` and ``M486 S-1``. Travels and retractions
        between bodies stay outside the brackets.
        """
        if spans is None:
            polys, bodies = self.plan.layer_bodies(i)
            if not len(polys):
                return lines
            ext, points = extruding_moves(lines)
            owner = nearest_body(polys, bodies, points, self.plan.outline(i))
            spans = np.column_stack([ext, ext, owner])
        if not len(spans):
            return lines
        owner = spans[:, 2]
        change = np.flatnonzero(np.diff(owner)) + 1
        starts = np.concatenate([[0], change]).tolist()
        ends = (np.concatenate([change, [len(spans)]]) - 1).tolist()
        firsts, lasts, owners = spans[:, 0].tolist(), spans[:, 1].tolist(), owner.tolist()
        out: list[str] = []
        position = 0
        for start, end in zip(starts, ends, strict=True):
            first, last, body = firsts[start], lasts[end], owners[start]
            out += lines[position:first]
            out += [f"M486 S{body}", f"EXCLUDE_OBJECT_START NAME={self.names[body]}"]
            out += lines[first:last + 1]
            out += [f"EXCLUDE_OBJECT_END NAME={self.names[body]}", "M486 S-1"]
            position = last + 1
        out += lines[position:]
        return out


def nearest_body(
    polys: np.ndarray, bodies: np.ndarray, points: np.ndarray, outline: shapely.Geometry
) -> np.ndarray:
    """The body of the polygon nearest each point, (k,) int64: ``polys`` (p,) shapely
    polygons, ``bodies`` (p,) int64, ``points`` (k, 2) mm, ``outline`` the polygons' union.

    A point inside exactly one polygon of a valid outline (polygons' interiors apart)
    is at distance zero from it and from no other: that polygon's body, found by a
    point-in-polygon test; the others (outside all, or the outline not valid) by a
    nearest-neighbour search over the polygons.
    """
    owner = np.empty(len(points), dtype=np.int64)
    rest = np.arange(len(points))
    if len(polys) > 1 and shapely.is_valid(outline):
        hits = np.zeros(len(points), dtype=np.int64)
        x, y = points[:, 0], points[:, 1]
        boxes = shapely.bounds(polys)
        shapely.prepare(polys)  # layer_bodies' own copies
        # (point, polygon) pairs whose box holds the point, a bounded block of polygons
        # at a time, then one point-in-polygon test over all the pairs of the block
        step = max(1, _PAIRS // max(len(points), 1))
        for a in range(0, len(polys), step):
            box = boxes[a : a + step]
            near = ((x[:, None] >= box[:, 0]) & (x[:, None] <= box[:, 2])
                    & (y[:, None] >= box[:, 1]) & (y[:, None] <= box[:, 3]))
            pt, poly = np.nonzero(near)
            poly += a
            inside = shapely.contains_xy(polys[poly], x[pt], y[pt])
            hits += np.bincount(pt[inside], minlength=len(points))
            owner[pt[inside]] = bodies[poly[inside]]
        rest = np.flatnonzero(hits != 1)
    elif len(polys) == 1:
        owner[:] = bodies[0]
        return owner
    if len(rest):
        tree = shapely.STRtree(polys)
        nearest = tree.query_nearest(shapely.points(points[rest]), all_matches=False)
        owner[rest[nearest[0]]] = bodies[nearest[1]]
    return owner


def extruding_moves(lines: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the moves that extrude while moving in X/Y, (k,) int64, and each one's
    midpoint (start and end averaged), (k, 2) float64 mm. Absolute X Y, relative E."""
    x, y, e = _move_words(lines)
    return moves_from(x, y, e > 0)


def moves_from(
    x: np.ndarray, y: np.ndarray, extruding: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`extruding_moves` from each line's X and Y (NaN where it has none) and
    whether its E is positive, (n,) each."""
    count = len(x)
    fx, fy = _fill_forward(x), _fill_forward(y)
    px, py = np.roll(fx, 1), np.roll(fy, 1)
    if count:
        px[0], py[0] = np.nan, np.nan
    moved = (~np.isnan(x) | ~np.isnan(y)) & ((fx != px) | (fy != py))
    ext = np.flatnonzero(extruding & moved & ~np.isnan(fx) & ~np.isnan(fy))
    sx = np.where(np.isnan(px[ext]), fx[ext], px[ext])
    sy = np.where(np.isnan(py[ext]), fy[ext], py[ext])
    points = np.column_stack([(sx + fx[ext]) / 2, (sy + fy[ext]) / 2])
    return ext, points


def _move_words(lines: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each line's X, Y (NaN where absent) and E (0 where absent) if it is a move,
    (n,) float64 each: one regular-expression pass over the joined text, the numbers
    converted by numpy (as ``float`` converts them)."""
    found = _LINE.findall("\n".join(lines) + "\n") if lines else []
    if len(found) != len(lines):  # a line with a newline inside: one line at a time
        found = [_LINE.match(line + "\n").groups("") for line in lines]  # type: ignore[union-attr]
    words = np.array(list(itertools.chain.from_iterable(found)), dtype=object).reshape(-1, 3)
    given = words != ""
    values = np.zeros(words.shape)
    values[given] = words[given].astype(np.float64)
    values[:, :2][~given[:, :2]] = np.nan
    return values[:, 0], values[:, 1], values[:, 2]


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
