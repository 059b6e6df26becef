"""Inward offsets of polygons: ``shapely.buffer(polygon, -d)``, convex ones in numpy.

A layer's walls and infill domain are inward offsets of its islands, and many
islands are small convex polygons (the struts of a lattice, pins, the rings
of a cone or a sphere), most of whose inner levels are empty. The inward
offset of a convex polygon needs no noding: it is the intersection of its
edges' half-planes moved in by ``d``, whose corners are where consecutive
moved edges meet. Those are made here in numpy for all the polygons at once
(the diagonal lattice's walls and domains: 0.65 -> 0.56 s of CPU); every
other polygon (holes, a reflex corner, a repeated point) is left to GEOS.
Both give the same region up to rounding, except near a collapse, where GEOS
leaves a speck (a 16-gon of inradius 0.588 mm buffered in by 0.6 mm: a
polygon of 0.0004 mm^2) and this gives nothing.
"""

from __future__ import annotations

import numpy as np
import shapely

# an offset edge shorter than this along its original direction counts as vanished, mm:
# a wall 2 d wide to within float noise (1.2000008 mm at d = 0.6) has no inset, as GEOS
# gives none (a sliver there made a second wall of a thin wall, not a widened first)
_MIN_EDGE = 1e-4


def inset(polygons: np.ndarray, distance: float | np.ndarray, quad_segs: int) -> np.ndarray:
    """``shapely.buffer(polygons, -distance, quad_segs=quad_segs)`` of ``polygons`` (n,)
    object array, ``distance`` mm (scalar or (n,), > 0): (n,) object array.

    Convex polygons without holes come out as the exact intersection of their
    edges' inset half-planes (a clockwise shell, as GEOS makes; an empty
    Polygon when nothing is left), the others from GEOS (which also drops an
    input point within 1 % of ``distance`` of its neighbours' line).
    """
    polygons = np.asarray(polygons, dtype=object)
    dist = np.broadcast_to(np.asarray(distance, dtype=np.float64), polygons.shape)
    out = np.empty(polygons.shape, dtype=object)
    if polygons.size == 0:
        return out
    fast = _hole_free(polygons) & (dist > 0)
    done = np.zeros(polygons.shape, dtype=bool)
    idx = np.flatnonzero(fast)
    if len(idx):
        made, ok = _convex_insets(polygons[idx], dist[idx])
        out[idx[ok]] = made[ok]
        done[idx[ok]] = True
    rest = np.flatnonzero(~done)
    if len(rest):
        out[rest] = shapely.buffer(polygons[rest], -dist[rest], quad_segs=quad_segs)
    return out


def _hole_free(polygons: np.ndarray) -> np.ndarray:
    """Polygons without holes, non-empty (n,) bool (their convexity is tested later)."""
    ok: np.ndarray = shapely.get_type_id(polygons) == shapely.GeometryType.POLYGON
    some = polygons[ok]
    ok[ok] = (shapely.get_num_interior_rings(some) == 0) & ~shapely.is_empty(some)
    return ok


def _convex_insets(polygons: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Insets of hole-free polygons (m,) by ``dist`` (m,) mm where each is convex: (the
    insets (m,) object, which ones were made (m,) bool; the others have a reflex
    corner, a repeated point or no area).

    Each edge's line is moved in by ``d`` and the inset's corners are where the
    lines of consecutive edges meet. An edge whose moved segment runs backwards
    (or shrinks under :data:`_MIN_EDGE`) is not part of the inset: the inset of
    the polygon its neighbours leave is only smaller, so its edge would be
    shorter still. Such edges are dropped, all at once, and the corners found
    again from the edges left, until none runs backwards; when fewer than
    three edges are left, or two consecutive ones turn by half a turn or more,
    the inset is empty.
    """
    m = len(polygons)
    coords, ring = shapely.get_coordinates(shapely.get_exterior_ring(polygons), return_index=True)
    counts = np.bincount(ring, minlength=m)
    keep = np.ones(len(coords), dtype=bool)
    keep[np.cumsum(counts) - 1] = False  # the closing point repeats the first
    x, y, ring = coords[keep, 0], coords[keep, 1], ring[keep]
    nxt, prev = _neighbours(ring, m)
    # twice the signed area: > 0 anticlockwise; clockwise rings are walked backwards
    side = np.sign(np.bincount(ring, weights=x * y[nxt] - x[nxt] * y, minlength=m))
    ok = (counts - 1 >= 3) & (side != 0)
    order = np.lexsort((np.arange(len(ring)) * np.where(side[ring] < 0, -1, 1), ring))
    x, y = x[order], y[order]
    dx, dy = x[nxt] - x, y[nxt] - y
    length = np.hypot(dx, dy)
    ok &= _none(ring, length <= 0.0, m)
    inv = 1.0 / np.where(length > 0, length, 1.0)
    ux, uy = dx * inv, dy * inv  # unit directions, anticlockwise
    sin = ux[prev] * uy - uy[prev] * ux  # turn at each point, > 0 convex
    ok &= _none(ring, sin < 0.0, m)
    out = np.empty(m, dtype=object)
    take = ok[ring]
    if not take.any():
        return out, ok
    x, y, ux, uy, ring = x[take], y[take], ux[take], uy[take], ring[take]
    d = dist[ring]
    # each polygon's box (its points are grouped by polygon, in order)
    first = np.flatnonzero(np.r_[True, ring[1:] != ring[:-1]])
    x_lo, x_hi = np.zeros(m), np.zeros(m)
    y_lo, y_hi = np.zeros(m), np.zeros(m)
    x_lo[ring[first]] = np.minimum.reduceat(x, first)
    x_hi[ring[first]] = np.maximum.reduceat(x, first)
    y_lo[ring[first]] = np.minimum.reduceat(y, first)
    y_hi[ring[first]] = np.maximum.reduceat(y, first)
    adjacent = None  # every edge's previous one is the polygon's own
    empty = np.zeros(m, dtype=bool)
    while True:
        nxt, prev = _neighbours(ring, m)
        cos = ux[prev] * ux + uy[prev] * uy
        sin = ux[prev] * uy - uy[prev] * ux
        half_turn = (sin < 0.0) | ((sin == 0.0) & (cos < 0.0))
        gone = (np.bincount(ring, minlength=m) < 3) | ~_none(ring, half_turn, m)
        # corner i: on edge i's moved line (inward normal (-uy, ux)), t along it from
        # where the previous edge's moved line meets it; t = d tan(turn / 2) where the
        # previous edge is the polygon's own
        with np.errstate(divide="ignore", invalid="ignore"):
            t = d * sin / (1.0 + cos)
            if adjacent is not None:
                far = ~adjacent
                gap = -uy[prev][far] * (x[prev][far] - x[far]) + ux[prev][far] * (
                    y[prev][far] - y[far])
                t[far] += gap / sin[far]
            cx = x - d * uy + t * ux
            cy = y + d * ux + t * uy
            along = (cx[nxt] - cx) * ux + (cy[nxt] - cy) * uy
        back = ~(along > _MIN_EDGE)
        back &= ~gone[ring]
        empty |= gone
        if not back.any():
            break
        # drop the backward edges: the next edge's previous one is no longer its own
        moved = np.zeros(len(ring), dtype=bool)
        moved[nxt[back]] = True
        adjacent = ~moved if adjacent is None else adjacent & ~moved
        stay = ~back & ~gone[ring]
        x, y, ux, uy, ring, d, adjacent = (
            x[stay], y[stay], ux[stay], uy[stay], ring[stay], d[stay], adjacent[stay])
    live = ~gone[ring]
    cx, cy, ring = cx[live], cy[live], ring[live]
    # two (nearly) parallel edges left next to each other (an edge between them
    # dropped) have moved lines that meet far away or never: an inset lies inside its
    # polygon, so a polygon with a corner outside its own box is left to GEOS
    inside = (cx >= x_lo[ring]) & (cx <= x_hi[ring]) & (cy >= y_lo[ring]) & (cy <= y_hi[ring])
    ok &= _none(ring, ~inside, m)
    keep = ok[ring]
    cx, cy, ring = cx[keep], cy[keep], ring[keep]
    made = np.flatnonzero(ok & ~empty)
    out[np.flatnonzero(ok & empty)] = shapely.Polygon()
    if len(made):
        # clockwise, as GEOS gives its shells: every ring reversed
        order = np.lexsort((-np.arange(len(ring)), ring))
        owner = np.searchsorted(made, ring[order])
        rings = shapely.linearrings(cx[order], cy[order], indices=owner)
        out[made] = shapely.polygons(rings)
    return out, ok


def _neighbours(ring: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Next and previous point of each point (n,) of rings numbered ``ring`` (n,), sorted,
    each ring cyclic: (next (n,), previous (n,)) indices."""
    counts = np.bincount(ring, minlength=m)
    ends = np.cumsum(counts)
    starts = ends - counts
    used = counts > 0
    nxt = np.arange(len(ring)) + 1
    nxt[ends[used] - 1] = starts[used]
    prev = np.arange(len(ring)) - 1
    prev[starts[used]] = ends[used] - 1
    return nxt, prev


def _none(ring: np.ndarray, flags: np.ndarray, m: int) -> np.ndarray:
    """(m,) bool: no point of the ring has its flag set."""
    clear: np.ndarray = np.bincount(ring[flags], minlength=m) == 0
    return clear
