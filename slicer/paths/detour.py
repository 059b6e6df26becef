"""Travels that go around a region (a cancelled body's outline grown by a margin).

A travel whose straight line meets the region is re-planned along the boundary
of the region grown a little more: from where the line enters each part of it
to where the line leaves it, the shorter way round the part's outer ring. Only
the travels that meet the region (found in one vectorised test) are walked, in
a deterministic order, so the same layer gives the same moves byte for byte.
"""

from __future__ import annotations

import numpy as np
import shapely

from slicer.geometry import geom
from slicer.geometry.geom import private_copy

# how far travels keep from a cancelled body's outline, mm
MARGIN = 1.0
# the ring walked lies this much further out, so it never touches the region
_CLEAR = 0.2


def avoid_region(outlines: np.ndarray, margin: float = MARGIN) -> shapely.Geometry | None:
    """The region travels must not cross: the union of ``outlines`` ((p,) polygons, mm)
    grown by ``margin`` mm; None when there is nothing to avoid."""
    if len(outlines) == 0:
        return None
    region = shapely.buffer(shapely.union_all(outlines), margin, quad_segs=4)
    return None if region.is_empty else region


def detours(a: np.ndarray, b: np.ndarray, region: shapely.Geometry | None) -> list[np.ndarray]:
    """For each travel ``a[k] -> b[k]`` ((n, 2) mm), the points to pass through between them
    ((m, 2), empty when the straight line keeps clear of ``region``)."""
    out = [np.zeros((0, 2)) for _ in range(len(a))]
    if region is None or len(a) == 0:
        return out
    lines = shapely.linestrings(np.stack([a, b], axis=1))
    area = private_copy(region)  # a private copy to prepare
    shapely.prepare(area)
    hit = np.flatnonzero(shapely.intersects(lines, area))
    if not len(hit):
        return out
    rings = [shapely.get_exterior_ring(p) for p in shapely.get_parts(
        shapely.buffer(region, _CLEAR, quad_segs=4))]
    for k in hit.tolist():
        out[k] = _around(a[k], b[k], rings)
    return out


def _around(a: np.ndarray, b: np.ndarray, rings: list[shapely.Geometry]) -> np.ndarray:
    """The points round every ring the line ``a -> b`` crosses, in the line's order; an end
    inside a ring (a body that close) leaves from, or arrives at, the ring's nearest point."""
    line = shapely.LineString([a, b])
    crossings = []
    for ring in rings:
        meet = shapely.get_coordinates(geom.intersection(line, ring))
        inside = [shapely.contains_xy(shapely.Polygon(ring), *end) for end in (a, b)]
        ends = [shapely.get_coordinates(shapely.line_interpolate_point(
            ring, shapely.line_locate_point(ring, shapely.Point(end))))[0]
            for end, within in zip((a, b), inside, strict=True) if within]
        meet = np.vstack([meet, *ends]) if ends else meet
        if len(meet) < 2:
            continue
        along = np.hypot(*(meet - a).T)
        first, last = meet[np.argmin(along)], meet[np.argmax(along)]
        if inside[0]:
            first = ends[0]
        if inside[1]:
            last = ends[-1]
        crossings.append((float(along.min()), _walk(ring, first, last)))
    crossings.sort(key=lambda c: c[0])
    if not crossings:
        return np.zeros((0, 2))
    return np.concatenate([points for _, points in crossings])


def _walk(ring: shapely.Geometry, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """The points of ``ring`` from ``start`` to ``end`` (both on it), the shorter way."""
    coords = shapely.get_coordinates(ring)[:-1]
    total = float(shapely.length(ring))
    s0 = float(shapely.line_locate_point(ring, shapely.Point(start)))
    s1 = float(shapely.line_locate_point(ring, shapely.Point(end)))
    steps = np.hypot(*np.diff(np.vstack([coords, coords[:1]]), axis=0).T)
    at = np.concatenate(([0.0], np.cumsum(steps)[:-1]))
    forward = (s1 - s0) % total
    if forward <= total - forward:
        offset = (at - s0) % total
        chosen = np.flatnonzero((offset > 0) & (offset < forward))
        order = chosen[np.argsort(offset[chosen])]
    else:
        offset = (s0 - at) % total
        chosen = np.flatnonzero((offset > 0) & (offset < total - forward))
        order = chosen[np.argsort(offset[chosen])]
    return np.vstack([start[None, :], coords[order], end[None, :]])
